"""Loader of the procedural generator's output (layout: :mod:`cylindersplat.data.synth.writer`)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from .base import ExampleRef, FrameRef, PanoramaDataset
from .depth_prior.base import DepthPrior
from .depth_prior.simulated import SimulatedPrior
from .views import select_views

__all__ = ["SyntheticDataset"]


def _read_json(path: Path):
    if not path.is_file():
        raise FileNotFoundError(f"missing file: {path}")
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: invalid JSON ({exc})") from exc


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
        self.scenes = [s for s in meta.get("scenes", []) if (root / s / "meta.json").is_file()]
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
        meta = _read_json(folder / "meta.json")
        poses = _read_json(folder / "poses.json")
        frames = []
        for name in meta["frames"]:
            if name not in poses:
                raise ValueError(f"{folder / 'poses.json'}: no pose for frame {name!r}")
            c2w = np.asarray(poses[name], dtype=np.float64)
            if c2w.shape != (4, 4) or not np.isfinite(c2w).all():
                raise ValueError(f"{folder / 'poses.json'}: pose of {name!r} must be a finite 4x4 matrix")
            frames.append(FrameRef(name, folder / name / "rgb.png", torch.from_numpy(c2w).float(), folder / name / "depth.png"))
        extra = {"kind": meta.get("kind"), "spacing": meta.get("spacing")}
        if "target_offset" in meta:  # datasets made with a target offset (data synth --profile occlusion)
            extra["target_offset"] = meta["target_offset"]
        return ExampleRef(scene, frames, select_views(len(frames), self.views), extra)
