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

* **COLMAP** sparse models (``images.txt``/``.bin``: ``cam_from_world`` as quaternion ``w x y z`` and
  translation, OpenCV camera axes; its ``EQUIRECTANGULAR`` camera is our panorama exactly), so
  ``c2w = [R^T | -R^T t]``; models of virtual pinhole cameras cut from panoramas (COLMAP's panorama workflow)
  give each panorama's pose (:func:`panoramas_from_virtual_cameras`).
* **Agisoft Metashape** camera XML: ``<transform>`` is camera-to-chunk (OpenCV camera axes), then the chunk's and
  component's similarity; its spherical sensor projects as ours does.
* **OpenMVG** ``sfm_data.json``: ``rotation`` R (world-to-camera) and ``center`` C; its spherical camera puts the
  top row on +y, so the world is mirrored back with ``diag(1, -1, 1)`` (:func:`openmvg_to_c2w`).

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
    "quaternion_wxyz_to_matrix",
    "matrix_to_quaternion_wxyz",
    "COLMAP_EQUIRECT_MODELS",
    "colmap_to_c2w",
    "c2w_to_colmap",
    "read_colmap",
    "write_colmap",
    "panoramas_from_virtual_cameras",
    "metashape_to_c2w",
    "read_metashape_xml",
    "write_metashape_xml",
    "openmvg_to_c2w",
    "c2w_to_openmvg",
    "read_openmvg",
    "write_openmvg",
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


# --- shared rotation helpers --------------------------------------------------------------------------


def quaternion_wxyz_to_matrix(q) -> Tensor:
    """Unit quaternion ``(qw, qx, qy, qz)`` (COLMAP's order; normalised here) -> 3x3 rotation (float64)."""
    w, x, y, z = (float(v) for v in q)
    return quaternion_xyzw_to_matrix((x, y, z, w))


def matrix_to_quaternion_wxyz(rot) -> np.ndarray:
    """3x3 rotation -> unit quaternion ``(qw, qx, qy, qz)`` with ``qw >= 0`` (float64; Shepperd's method)."""
    m = np.asarray(rot, dtype=np.float64)
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.array(q) / np.linalg.norm(q)
    return -q if q[0] < 0 else q


def _w2c_to_c2w(rot: Tensor, t: Tensor) -> Tensor:
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[:3, :3], c2w[:3, 3] = rot.T, -rot.T @ t
    return c2w


def _nearest_rotation(m: np.ndarray) -> np.ndarray:
    """The rotation nearest to ``m`` (3x3) in the Frobenius sense: the chordal mean of a sum of rotations."""
    u, _, vt = np.linalg.svd(m)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


# --- COLMAP -------------------------------------------------------------------------------------------

# COLMAP's 360° camera model: EQUIRECTANGULAR (pycolmap 4.2.1, params w, h); SPHERICAL is the later name.
COLMAP_EQUIRECT_MODELS = ("EQUIRECTANGULAR", "SPHERICAL")


def colmap_to_c2w(qvec, tvec) -> Tensor:
    """COLMAP's ``cam_from_world`` (quaternion ``w, x, y, z`` and translation: ``x_cam = R x_world + t``) -> OpenCV
    c2w. COLMAP's camera frame is OpenCV's (x right, y down, z forward), and its EQUIRECTANGULAR model maps pixels to
    rays exactly as ours does (centre column +z, top row -y, longitude growing to the right, pixel centres at
    +0.5; checked against pycolmap's ``Camera.cam_ray_from_img`` in tests/test_pose_files.py), so no axis change."""
    return _w2c_to_c2w(quaternion_wxyz_to_matrix(qvec), torch.as_tensor(np.asarray(tvec, dtype=np.float64)))


def c2w_to_colmap(c2w) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV c2w -> COLMAP ``(qvec wxyz, tvec)`` of ``cam_from_world`` (the inverse of :func:`colmap_to_c2w`)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    rot = c2w[:3, :3].T
    return matrix_to_quaternion_wxyz(rot), -rot @ c2w[:3, 3]


def read_colmap(path: str | Path, scale: float = 1.0) -> list[PoseRecord]:
    """Panorama poses of a COLMAP sparse model (``.txt`` or ``.bin``; a model folder or one holding ``sparse/0``),
    sorted by image name.

    * ``EQUIRECTANGULAR`` (or ``SPHERICAL``) cameras: one record per image (:func:`colmap_to_c2w`).
    * Perspective cameras cut from panoramas (COLMAP's panorama workflow, ``python/examples/panorama_sfm.py``:
      images ``<virtual camera folder>/<panorama name>``, several per panorama, one shared centre): one record per
      panorama, its pose recovered by :func:`panoramas_from_virtual_cameras`.
    """
    from .colmap_model import read_colmap_model

    scale = _check_scale(scale)
    model = read_colmap_model(path, points=False)
    if not model.images:
        raise ValueError(f"{path}: the COLMAP model has no registered images")
    spherical = {i for i, c in model.cameras.items() if c.model.upper() in COLMAP_EQUIRECT_MODELS}
    for i, c in model.cameras.items():
        if i in spherical and c.width != 2 * c.height:
            raise ValueError(f"{path}: camera {i} is {c.model} {c.width}x{c.height}; an equirectangular panorama "
                             "must be twice as wide as high")
    if all(im.camera_id in spherical for im in model.images.values()):
        records = [PoseRecord(im.name, _scaled(colmap_to_c2w(im.qvec, im.tvec), scale)) for im in model.images.values()]
        return sorted(records, key=lambda r: r.image)
    if spherical:
        raise ValueError(f"{path}: the model mixes equirectangular and perspective cameras; export the panoramas' "
                         "images only")
    cams = [(im.name, colmap_to_c2w(im.qvec, im.tvec)) for im in model.images.values()]
    records = panoramas_from_virtual_cameras(cams, str(path))
    return [PoseRecord(r.image, _scaled(r.c2w, scale)) for r in records]


def _virtual_camera_key(name: str) -> tuple[str, str] | None:
    """``"pano_camera3/hall.jpg"`` -> ``("pano_camera3", "hall.jpg")``: the virtual camera's folder and the panorama."""
    folder, sep, rest = name.partition("/")
    return (folder, rest) if sep and rest else None


def _natural(text: str):
    import re

    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", text)]


def panoramas_from_virtual_cameras(cameras: list[tuple[str, Tensor]], where: str = "model") -> list[PoseRecord]:
    """Panorama poses from perspective images cut out of them, as COLMAP's panorama workflow names and rigs them.

    ``cameras``: ``(name, c2w)`` of images named ``<virtual camera>/<panorama>`` (``pano_camera0/hall.jpg``, ...).
    What is assumed, as that workflow makes its virtual cameras (``get_virtual_rotations``: each is the panorama
    turned by a yaw about its vertical axis, then tilted by a pitch, no roll; the reference camera, the first
    folder in natural order, has yaw 0): (1) the panorama's vertical is the one direction that is level (no x
    component) in every virtual camera: the null vector of their rows ``x`` in the reference camera's frame;
    (2) the panorama's centre column lies in the reference camera's vertical plane. Then ``cam0_from_pano`` is a
    pure pitch, and each panorama's pose is the chordal mean over its virtual cameras of
    ``c2w_i @ cam_i_from_pano`` (centres: their mean).
    """
    groups: dict[str, dict[str, Tensor]] = {}
    for name, c2w in cameras:
        key = _virtual_camera_key(name)
        if key is None:
            raise ValueError(f"{where}: image {name!r} has a perspective camera and is not named <virtual camera>/"
                             "<panorama> as COLMAP's panorama workflow names the cameras it cuts out of a panorama; "
                             "cylindersplat needs equirectangular cameras (EQUIRECTANGULAR) or such virtual cameras")
        groups.setdefault(key[1], {})[key[0]] = c2w.to(torch.float64)
    folders = sorted({f for views in groups.values() for f in views}, key=_natural)
    if len(folders) < 2:
        raise ValueError(f"{where}: only one virtual camera per panorama ({folders[0]}); a panorama's pose needs "
                         "at least two of its virtual cameras")
    ref = folders[0]
    # cam_i_from_cam0 = R_i^T-world ... from every panorama that has both (rigid rigs: all the same).
    sums = {f: np.zeros((3, 3)) for f in folders}
    for views in groups.values():
        if ref not in views:
            continue
        r0 = views[ref][:3, :3].numpy()
        for f, c2w in views.items():
            sums[f] += c2w[:3, :3].numpy().T @ r0  # cam_f_from_cam0
    if any(not sums[f].any() for f in folders):
        raise ValueError(f"{where}: some virtual cameras never appear with {ref!r} in one panorama; cannot relate them")
    cam_from_ref = {f: _nearest_rotation(s) for f, s in sums.items()}
    rows = np.stack([cam_from_ref[f][0] for f in folders])  # each camera's x axis in the reference frame
    _, singular, vt = np.linalg.svd(rows)
    down = vt[-1] * (1.0 if vt[-1][1] >= 0 else -1.0)  # the panorama's +y (down) in cam0, pitch within +-90 deg
    if singular[-1] > 0.05 * math.sqrt(len(folders)):
        raise ValueError(f"{where}: the virtual cameras share no level axis (they roll); cannot recover the "
                         "panoramas' poses from them")
    a = math.atan2(down[2], down[1])
    ref_from_pano = np.array([[1.0, 0.0, 0.0], [0.0, math.cos(a), -math.sin(a)], [0.0, math.sin(a), math.cos(a)]])
    records = []
    for pano, views in sorted(groups.items()):
        rot, centre = np.zeros((3, 3)), np.zeros(3)
        for f, c2w in views.items():
            rot += c2w[:3, :3].numpy() @ cam_from_ref[f] @ ref_from_pano  # world_from_cam_f @ cam_f_from_pano
            centre += c2w[:3, 3].numpy()
        c2w = torch.eye(4, dtype=torch.float64)
        c2w[:3, :3] = torch.from_numpy(_nearest_rotation(rot))
        c2w[:3, 3] = torch.from_numpy(centre / len(views))
        records.append(PoseRecord(pano, c2w))
    return records


def write_colmap(folder: str | Path, records: list[PoseRecord], width: int, height: int, kind: str = "txt") -> Path:
    """``records`` (named OpenCV c2w) as a COLMAP sparse model of one ``EQUIRECTANGULAR`` camera
    (``width`` x ``height``), without 3-D points; images numbered from 1 in ``records`` order."""
    from .colmap_model import ColmapCamera, ColmapImage, ColmapModel, write_colmap_model

    if any(r.image is None for r in records):
        raise ValueError("COLMAP images need names: every pose needs its image")
    images = {}
    for i, r in enumerate(records, 1):
        qvec, tvec = c2w_to_colmap(r.c2w)
        images[i] = ColmapImage(r.image, 1, qvec, tvec)
    return write_colmap_model(folder, ColmapModel({1: ColmapCamera("EQUIRECTANGULAR", width, height,
                                                                   [float(width), float(height)])}, images, {}), kind)


# --- Agisoft Metashape --------------------------------------------------------------------------------


def _floats(text: str | None, count: int, where: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in (text or "").split()], dtype=np.float64)
    except ValueError:
        raise ValueError(f"{where}: expected {count} numbers, got {(text or '')[:60]!r}") from None
    if values.size != count or not np.isfinite(values).all():
        raise ValueError(f"{where}: expected {count} finite numbers, got {values.size}")
    return values


