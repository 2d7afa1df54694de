"""Camera poses of 360° panoramas as other tools write them -> our OpenCV camera-to-world ``c2w``.

This module owns every pose convention conversion of the package: :func:`to_opencv_c2w` (OpenGL/Blender camera
axes and world-to-camera matrices, the ``"convention"`` of our ``poses.json``) and :func:`parse_pose_matrix` (a
3x4/4x4 list checked to be a rigid pose); ``data.folder`` (our poses files) and the readers below use them.

Every reader returns ``PoseRecord``s: an image name (or ``None``), a 4x4 float64 OpenCV c2w (camera
+x right, +y down, +z forward; :doc:`docs/conventions.md`), an optional depth file and, for
trajectories, a timestamp. What each tool means by a pose and by its panorama's pixels (checked
against each tool's own projection formulas in ``tests/test_pose_formats.py``):

* **nerfstudio** ``transforms.json`` with ``"camera_model": "EQUIRECTANGULAR"``: ``transform_matrix``
  is an OpenGL camera-to-world (+y up, +z back); its equirect model puts the panorama's centre
  column on -z and the top row on +y, which is our panorama turned into OpenGL axes, so
  ``c2w = transform_matrix @ diag(1, -1, -1, 1)``.
* **OpenSfM** ``reconstruction.json`` (``projection_type`` ``spherical``/``equirectangular``): each shot
  stores the world-to-camera rotation as an angle-axis vector and the translation
  (``x_cam = R x_world + t``) in a camera frame x right, y down, z forward whose spherical model is
  ours exactly, so ``c2w = [R^T | -R^T t]``.
* **stella_vslam / OpenVSLAM** keyframe trajectories: ``TUM`` lines ``timestamp tx ty tz qx qy qz qw`` and
  ``KITTI`` lines (12 numbers, a row-major 3x4) are camera-to-world in a camera frame x right, y down,
  z forward whose equirect model is ours exactly, so they are used as they are.

SfM and SLAM reconstructions have an arbitrary scale unless they were given one (GPS, a known
distance); ``scale`` multiplies every camera position (metres per reconstruction unit).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..geometry import validate_c2w
from ..utils.atomic import atomic_write_text
from ..utils.jsonfile import read_json_file

__all__ = [
    "POSE_CONVENTIONS",
    "to_opencv_c2w",
    "parse_pose_matrix",
    "PoseRecord",
    "EQUIRECT_CAMERA_MODELS",
    "is_transforms_json",
    "read_transforms_json",
    "read_opensfm",
    "read_tum",
    "read_kitti",
    "axis_angle_to_matrix",
    "quaternion_xyzw_to_matrix",
    "write_poses_json",
    "match_timestamps_to_images",
]

_GL_TO_CV = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))  # +y up, +z back -> +y down, +z forward
# What a 4x4 pose may mean ("convention" of a poses file): camera axes OpenCV or OpenGL/Blender, c2w or w2c.
POSE_CONVENTIONS = ("opencv_c2w", "opengl_c2w", "blender_c2w", "opencv_w2c", "opengl_w2c")
EQUIRECT_CAMERA_MODELS = ("EQUIRECTANGULAR",)  # nerfstudio's name for 360° panoramas
OPENSFM_SPHERICAL = ("spherical", "equirectangular")


@dataclass
class PoseRecord:
    """One camera: ``image`` (relative file name or ``None``), OpenCV ``c2w`` (4x4), ``depth`` file,
    ``timestamp`` (trajectories)."""

    image: str | None
    c2w: Tensor
    depth: str | None = None
    timestamp: float | None = None


def _all_numbers(value) -> bool:
    """Nested lists of JSON numbers only (no strings, booleans or nulls, which torch would convert or choke on)."""
    if isinstance(value, list):
        return all(_all_numbers(v) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def parse_pose_matrix(value, where: str) -> Tensor:
    """A 3x4 or 4x4 nested list -> 4x4 float64, checked: finite, a rotation (det +1), last row ``0 0 0 1``;
    ``ValueError`` naming ``where`` otherwise."""
    if not isinstance(value, list) or not _all_numbers(value):
        raise ValueError(f"{where}: pose must be a 3x4 or 4x4 list of numbers, got {value!r:.80}")
    try:
        m = torch.tensor(value, dtype=torch.float64)
    except (TypeError, ValueError) as exc:  # ragged rows
        raise ValueError(f"{where}: pose must be a 3x4 or 4x4 list of numbers ({exc})") from None
    if m.shape == (3, 4):
        m = torch.cat((m, torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=m.dtype)))
    if m.shape != (4, 4):
        raise ValueError(f"{where}: pose must be 3x4 or 4x4, got shape {tuple(m.shape)}")
    validate_c2w(m, name=where)  # finite, rotation (det +1), last row 0 0 0 1
    return m


def to_opencv_c2w(pose: Tensor, convention: str) -> Tensor:
    """A rigid 4x4 ``pose`` meant as ``convention`` (one of :data:`POSE_CONVENTIONS`) -> OpenCV camera-to-world:
    a world-to-camera matrix is inverted (``[R^T | -R^T t]``), OpenGL/Blender camera axes (+y up, +z back) are
    turned into OpenCV's (+y down, +z forward) by ``c2w @ diag(1, -1, -1, 1)``."""
    if convention not in POSE_CONVENTIONS:
        raise ValueError(f"unknown pose convention {convention!r}; use one of {list(POSE_CONVENTIONS)}")
    if convention.endswith("_w2c"):
        rot, t = pose[:3, :3], pose[:3, 3]
        pose = torch.eye(4, dtype=pose.dtype)
        pose[:3, :3], pose[:3, 3] = rot.T, -rot.T @ t
    if convention.startswith(("opengl", "blender")):
        pose = pose @ _GL_TO_CV.to(pose.dtype)
    return pose


