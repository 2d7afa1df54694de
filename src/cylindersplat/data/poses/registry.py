"""The pose formats ``data import-poses --from NAME`` reads: one line each, the module that reads it and how.

A new format is one new module of this package (a header table like :mod:`.conventions`' and a reader
``read_x(path, scale=1.0, **options) -> list[PoseRecord]`` ending in :func:`~.conventions.check_pose`) and one line
here; ``tests/test_pose_registry.py`` checks every line, and docs/poses.md walks through an example. No reader
module is imported until its format is read (``PoseFormat.read``); ``data import-poses`` reads the names from here
only when it parses ``--from``.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # (conventions imports torch; this module does not, for the command line's help)
    from .conventions import PoseRecord

__all__ = ["POSE_FORMATS", "PoseFormat", "pose_format"]


@dataclass(frozen=True)
class PoseFormat:
    """One ``data import-poses --from NAME`` of the registry: the ``module`` of this package and its ``reader``
    function (``reader(path, scale, **options) -> list[PoseRecord]``); ``images`` says how its poses name their
    panoramas: ``"named"`` (image names, looked up in ``--images``), ``"relative"`` (file names relative to the
    pose file, nerfstudio) or ``"ordered"`` (none: trajectories, matched in name order or by timestamp);
    ``options`` are the command-line options it takes (``"reconstruction"``)."""

    module: str
    reader: str
    images: str
    options: tuple[str, ...] = ()

    def read(self, path, scale: float = 1.0, **options) -> list[PoseRecord]:
        return getattr(importlib.import_module(f"{__package__}.{self.module}"), self.reader)(path, scale, **options)


POSE_FORMATS: dict[str, PoseFormat] = {
    "opensfm": PoseFormat("opensfm", "read_opensfm", "named", options=("reconstruction",)),
    "nerfstudio": PoseFormat("nerfstudio", "read_transforms_json", "relative"),
    "tum": PoseFormat("trajectories", "read_tum", "ordered"),
    "kitti": PoseFormat("trajectories", "read_kitti", "ordered"),
    "colmap": PoseFormat("colmap", "read_colmap", "named"),
    "metashape": PoseFormat("metashape", "read_metashape_xml", "named"),
    "openmvg": PoseFormat("openmvg", "read_openmvg", "named"),
}


def pose_format(name: str) -> PoseFormat:
    """The registry entry ``name``; ``ValueError`` listing the formats otherwise."""
    if name not in POSE_FORMATS:
        raise ValueError(f"unknown pose format {name!r}; use one of {', '.join(POSE_FORMATS)}")
    return POSE_FORMATS[name]
