"""Loader of the procedural generator's output (layout: :mod:`cylindersplat.data.synth.writer`)."""

from __future__ import annotations

import math
import warnings
from pathlib import Path

from ..utils.jsonfile import read_json_file
from ..utils.notices import Notice
from .base import ExampleRef, FrameRef, PanoramaDataset
from .depth_prior.base import DepthPrior
from .depth_prior.simulated import SimulatedPrior
from .io import DEPTH_PNG_SCALE
from .poses.conventions import parse_pose_matrix
from .views import select_views

__all__ = ["SyntheticDataset"]


def _read_json(path: Path, kind: type = dict):
    """A JSON file of the dataset, which must hold a ``kind`` (an object, for every file of the layout)."""
    data = read_json_file(path)
    if not isinstance(data, kind):
        raise ValueError(f"{path}: expected a JSON {'object' if kind is dict else kind.__name__}, got "
                         f"{type(data).__name__} (is it a file written by cylindersplat data synth?)")
    return data


def _depth_scale(meta: dict, path: Path, default: float = DEPTH_PNG_SCALE) -> float:
    """``depth_scale`` of a meta.json (depth PNG units per metre; absent: ``default``, the dataset's own
    ``depth_scale`` for a scene, millimetres for the dataset)."""
    scale = meta.get("depth_scale", default)
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale <= 0:
        raise ValueError(f"{path}: depth_scale must be a positive number (PNG units per metre), got {scale!r}")
    return float(scale)


class SyntheticDataset(PanoramaDataset):
    """Sequences written by ``cylindersplat data synth``.

    ``views``: protocol of :func:`cylindersplat.data.views.select_views`. ``depth_prior`` defaults
    to :class:`SimulatedPrior` (ground truth degraded reproducibly) because that is what synthetic
    data is for; pass :class:`~cylindersplat.data.depth_prior.NoPrior` for all-zero priors.
    ``scenes`` restricts the dataset to these scene ids (e.g. a train/test split), in that order.
    """

    dataset_name = "synthetic"

    def __init__(
        self,
        root: str | Path,
        *,
        views="two_view",
        resolution: tuple[int, int] | None = None,
        depth_prior: DepthPrior | None = None,
        depth_resize: str = "area",
        scenes: list[str] | tuple[str, ...] | None = None,
    ) -> None:
        root = Path(root)
        meta = _read_json(root / "meta.json")
        stored = tuple(meta.get("resolution", ()))
        if len(stored) != 2:
            raise ValueError(f"{root / 'meta.json'}: 'resolution' must be [H, W]")
        super().__init__(resolution, depth_prior or SimulatedPrior(), stored_size=stored, depth_resize=depth_resize)
        self.root = self.data_root = root
        self.views = views
        self.depth_scale = _depth_scale(meta, root / "meta.json")  # for scenes whose meta.json names none
        listed = meta.get("scenes", [])
        if not isinstance(listed, list) or not all(isinstance(s, str) for s in listed):
            raise ValueError(f'{root / "meta.json"}: "scenes" must be a list of scene ids, got {listed!r:.80}')
        self.scenes = [s for s in listed if (root / s / "meta.json").is_file()]
        if self.scenes and len(self.scenes) < len(listed):  # an interrupted `data synth`: say so, read the rest
            absent = [s for s in listed if s not in self.scenes]
            warnings.warn(f"{root}: {len(absent)} of {len(listed)} scenes listed in meta.json are missing or "
                          f"incomplete ({', '.join(absent[:3])}{', ...' if len(absent) > 3 else ''}); using the other "
                          f"{len(self.scenes)} (run data synth again to finish them)", Notice, stacklevel=2)
        if not self.scenes:
            raise ValueError(f"{root}: no complete scenes (each needs <id>/meta.json)")
        if scenes is not None:
            missing = [s for s in scenes if s not in self.scenes]
            if missing:
                raise ValueError(f"{root}: no complete scene(s) {missing}; available: {self.scenes}")
            self.scenes = list(scenes)

    def __len__(self) -> int:
        return len(self.scenes)

    def example(self, index: int) -> ExampleRef:
        scene = self.scenes[index]
        folder = self.root / scene
        meta_path = folder / "meta.json"
        meta = _read_json(meta_path)
        poses = _read_json(folder / "poses.json")
        names = meta.get("frames")
        if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
            raise ValueError(f'{meta_path}: "frames" must be a non-empty list of frame names, got {names!r:.80}')
        scale = _depth_scale(meta, meta_path, default=self.depth_scale)
        frames = []
        for name in names:
            if name not in poses:
                raise ValueError(f"{folder / 'poses.json'}: no pose for frame {name!r}")
            # finite, 4x4, a rotation (a reflected pose is refused), last row 0 0 0 1
            c2w = parse_pose_matrix(poses[name], f"{folder / 'poses.json'} frame {name!r}")
            for file in ("rgb.png", "depth.png"):
                if not (folder / name / file).is_file():
                    raise FileNotFoundError(f"missing {file} of frame {name!r}: {folder / name / file} (the scene is "
                                            "incomplete; run data synth again to finish it)")
            frames.append(FrameRef(name, folder / name / "rgb.png", c2w.float(), folder / name / "depth.png", scale))
        extra = {"kind": meta.get("kind"), "spacing": meta.get("spacing")}
        if "target_offset" in meta:  # datasets made with a target offset (data synth --profile occlusion)
            extra["target_offset"] = meta["target_offset"]
        return ExampleRef(scene, frames, select_views(len(frames), self.views), extra)
