"""stella_vslam / OpenVSLAM keyframe trajectories: TUM and KITTI text files.

=====================  ===================================================================================
File                   ``TUM``: lines ``timestamp tx ty tz qx qy qz qw``; ``KITTI``: lines of 12 numbers, a
                       row-major 3x4 (``save_keyframe_trajectory(path, "TUM" | "KITTI")``); ``#`` comments
Pose                   camera-to-world, camera axes x right, y down, z forward
Panorama pixels        stella_vslam's equirectangular model is ours exactly
To ours                used as they are
Order                  file order; no image names: :func:`match_timestamps_to_images` pairs them with a
                       folder's images (in name order, or TUM timestamps by frame rate)
=====================  ===================================================================================
"""

from __future__ import annotations

import math
from pathlib import Path

import torch

from ...geometry.rotations import quaternion_xyzw_to_matrix
from .conventions import PoseRecord, check_pose, check_scale, parse_pose_matrix, scaled

__all__ = ["read_tum", "read_kitti", "match_timestamps_to_images"]


def _numeric_lines(path: Path, count: int, what: str) -> list[list[float]]:
    if not path.is_file():
        raise FileNotFoundError(f"missing trajectory file: {path}")
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            values = [float(v) for v in line.replace(",", " ").split()]
        except ValueError:
            raise ValueError(f"{path} line {number}: not numbers: {line[:80]!r}") from None
        if len(values) != count or not all(math.isfinite(v) for v in values):
            raise ValueError(f"{path} line {number}: a {what} line has {count} finite numbers, got {len(values)}")
        rows.append(values)
    if not rows:
        raise ValueError(f"{path}: no poses")
    return rows


def read_tum(path: str | Path, scale: float = 1.0) -> list[PoseRecord]:
    """TUM trajectory (``timestamp tx ty tz qx qy qz qw``, camera-to-world; stella_vslam's
    ``save_keyframe_trajectory(..., "TUM")``), in file order."""
    path = Path(path)
    scale = check_scale(scale)
    records = []
    for row in _numeric_lines(path, 8, "TUM"):
        where = f"{path} pose {len(records)} (timestamp {row[0]:g})"
        try:
            rotation = quaternion_xyzw_to_matrix(row[4:])
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
        c2w = torch.eye(4, dtype=torch.float64)
        c2w[:3, :3], c2w[:3, 3] = rotation, torch.tensor(row[1:4], dtype=torch.float64)
        records.append(PoseRecord(None, check_pose(scaled(c2w, scale), where), timestamp=row[0]))
    return records


def read_kitti(path: str | Path, scale: float = 1.0) -> list[PoseRecord]:
    """KITTI trajectory (12 numbers a line: the first three rows of a camera-to-world matrix), in file order."""
    path = Path(path)
    scale = check_scale(scale)
    records = []
    for i, row in enumerate(_numeric_lines(path, 12, "KITTI")):
        where = f"{path} pose {i}"
        records.append(PoseRecord(None, check_pose(scaled(parse_pose_matrix([row[0:4], row[4:8], row[8:12]], where),
                                                          scale), where)))
    return records


def match_timestamps_to_images(records: list[PoseRecord], images: list[str], fps: float | None, source: Path,
                               start: float | str = 0.0) -> list[PoseRecord]:
    """Give trajectory poses their image names: with ``fps``, pose at time ``t`` is image ``round((t - start) * fps)``
    of ``images`` (frames numbered from 0, as stella_vslam's examples time a video or image sequence); ``start`` is
    the time of image 0 in seconds, or ``"first"``: the trajectory's first timestamp (SLAM runs that stamp poses
    with the clock). Without ``fps``, poses and images pair up in order (the counts must agree)."""
    if fps is None:
        if len(images) != len(records):
            raise ValueError(f"{source} has {len(records)} poses but {len(images)} images were given; pass --fps to "
                             "match timestamps to frame numbers, or give exactly one image per pose")
        return [PoseRecord(name, r.c2w, r.depth, r.timestamp) for name, r in zip(images, records)]
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if any(r.timestamp is None for r in records):
        raise ValueError(f"{source}: --fps needs timestamps (a TUM trajectory)")
    if start == "first":
        start = min(r.timestamp for r in records)
    elif isinstance(start, str):
        raise ValueError(f"the start time must be seconds or 'first', got {start!r}")
    out = []
    for r in records:
        index = math.floor((r.timestamp - start) * fps + 0.5)
        if not 0 <= index < len(images):
            clock = "; clock timestamps? --start-time first counts from the first pose" if start == 0 else ""
            raise ValueError(f"{source}: timestamp {r.timestamp:g} s is frame {index} at {fps:g} fps, but only "
                             f"{len(images)} images were given (image 0 is at {start:g} s{clock})")
        out.append(PoseRecord(images[index], r.c2w, r.depth, r.timestamp))
    return out