def _scaled(c2w: Tensor, scale: float) -> Tensor:
    c2w = c2w.clone()
    c2w[:3, 3] *= scale
    return c2w


def _check_scale(scale: float) -> float:
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale <= 0:
        raise ValueError(f"scale must be a positive number (metres per unit), got {scale!r}")
    return float(scale)


def _load_json(path: Path):
    return read_json_file(path, "poses file")


# --- nerfstudio ---------------------------------------------------------------------------------------


def is_transforms_json(data) -> bool:
    """Whether parsed JSON looks like a nerfstudio ``transforms.json`` (frames with ``transform_matrix``)."""
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        return False
    return "camera_model" in data or any(isinstance(f, dict) and "transform_matrix" in f for f in data["frames"])


def read_transforms_json(path: str | Path, scale: float = 1.0, data=None) -> list[PoseRecord]:
    """Frames of a nerfstudio ``transforms.json`` of equirectangular panoramas, sorted by file name (as
    nerfstudio does); ``file_path``/``depth_file_path`` stay relative to the file's folder.

    Any other ``camera_model`` (perspective ``OPENCV``, fisheye, ...) is an error: the model needs 360° panoramas.
    """
    path = Path(path)
    scale = _check_scale(scale)
    data = _load_json(path) if data is None else data
    if not is_transforms_json(data):
        raise ValueError(f'{path}: not a nerfstudio transforms.json (expected "frames" with "transform_matrix")')
    records = []
    for i, frame in enumerate(data["frames"]):
        where = f"{path} frame {i}"
        if not isinstance(frame, dict) or "transform_matrix" not in frame or "file_path" not in frame:
            raise ValueError(f'{where}: each frame needs "file_path" and "transform_matrix"')
        model = frame.get("camera_model", data.get("camera_model"))
        if model is None:
            raise ValueError(f"{path}: no camera_model (nerfstudio then assumes perspective images); cylindersplat needs "
                             '360° equirectangular panoramas: "camera_model": "EQUIRECTANGULAR"')
        if str(model).upper() not in EQUIRECT_CAMERA_MODELS:
            raise ValueError(f"{where}: camera_model {model!r} is not a 360° panorama; cylindersplat needs "
                             '"camera_model": "EQUIRECTANGULAR" (equirectangular images, W = 2H)')
        w, h = frame.get("w", data.get("w")), frame.get("h", data.get("h"))
        if w is not None and h is not None and (not isinstance(w, (int, float)) or not isinstance(h, (int, float)) or w != 2 * h):
            raise ValueError(f"{where}: an equirectangular image must be twice as wide as high, got w={w!r}, h={h!r}")
        for key in ("file_path", "depth_file_path"):
            if frame.get(key) is not None and not isinstance(frame[key], str):
                raise ValueError(f'{where}: "{key}" must be a file name, got {frame[key]!r}')
        c2w = _scaled(to_opencv_c2w(parse_pose_matrix(frame["transform_matrix"], where), "opengl_c2w"), scale)
        records.append(PoseRecord(frame["file_path"], c2w, frame.get("depth_file_path")))
    if not records:
        raise ValueError(f"{path}: no frames")
    return sorted(records, key=lambda r: r.image)


# --- OpenSfM ------------------------------------------------------------------------------------------


def axis_angle_to_matrix(r) -> Tensor:
    """Rodrigues: rotation vector (axis * angle in radians) -> 3x3 rotation (float64)."""
    r = torch.as_tensor(r, dtype=torch.float64)
    angle = float(torch.linalg.vector_norm(r))
    if angle < 1e-12:
        return torch.eye(3, dtype=torch.float64)
    k = r / angle
    kx = torch.tensor([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]], dtype=torch.float64)
    return torch.eye(3, dtype=torch.float64) + math.sin(angle) * kx + (1 - math.cos(angle)) * kx @ kx