def _metashape_component(element, where: str) -> np.ndarray:
    """A chunk's or component's ``<transform>`` (``rotation`` 9, ``translation`` 3, ``scale`` 1) as the 4x4
    similarity from the chunk's local frame to its world; identity where there is none."""
    out = np.eye(4)
    transform = element.find("transform") if element is not None else None
    if transform is None:
        return out
    rot, trans, scale = transform.find("rotation"), transform.find("translation"), transform.find("scale")
    if rot is not None:
        out[:3, :3] = _floats(rot.text, 9, f"{where} <rotation>").reshape(3, 3)
    if scale is not None:
        out[:3, :3] *= _floats(scale.text, 1, f"{where} <scale>")[0]
    if trans is not None:
        out[:3, 3] = _floats(trans.text, 3, f"{where} <translation>")
    return out


def metashape_to_c2w(transform, chunk=None) -> Tensor:
    """A Metashape camera ``<transform>`` (4x4 camera-to-chunk-local, camera axes x right, y down, z forward) and
    its chunk/component similarity ``chunk`` (4x4, scale included) -> OpenCV c2w in the chunk's world frame.

    The similarity's scale multiplies positions only; rotations keep their unit length. Metashape's spherical
    sensor maps a ray ``(X, Y, Z)`` to ``u = w/2 + w/(2 pi) atan2(X, Z)``, ``v = h/2 + w/(2 pi) atan2(Y, sqrt(X^2 +
    Z^2))`` (the user manual's camera-model appendix): ours, so no axis change."""
    t = np.asarray(transform, dtype=np.float64).reshape(4, 4)
    m = (np.eye(4) if chunk is None else np.asarray(chunk, dtype=np.float64)) @ t
    scale = np.cbrt(np.linalg.det(m[:3, :3]))
    if not scale > 0:
        raise ValueError("Metashape transform is not a rotation (determinant <= 0)")
    c2w = torch.from_numpy(m.copy())
    c2w[:3, :3] /= scale
    c2w[3] = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)
    return c2w


