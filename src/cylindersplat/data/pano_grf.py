"""Matterport3D / Replica / Residential renders in the PanoGRF layout, as PanSplat reads them.

Layout::

    ROOT/png_render_{split}_{W}x{H}_seq_len_3_{m3d|replica|residential}_dist_{d}/<id>/{00,01,02}/
        rgb.png    8-bit RGB panorama
        depth.png  16-bit, millimetres of *ray* (radial) distance, 0 = hole (absent for Residential)
        rot.txt    3x3 rotation
        tran.txt   3-vector translation

Frames lie on a line ``d`` metres apart; frames 00/02 are the contexts and 01 the target
("two_view"), so the context baseline is ``2 d``.

Pose convention (verified in PanSplat's ``src/dataset/dataset_mp3d.py``, ``convert_poses``,
repository chengzhag/PanSplat): ``(rot, tran)`` is a Habitat camera-to-world pose (camera x right,
y up, z backward; world y up). PanSplat builds ``c2w = W @ [rot | tran] @ C`` with the fixed
world change ``W`` = rows ``(1,0,0), (0,0,-1), (0,1,0)`` (a z-up world) and the camera flip
``C = diag(1, -1, -1)`` (Habitat camera -> OpenCV camera). We use the same camera flip but the
world change ``diag(1, -1, -1)`` instead of ``W``, so that world +y is gravity-down as docs/conventions.md
asks; the two worlds differ by one fixed rotation, so all relative poses (and every reprojection)
are identical to PanSplat's. With identity rotations the result is ``c2w = [I | diag(1,-1,-1) tran]``;
the test ``tests/test_data_pano_grf.py`` proves the convention on a real triplet by reprojection.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .base import ExampleRef, FrameRef, PanoramaDataset
from .depth_prior.files import PRIORS_DIR
from .io import read_matrix_txt
from .views import select_views

__all__ = ["PanoGRFDataset", "panogrf_c2w", "panogrf_folder_name", "PANOGRF_NAMES"]

PANOGRF_NAMES = ("m3d", "replica", "residential")
# Any text after "_dist_": PanoGRF's own folders end in a distance (0.5, 1.0, ...), others in e.g. "var".
_FOLDER = re.compile(r"png_render_(?P<split>\w+?)_(?P<w>\d+)x(?P<h>\d+)_seq_len_(?P<n>\d+)"
                     r"_(?P<name>\w+?)_dist_(?P<d>.+)")
_HABITAT_TO_OPENCV = np.diag([1.0, -1.0, -1.0])


def panogrf_c2w(rot: np.ndarray, tran: np.ndarray) -> Tensor:
    """PanoGRF ``(rot 3x3, tran 3)`` -> OpenCV ``c2w`` 4x4 in a gravity-down (+y) world."""
    c2w = np.eye(4)
    c2w[:3, :3] = _HABITAT_TO_OPENCV @ rot @ _HABITAT_TO_OPENCV
    c2w[:3, 3] = _HABITAT_TO_OPENCV @ tran
    return torch.from_numpy(c2w).float()


def _distance(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def panogrf_folder_name(split: str, size: tuple[int, int], name: str, dist: float | str) -> str:
    """``png_render_{split}_{W}x{H}_seq_len_3_{name}_dist_{dist}`` (``dist`` printed as PanSplat does)."""
    dist_text = dist if isinstance(dist, str) else str(float(dist))
    return f"png_render_{split}_{size[1]}x{size[0]}_seq_len_3_{name}_dist_{dist_text}"


class PanoGRFDataset(PanoramaDataset):
    """Sequences of one ``png_render_*`` folder.

    ``folder`` is either that folder itself or a root holding it together with ``split``,
    ``stored_size`` (H, W), ``name`` and ``dist``. ``views`` picks the protocol
    (:func:`cylindersplat.data.views.select_views`). Ground-truth depth is loaded when every
    frame has a ``depth.png``. There is no depth prior of its own: pass ``depth_prior=`` (e.g.
    ``FilePrior("unik3d")`` for files written by ``cylindersplat data priors``).
    """

    def __init__(
        self,
        folder: str | Path,
        *,
        split: str = "test",
        stored_size: tuple[int, int] | None = None,
        name: str = "m3d",
        dist: float | str = 0.5,
        views="two_view",
        resolution: tuple[int, int] | None = None,
        depth_prior=None,
        depth_resize: str = "area",
    ) -> None:
        folder = Path(folder)
        if not _FOLDER.fullmatch(folder.name):
            if stored_size is None:
                inside = sorted(p.name for p in folder.glob("png_render_*") if _FOLDER.fullmatch(p.name))
                hint = f" (here: {', '.join(inside[:3])}{' ...' if len(inside) > 3 else ''})" if inside else ""
                raise ValueError(f"{folder}: not a png_render_{{split}}_{{W}}x{{H}}_seq_len_3_{{name}}_dist_{{d}} "
                                 f"folder; give that folder itself as --data (data.root){hint}")
            folder = folder / panogrf_folder_name(split, stored_size, name, dist)
        match = _FOLDER.fullmatch(folder.name)
        if not folder.is_dir():
            raise FileNotFoundError(f"missing dataset folder: {folder}")
        size = (int(match["h"]), int(match["w"]))
        super().__init__(resolution, depth_prior, stored_size=size, depth_resize=depth_resize)
        self.folder = self.data_root = folder
        self.name = match["name"]
        self.dataset_name = self.name
        self.dist = _distance(match["d"])  # None where the suffix is no distance (e.g. dist_var)
        self.split = match["split"]
        self.views = views
        # (a `priors` folder holds depth priors written by `cylindersplat data priors`, not a scene)
        self.scenes = sorted(p.name for p in folder.iterdir() if p.is_dir() and p.name != PRIORS_DIR)
        if not self.scenes:
            raise ValueError(f"{folder}: no scene folders found")

    def __len__(self) -> int:
        return len(self.scenes)

    def example(self, index: int) -> ExampleRef:
        scene = self.scenes[index]
        scene_dir = self.folder / scene
        frame_dirs = sorted(p for p in scene_dir.iterdir() if p.is_dir())
        if not frame_dirs:
            raise ValueError(f"{scene_dir}: no frame folders (expected 00, 01, 02)")
        has_depth = all((d / "depth.png").is_file() for d in frame_dirs)
        frames = [
            FrameRef(
                name=d.name,
                rgb=d / "rgb.png",
                c2w=panogrf_c2w(read_matrix_txt(d / "rot.txt", (3, 3)), read_matrix_txt(d / "tran.txt", (3,))),
                depth=d / "depth.png" if has_depth else None,
            )
            for d in frame_dirs
        ]
        meta = {"dist": self.dist, "nominal_baseline": None if self.dist is None else 2 * self.dist,
                "split": self.split}
        return ExampleRef(scene, frames, select_views(len(frames), self.views), meta)