def read_opensfm(path: str | Path, scale: float = 1.0, reconstruction: int = 0) -> list[PoseRecord]:
    """Shots of one reconstruction (default the first, OpenSfM's largest) of an OpenSfM/OpenDroneMap
    ``reconstruction.json``, sorted by image name; every shot's camera must be spherical/equirectangular."""
    path = Path(path)
    scale = _check_scale(scale)
    data = _load_json(path)
    if isinstance(data, dict):
        data = [data]
    if not isinstance(data, list) or not data or not all(isinstance(r, dict) and "shots" in r for r in data):
        raise ValueError(f'{path}: not an OpenSfM reconstruction.json (a list of reconstructions with "cameras" and "shots")')
    if not 0 <= reconstruction < len(data):
        raise ValueError(f"{path} holds {len(data)} reconstruction(s); --reconstruction {reconstruction} does not exist")
    rec = data[reconstruction]
    cameras = rec.get("cameras", {})
    records = []
    for name, shot in sorted(rec["shots"].items()):
        where = f"{path} shot {name!r}"
        camera = cameras.get(shot.get("camera"), {})
        projection = camera.get("projection_type")
        if projection not in OPENSFM_SPHERICAL:
            raise ValueError(f"{where}: camera {shot.get('camera')!r} has projection_type {projection!r}; cylindersplat needs "
                             "360° panoramas (projection_type spherical or equirectangular)")
        try:
            rot = axis_angle_to_matrix(shot["rotation"])
            t = torch.tensor(shot["translation"], dtype=torch.float64)
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise ValueError(f'{where}: needs "rotation" (angle-axis, 3 numbers) and "translation" (3 numbers) ({exc})') from None
        if rot.shape != (3, 3) or t.shape != (3,) or not torch.isfinite(t).all() or not torch.isfinite(rot).all():
            raise ValueError(f'{where}: "rotation" and "translation" must be 3 finite numbers each')
        w2c = torch.eye(4, dtype=torch.float64)
        w2c[:3, :3], w2c[:3, 3] = rot, t  # x_cam = R x_world + t, OpenCV camera axes
        records.append(PoseRecord(name, _scaled(to_opencv_c2w(w2c, "opencv_w2c"), scale)))
    if not records:
        raise ValueError(f"{path}: reconstruction {reconstruction} has no shots")
    return records


# --- stella_vslam / OpenVSLAM trajectories ------------------------------------------------------------


def quaternion_xyzw_to_matrix(q) -> Tensor:
    """Unit quaternion ``(qx, qy, qz, qw)`` (TUM order; normalised here) -> 3x3 rotation (float64)."""
    x, y, z, w = (float(v) for v in q)
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not n > 1e-9:
        raise ValueError(f"quaternion {q} has no length")
    x, y, z, w = x / n, y / n, z / n, w / n
    return torch.tensor([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ], dtype=torch.float64)


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
    scale = _check_scale(scale)
    records = []
    for row in _numeric_lines(path, 8, "TUM"):
        c2w = torch.eye(4, dtype=torch.float64)
        c2w[:3, :3], c2w[:3, 3] = quaternion_xyzw_to_matrix(row[4:]), torch.tensor(row[1:4], dtype=torch.float64)
        records.append(PoseRecord(None, _scaled(c2w, scale), timestamp=row[0]))
    return records


def read_kitti(path: str | Path, scale: float = 1.0) -> list[PoseRecord]:
    """KITTI trajectory (12 numbers a line: the first three rows of a camera-to-world matrix), in file order."""
    path = Path(path)
    scale = _check_scale(scale)
    return [PoseRecord(None, _scaled(parse_pose_matrix([row[0:4], row[4:8], row[8:12]], f"{path} pose {i}"), scale))
            for i, row in enumerate(_numeric_lines(path, 12, "KITTI"))]


def match_timestamps_to_images(records: list[PoseRecord], images: list[str], fps: float | None, source: Path,
                               start: float | str = 0.0) -> list[PoseRecord]:
    """Give trajectory poses their image names: with ``fps``, pose at time ``t`` is image ``round((t - start) * fps)``
    of ``images`` (frames numbered from 0, as stella_vslam's examples time a video or image sequence); ``start`` is
    the time of image 0 in seconds, or ``"first"``: the trajectory's first timestamp (SLAM runs that stamp poses
    with the clock). Without ``fps``, poses and images pair up in order (the counts must agree)."""
    if fps is None:
        if len(images) != len(records):
            raise ValueError(f"{source} has {len(records)} poses but {len(images)} images were given; pass --fps to match "
                             "timestamps to frame numbers, or give exactly one image per pose")
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


# --- writing ------------------------------------------------------------------------------------------


def write_poses_json(path: str | Path, records: list[PoseRecord], depth_scale: float | None = None, **extra) -> Path:
    """Write ``records`` as our ``poses.json`` (OpenCV c2w): ``"frames"`` when every record names its image,
    else ``"poses"`` (matched to a folder's images in name order). ``extra`` keys are stored as they are
    (readers ignore keys they do not know). Written atomically."""
    if not records:
        raise ValueError("no poses to write")
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