def read_metashape_xml(path: str | Path, scale: float = 1.0) -> list[PoseRecord]:
    """Aligned cameras of an Agisoft Metashape camera XML (File > Export > Export Cameras), sorted by label; every
    camera's sensor must be ``type="spherical"``. Cameras without a ``<transform>`` (not aligned) are skipped;
    the chunk's (and each component's) ``<transform>`` is applied, so positions are in the chunk's world units.
    ``image`` is the camera's ``label`` (the photo's file name, usually without its folder, sometimes without
    its suffix)."""
    import xml.etree.ElementTree as ET

    path = Path(path)
    scale = _check_scale(scale)
    if not path.is_file():
        raise FileNotFoundError(f"missing Metashape XML: {path}")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise ValueError(f"{path}: not an XML file ({exc})") from None
    chunk = root if root.tag == "chunk" else root.find("chunk")
    if chunk is None or chunk.find("cameras") is None:
        raise ValueError(f"{path}: not a Metashape camera XML (expected <document><chunk> with <sensors> and <cameras>)")
    sensors = {s.get("id"): (s.get("type") or "frame") for s in chunk.iter("sensor")}
    chunk_transform = _metashape_component(chunk, f"{path} chunk")
    components = {c.get("id"): _metashape_component(c, f"{path} component {c.get('id')}") for c in chunk.iter("component")}
    records = []
    for camera in chunk.find("cameras").iter("camera"):
        label = camera.get("label")
        where = f"{path} camera {label!r}"
        transform = camera.find("transform")
        if transform is None:
            continue  # not aligned
        kind = sensors.get(camera.get("sensor_id"))
        if kind != "spherical":
            raise ValueError(f"{where}: sensor {camera.get('sensor_id')!r} is of type {kind!r}; cylindersplat needs "
                             '360° panoramas (sensor type="spherical")')
        component = components.get(camera.get("component_id"))
        similarity = chunk_transform @ component if component is not None else chunk_transform
        c2w = metashape_to_c2w(_floats(transform.text, 16, f"{where} <transform>"), similarity)
        records.append(PoseRecord(label, _scaled(c2w, scale)))
    if not records:
        raise ValueError(f"{path}: no aligned camera (no <camera> with a <transform>)")
    return sorted(records, key=lambda r: r.image)


