"""Writing our ``poses.json`` (:mod:`.conventions` says what its numbers mean; ``data.folder`` reads it), and the
warning for one whose poses are in SfM units (``data poses --scale none``)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ...utils.atomic import atomic_write_text
from .conventions import PoseRecord, check_pose

__all__ = ["write_poses_json", "SFM_UNITS", "warn_if_not_metric"]

SFM_UNITS = "none (SfM units)"  # the "scale" data poses writes when it could not make the poses metric


def write_poses_json(path: str | Path, records: list[PoseRecord], depth_scale: float | None = None, **extra) -> Path:
    """Write ``records`` as our ``poses.json`` (OpenCV c2w): ``"frames"`` when every record names its image,
    else ``"poses"`` (matched to a folder's images in name order). ``extra`` keys are stored as they are
    (readers ignore keys they do not know). Written atomically."""
    if not records:
        raise ValueError("no poses to write")
    for i, r in enumerate(records):  # no NaN, shear or reflection is ever written
        check_pose(r.c2w, f"pose {i}" + (f" ({r.image})" if r.image is not None else ""))
    data: dict = {"convention": "opencv_c2w"}
    if depth_scale is not None:
        data["depth_scale"] = depth_scale
    data.update(extra)
    if all(r.image is not None for r in records):
        frames = []
        for r in records:
            frame = {"image": r.image, "c2w": _rows(r.c2w)}
            if r.depth is not None:
                frame["depth"] = r.depth
            if r.timestamp is not None:
                frame["timestamp"] = r.timestamp
            frames.append(frame)
        data["frames"] = frames
    else:
        data["poses"] = [_rows(r.c2w) for r in records]
        if any(r.timestamp is not None for r in records):
            data["timestamps"] = [r.timestamp for r in records]
    return atomic_write_text(path, _dumps(data) + "\n")


def _rows(matrix: Tensor) -> list[list[float]]:
    """A pose as nested lists; float32 values as their shortest float32 text (0.3, not 0.30000001192092896)."""
    if matrix.dtype == torch.float32:
        return [[float(str(np.float32(v))) for v in row] for row in matrix.tolist()]
    return matrix.tolist()


def _dumps(value, indent: str = "") -> str:
    """JSON with one matrix row (a list of numbers) per line: readable 4x4 poses, still plain JSON."""
    inner = indent + " "
    if isinstance(value, dict):
        if not value:
            return "{}"
        items = [f"{inner}{json.dumps(str(k))}: {_dumps(v, inner)}" for k, v in value.items()]
        return "{\n" + ",\n".join(items) + "\n" + indent + "}"
    if isinstance(value, (list, tuple)):
        if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            return json.dumps(list(value))
        if all(isinstance(v, (list, tuple)) and all(isinstance(x, (int, float)) for x in v) for v in value) and value:
            return "[" + (",\n" + inner).join(json.dumps(list(v)) for v in value) + "]"  # a matrix
        return "[\n" + ",\n".join(inner + _dumps(v, inner) for v in value) + "\n" + indent + "]"
    return json.dumps(value)


def warn_if_not_metric(path: str | Path) -> None:
    """Warn once (:class:`~cylindersplat.validation.ScaleWarning`, one line naming ``path``) when a ``poses.json``
    says its poses are in SfM units (``"scale": "none (SfM units)"``, top level or in ``"sfm"``): depth in metres
    and such poses disagree, so a render or a depth-scale search from them is unreliable. Unreadable files are
    left to the reader that follows."""
    from ...validation import ScaleWarning

    try:
        data = json.loads(Path(path).read_text())
    except (OSError, ValueError, RecursionError):  # RecursionError: nested thousands deep (the reader says so)
        return
    if not isinstance(data, dict):
        return
    sfm = data.get("sfm") if isinstance(data.get("sfm"), dict) else {}
    if SFM_UNITS not in (data.get("scale"), sfm.get("scale")):
        return
    warnings.warn(f"{path}: the poses are in SfM units, not metres (data poses found no depth, --depth-prior, "
                  "--camera-height or --scale to fix the scale), so renders and the depth-scale search from them are "
                  "unreliable: run data poses again with one of those (and --overwrite)", ScaleWarning, stacklevel=2)
