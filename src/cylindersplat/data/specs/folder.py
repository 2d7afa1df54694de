"""Posed panoramas in the input format of docs/inference.md: a folder with ``poses.json`` (or ``transforms.json``)
and the images (depth files optional), or a folder of such folders (:mod:`cylindersplat.data.folder`). No splits;
``targets`` holds frames out, else the views run over the frames in poses-file order."""

from __future__ import annotations

from pathlib import Path

from ...dataset_layouts import HOLDS_SOME, IS_ONE, DatasetSpec


def _detect(path: Path) -> int:
    from ..folder import is_input_folder

    if is_input_folder(path):
        return IS_ONE
    return HOLDS_SOME if any(is_input_folder(d) for d in path.iterdir() if d.is_dir()) else 0


def _open(root, *, views="all_inputs", split=None, **options):
    from ..folder import FolderDataset

    return FolderDataset(root, views=views, **options)  # a folder of posed panoramas, or a folder of them


def _frames(root, split: str = "all"):
    from ...errors import OutsideFolderError
    from ..confine import ALLOW_OUTSIDE_OPTION
    from ..depth_prior.base import NoPrior
    from ..folder import FolderDataset

    try:
        return FolderDataset(root, depth_prior=NoPrior())
    except OutsideFolderError as exc:  # no way round here: the tree mirrors paths inside the dataset
        text = str(exc).replace(f" (or pass {ALLOW_OUTSIDE_OPTION} to read it anyway)", "")
        raise OutsideFolderError(f"{text} (prior files mirror the panoramas' paths inside the dataset)") from None


def _inspect(root, *, views, resolution=None, targets=None, allow_outside_paths=False):
    from ..depth_prior.base import NoPrior
    from ..folder import FolderDataset

    # depth files only as ground truth: pictures and occlusion need no prior
    return FolderDataset(root, views=views, targets=targets, resolution=resolution, depth_prior=NoPrior(),
                         depth_files="reference", allow_outside_paths=allow_outside_paths)


WHAT = "a folder of posed panoramas (poses.json or transforms.json, or subfolders with one)"
SPEC = DatasetSpec("folder", WHAT, _detect, _open, _frames, _inspect,
                   views="all_inputs", info_views="two_view", preview_views="all_inputs",
                   options=("targets", "allow_outside_paths", "poses_file", "depth_files", "depth_resize",
                            "check_plausibility"),
                   depth_range=(0.05, 1000.0))
