"""360Loc panoramic sequences, as PanSplat uses them.

Layout (checked in PanSplat's ``src/dataset/dataset_360loc.py``, repository chengzhag/PanSplat)::

    ROOT/<location>/{mapping,query_360}/<sequence with "360" in its name>/
        camera_pose.json   {frame file name: 4x4 camera-to-world, OpenCV camera}, in frame order
        image/<frame file name>

PanSplat uses the poses as stored (no axis change), trains on ``concourse``, ``hall``,
``piatrium`` and tests on ``atrium``. Its test sampler (``view_sampler_bounded.py`` with the
360Loc gaps min 2 / max 5) takes two contexts ``gap = (2 + 5) // 2 = 3`` frames apart (~1.4 m) at
``times_per_sequence = 100`` evenly spaced starts, and renders every frame between them, the
contexts included (:func:`cylindersplat.data.views.all_between`). There is no ground-truth depth.

More context views (the paper's Table 5: 3 and 4 views) and wider gaps (its wide-baseline table:
3.0 m and 4.5 m; frames are ~0.46 m apart): ``context_views`` and ``gap`` (``context_layout`` says where
the extra contexts go, see :func:`~cylindersplat.data.views.all_between`). The starts follow the
same sampler with the span from the first to the last context in place of the gap:
``int((n - span - 1) * i / (times - 1))``; sequences of ``n <= span`` frames give no example.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from ..utils.jsonfile import read_json_file
from .base import ExampleRef, FrameRef, PanoramaDataset
from .views import all_between, all_between_span, all_between_starts

__all__ = ["Loc360Dataset", "LOC360_SPLITS", "read_camera_pose_json"]

LOC360_SPLITS = {"train": ("concourse", "hall", "piatrium"), "test": ("atrium",)}


def read_camera_pose_json(path: Path) -> list[tuple[str, torch.Tensor]]:
    """``camera_pose.json`` -> ``[(frame name, c2w 4x4 float32)]`` in file order."""
    data = read_json_file(path)
    if not isinstance(data, dict) or not data:
        raise ValueError(f"{path}: expected a non-empty object {{frame name: 4x4 matrix}}")
    out = []
    for name, matrix in data.items():
        arr = np.asarray(matrix, dtype=np.float64)
        if arr.shape != (4, 4):
            raise ValueError(f"{path}: pose of {name!r} must be 4x4, got shape {arr.shape}")
        if not np.isfinite(arr).all():
            raise ValueError(f"{path}: pose of {name!r} contains non-finite values")
        out.append((name, torch.from_numpy(arr).float()))
    return out


class Loc360Dataset(PanoramaDataset):
    """360Loc examples: ``split`` picks the locations (or pass ``locations``)."""

    dataset_name = "360loc"

    def __init__(
        self,
        root: str | Path,
        *,
        split: str = "test",
        locations: tuple[str, ...] | None = None,
        gap: int = 3,
        context_views: int = 2,
        context_layout: str = "spaced",
        times_per_sequence: int = 100,
        resolution: tuple[int, int] | None = None,
        depth_prior=None,
    ) -> None:
        super().__init__(resolution, depth_prior)
        root = Path(root)
        if not root.is_dir():
            raise FileNotFoundError(f"missing dataset folder: {root}")
        locations = locations or LOC360_SPLITS.get(split)
        if locations is None:
            raise ValueError(f"unknown 360Loc split {split!r}; use one of {sorted(LOC360_SPLITS)} or pass locations")
        self.root = self.data_root = root
        span = all_between_span(gap, context_views, context_layout)  # also checks the three choices
        self.gap, self.context_views, self.context_layout = gap, context_views, context_layout
        self.sequences: list[tuple[str, Path, list[tuple[str, torch.Tensor]]]] = []
        self.index: list[tuple[int, int]] = []
        for location in locations:
            for folder in ("mapping", "query_360"):
                for seq in sorted((root / location / folder).glob("*360*")):
                    if not seq.is_dir():
                        continue
                    poses = read_camera_pose_json(seq / "camera_pose.json")
                    seq_id = len(self.sequences)
                    self.sequences.append((f"{location}-{seq.name}", seq, poses))
                    self.index += [(seq_id, s) for s in all_between_starts(len(poses), span, times_per_sequence)]
        if not self.sequences:
            raise ValueError(f"{root}: no 360Loc sequences (<location>/{{mapping,query_360}}/*360*/) for {locations}")

    def __len__(self) -> int:
        return len(self.index)

    def require_examples(self) -> None:
        """A one-line ``ValueError`` when no sequence is long enough for the chosen views and gap."""
        if not self.index:
            span = all_between_span(self.gap, self.context_views, self.context_layout)
            longest = max(len(poses) for _, _, poses in self.sequences)
            raise ValueError(f"{self.root}: {self.context_views} context views {self.gap} frames apart "
                             f"({self.context_layout} layout) span {span} frames, but the longest sequence has "
                             f"{longest}: choose a smaller gap or fewer views")

    def frames(self) -> list[tuple[FrameRef, str]]:
        """Every frame of every sequence (also those no example of this protocol uses)."""
        return [(FrameRef(name, seq / "image" / name, c2w), f"{self.dataset_name}/{scene}/{name}")
                for scene, seq, poses in self.sequences for name, c2w in poses]

    def example(self, index: int) -> ExampleRef:
        seq_id, start = self.index[index]
        scene, seq, poses = self.sequences[seq_id]
        frames = [FrameRef(name, seq / "image" / name, c2w) for name, c2w in poses]
        views = all_between(start, self.gap, self.context_views, self.context_layout)
        return ExampleRef(scene, frames, views, {"start": start, "gap": self.gap, "context_views": self.context_views,
                                                 "context_layout": self.context_layout})