def write_metashape_xml(path: str | Path, records: list[PoseRecord], width: int, height: int) -> Path:
    """``records`` as a Metashape camera XML with one spherical sensor (``width`` x ``height``) and no chunk
    transform (camera transforms are in our world frame). Written atomically."""
    import xml.etree.ElementTree as ET

    document = ET.Element("document", version="1.5.0")
    chunk = ET.SubElement(document, "chunk", label="cylindersplat", enabled="true")
    sensors = ET.SubElement(chunk, "sensors", next_id="1")
    sensor = ET.SubElement(sensors, "sensor", id="0", label="equirectangular", type="spherical")
    ET.SubElement(sensor, "resolution", width=str(width), height=str(height))
    cameras = ET.SubElement(chunk, "cameras", next_id=str(len(records)))
    for i, r in enumerate(records):
        camera = ET.SubElement(cameras, "camera", id=str(i), sensor_id="0", label=str(r.image))
        ET.SubElement(camera, "transform").text = " ".join(repr(float(v)) for v in r.c2w.reshape(-1).tolist())
    ET.indent(document)
    return atomic_write_text(path, '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(document, "unicode") + "\n")


# --- OpenMVG ------------------------------------------------------------------------------------------

# OpenMVG's spherical camera (Camera_Spherical.hpp) maps a ray (x, y, z) to lon = atan2(x, z),
# lat = atan2(-y, sqrt(x^2 + z^2)), u = w/2 + w lon / (2 pi), v = h/2 + w lat / (2 pi): its top row looks along
# +y. Ours looks along -y there, so an OpenMVG spherical reconstruction is our world seen in a mirror that flips y;
# reflecting the world back (x_ours = S x_mvg) keeps every pixel where it is and makes the rotations proper again.
_OPENMVG_MIRROR = np.diag([1.0, -1.0, 1.0])


def openmvg_to_c2w(rotation, center) -> Tensor:
    """An OpenMVG pose (``rotation`` R world-to-camera, ``center`` C: ``x_cam = R (X - C)``) of a spherical camera
    -> OpenCV c2w in the mirrored-back world ``S X`` (``S = diag(1, -1, 1)``): ``[S R^T S | S C]``."""
    rot = np.asarray(rotation, dtype=np.float64).reshape(3, 3)
    centre = np.asarray(center, dtype=np.float64).reshape(3)
    s = _OPENMVG_MIRROR
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[:3, :3] = torch.from_numpy(s @ rot.T @ s)
    c2w[:3, 3] = torch.from_numpy(s @ centre)
    return c2w


def c2w_to_openmvg(c2w) -> tuple[np.ndarray, np.ndarray]:
    """The inverse of :func:`openmvg_to_c2w`: ``(rotation, center)``."""
    c2w = np.asarray(c2w, dtype=np.float64)
    s = _OPENMVG_MIRROR
    return s @ c2w[:3, :3].T @ s, s @ c2w[:3, 3]


def _cereal_data(entry: dict) -> dict:
    value = entry.get("value", entry)
    wrapper = value.get("ptr_wrapper", value) if isinstance(value, dict) else {}
    return wrapper.get("data", wrapper) if isinstance(wrapper, dict) else {}


def read_openmvg(path: str | Path, scale: float = 1.0) -> list[PoseRecord]:
    """Posed views of an OpenMVG ``sfm_data.json`` (cereal JSON: ``views``, ``intrinsics``, ``extrinsics``), sorted
    by file name; every posed view's intrinsic must be ``spherical``. Views without a pose are skipped."""
    path = Path(path)
    scale = _check_scale(scale)
    data = _load_json(path)
    if not isinstance(data, dict) or not all(isinstance(data.get(k), list) for k in ("views", "intrinsics", "extrinsics")):
        raise ValueError(f'{path}: not an OpenMVG sfm_data.json (expected "views", "intrinsics" and "extrinsics" lists)')
    names_by_id: dict[int, str] = {}
    kinds = {}
    for entry in data["intrinsics"]:
        value = entry.get("value", {})
        poly_id, name = value.get("polymorphic_id"), value.get("polymorphic_name")
        if isinstance(poly_id, int) and name:  # cereal names a type once, then refers to it by id (high bit cleared)
            names_by_id[poly_id & 0x7FFFFFFF] = name
        kinds[entry.get("key")] = name or names_by_id.get((poly_id or 0) & 0x7FFFFFFF)
    poses = {}
    for entry in data["extrinsics"]:
        value = entry.get("value", {})
        where = f"{path} extrinsic {entry.get('key')}"
        try:
            rot, centre = np.array(value["rotation"], dtype=np.float64), np.array(value["center"], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f'{where}: needs "rotation" (3x3) and "center" (3 numbers)') from None
        if rot.shape != (3, 3) or centre.shape != (3,) or not (np.isfinite(rot).all() and np.isfinite(centre).all()):
            raise ValueError(f'{where}: "rotation" must be 3x3 and "center" 3 finite numbers')
        poses[entry.get("key")] = (rot, centre)
    records = []
    for entry in data["views"]:
        view = _cereal_data(entry)
        name, pose_id = view.get("filename"), view.get("id_pose")
        if pose_id not in poses:
            continue  # not reconstructed
        kind = kinds.get(view.get("id_intrinsic"))
        if kind != "spherical":
            raise ValueError(f"{path} view {name!r}: intrinsic {view.get('id_intrinsic')!r} is {kind!r}; cylindersplat "
                             'needs 360° panoramas (OpenMVG\'s "spherical" intrinsic)')
        c2w = openmvg_to_c2w(*poses[pose_id])
        parse_pose_matrix(c2w.tolist(), f"{path} view {name!r}")  # a proper rotation: refuses reflections
        records.append(PoseRecord(name, _scaled(c2w, scale)))
    if not records:
        raise ValueError(f"{path}: no view has a pose")
    return sorted(records, key=lambda r: r.image)


def write_openmvg(path: str | Path, records: list[PoseRecord], width: int, height: int, root_path: str = "") -> Path:
    """``records`` as an OpenMVG ``sfm_data.json`` with one ``spherical`` intrinsic (``width`` x ``height``), view
    and pose ids from 0 in ``records`` order, no structure. Written atomically."""
    views, extrinsics = [], []
    for i, r in enumerate(records):
        views.append({"key": i, "value": {"polymorphic_id": 1073741824, "ptr_wrapper": {"id": 2147483649 + i, "data": {
            "local_path": "", "filename": r.image, "width": width, "height": height,
            "id_view": i, "id_intrinsic": 0, "id_pose": i}}}})
        rot, centre = c2w_to_openmvg(r.c2w)
        extrinsics.append({"key": i, "value": {"rotation": rot.tolist(), "center": centre.tolist()}})
    intrinsics = [{"key": 0, "value": {"polymorphic_id": 2147483649, "polymorphic_name": "spherical", "ptr_wrapper": {
        "id": 2147483649 + len(records), "data": {"value0": {"width": width, "height": height}}}}}]
    data = {"sfm_data_version": "0.3", "root_path": root_path, "views": views, "intrinsics": intrinsics,
            "extrinsics": extrinsics, "structure": [], "control_points": []}
    return atomic_write_text(path, json.dumps(data, indent=1) + "\n")
