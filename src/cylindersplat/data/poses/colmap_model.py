"""COLMAP sparse models on disk (``cameras``, ``images``, ``points3D`` as ``.txt`` or ``.bin``), without pycolmap.

Only the file layout lives here; what the numbers mean as poses (``cam_from_world``, the camera models) is
:mod:`.colmap`'s. The layout, as COLMAP 3.x/4.x writes it (checked against files written by
pycolmap 4.2.1; ``rigs``/``frames`` files of COLMAP >= 3.12 are not needed: every image keeps its own pose):

* ``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS...``; ``cameras.bin``: ``uint64`` count, then per camera
  ``int32 id, int32 model_id, uint64 width, uint64 height, float64 params[n(model)]``.
* ``images.txt``: two lines per image, ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` then ``X Y POINT3D_ID ...``;
  ``images.bin``: ``uint64`` count, then ``int32 id, float64 qw qx qy qz tx ty tz, int32 camera_id``, the name
  NUL-terminated, ``uint64`` number of 2-D points, each ``float64 x, float64 y, int64 point3D_id`` (-1: none).
  The pose is world-to-camera: ``x_cam = R(q) x_world + t``, pixel coordinates with the top-left corner at (0, 0).
* ``points3D.txt``: ``POINT3D_ID X Y Z R G B ERROR (IMAGE_ID POINT2D_IDX)...``; ``points3D.bin``: ``uint64``
  count, then ``uint64 id, float64 xyz[3], uint8 rgb[3], float64 error, uint64 track length, (int32, int32)...``.
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...utils.atomic import atomic_path

__all__ = ["ColmapCamera", "ColmapImage", "ColmapModel", "read_colmap_model", "write_colmap_model",
           "CAMERA_MODEL_PARAMS", "find_colmap_model"]

# Model id -> (name, number of parameters), as COLMAP numbers its camera models (pycolmap 4.2.1's CameraModelId).
CAMERA_MODEL_PARAMS = {
    0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5), 4: ("OPENCV", 8),
    5: ("OPENCV_FISHEYE", 8), 6: ("FULL_OPENCV", 12), 7: ("FOV", 5), 8: ("SIMPLE_RADIAL_FISHEYE", 4),
    9: ("RADIAL_FISHEYE", 5), 10: ("THIN_PRISM_FISHEYE", 12), 11: ("RAD_TAN_THIN_PRISM_FISHEYE", 16),
    12: ("SIMPLE_DIVISION", 4), 13: ("DIVISION", 5), 14: ("SIMPLE_FISHEYE", 3), 15: ("FISHEYE", 4), 16: ("EUCM", 6),
    17: ("EQUIRECTANGULAR", 2),
}
_MODEL_IDS = {name: (model_id, n) for model_id, (name, n) in CAMERA_MODEL_PARAMS.items()}


@dataclass
class ColmapCamera:
    model: str
    width: int
    height: int
    params: list[float]


@dataclass
class ColmapImage:
    """One image: ``qvec`` (w, x, y, z) and ``tvec`` of ``cam_from_world``; ``xy`` ``(P, 2)`` pixel positions of
    its keypoints and ``point_ids`` ``(P,)`` their 3-D point (-1: none)."""

    name: str
    camera_id: int
    qvec: np.ndarray
    tvec: np.ndarray
    xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    point_ids: np.ndarray = field(default_factory=lambda: np.zeros((0,), dtype=np.int64))


@dataclass
class ColmapModel:
    """``points`` maps a 3-D point id to its position ``(3,)`` (world units of the model)."""

    cameras: dict[int, ColmapCamera]
    images: dict[int, ColmapImage]
    points: dict[int, np.ndarray]


def find_colmap_model(path: str | Path) -> tuple[Path, str]:
    """``(folder, "txt" | "bin")`` of the model at ``path``: a model folder, a file in one, or a folder holding
    ``sparse/0`` or ``0`` (COLMAP's own layouts); text wins where both are there."""
    path = Path(path)
    if path.is_file():
        path = path.parent
    for folder in (path, path / "0", path / "sparse" / "0", path / "sparse"):
        for kind in ("txt", "bin"):
            if (folder / f"cameras.{kind}").is_file() and (folder / f"images.{kind}").is_file():
                return folder, kind
    if not path.exists():
        raise FileNotFoundError(f"COLMAP model not found: {path}")
    raise ValueError(f"{path}: not a COLMAP sparse model (expected cameras.txt + images.txt or cameras.bin + "
                     "images.bin, here or in sparse/0)")


def read_colmap_model(path: str | Path, points: bool = True) -> ColmapModel:
    """The model at ``path`` (:func:`find_colmap_model`); ``points=False`` skips ``points3D``."""
    folder, kind = find_colmap_model(path)
    try:
        if kind == "txt":
            cameras, images = _read_cameras_txt(folder / "cameras.txt"), _read_images_txt(folder / "images.txt")
            pts = _read_points_txt(folder / "points3D.txt") if points and (folder / "points3D.txt").is_file() else {}
        else:
            cameras, images = _read_cameras_bin(folder / "cameras.bin"), _read_images_bin(folder / "images.bin")
            pts = _read_points_bin(folder / "points3D.bin") if points and (folder / "points3D.bin").is_file() else {}
    except (struct.error, IndexError, UnicodeDecodeError) as exc:
        raise ValueError(f"{folder}: truncated or corrupt COLMAP {kind} model ({exc})") from None
    return ColmapModel(cameras, images, pts)


# --- text ---------------------------------------------------------------------------------------------


def _data_lines(path: Path) -> list[str]:
    return [line for line in path.read_text().splitlines() if line.strip() and not line.lstrip().startswith("#")]


def _read_cameras_txt(path: Path) -> dict[int, ColmapCamera]:
    cameras = {}
    for number, line in enumerate(_data_lines(path), 1):
        parts = line.split()
        try:
            cameras[int(parts[0])] = ColmapCamera(parts[1], int(parts[2]), int(parts[3]), [float(p) for p in parts[4:]])
        except (IndexError, ValueError):
            raise ValueError(f"{path} camera line {number}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS..., "
                             f"got {line[:80]!r}") from None
    return cameras


def _read_images_txt(path: Path) -> dict[int, ColmapImage]:
    # Not _data_lines: an image without keypoints has an empty second line, which must still count.
    lines = [(number, line) for number, line in enumerate(path.read_text().splitlines(), 1)
             if not line.lstrip().startswith("#")]
    while lines and not lines[-1][1].strip():
        lines.pop()
    images = {}
    for i in range(0, len(lines), 2):
        number, line = lines[i]
        parts = line.split(maxsplit=9)
        try:
            image_id, camera_id = int(parts[0]), int(parts[8])
            values = [float(p) for p in parts[1:8]]
            name = parts[9].strip()
        except (IndexError, ValueError):
            raise ValueError(f"{path} line {number}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, "
                             f"got {line[:80]!r}") from None
        _check_pose_numbers(values, f"{path} line {number} (image {name!r})")
        try:
            row = np.array(lines[i + 1][1].split() if i + 1 < len(lines) else [], dtype=np.float64).reshape(-1, 3)
        except ValueError:
            raise ValueError(f"{path} line {lines[i + 1][0]}: expected X Y POINT3D_ID triples (the keypoints of image "
                             f"{name!r}), got {lines[i + 1][1][:80]!r}") from None
        images[image_id] = ColmapImage(name, camera_id, np.array(values[:4]), np.array(values[4:]),
                                       row[:, :2], row[:, 2].astype(np.int64))
    return images


def _check_pose_numbers(values, where: str) -> None:
    """``QW QX QY QZ TX TY TZ`` must be finite, the quaternion not zero: ``ValueError`` naming ``where``."""
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{where}: the pose QW QX QY QZ TX TY TZ holds a non-finite number "
                         f"({' '.join(map(repr, values))}); fix or remove this image")
    if not math.hypot(*values[:4]) > 1e-9:
        raise ValueError(f"{where}: the quaternion QW QX QY QZ is zero, not a rotation; fix or remove this image")


def _read_points_txt(path: Path) -> dict[int, np.ndarray]:
    points = {}
    for line in _data_lines(path):
        parts = line.split()
        points[int(parts[0])] = np.array([float(p) for p in parts[1:4]])
    return points


# --- binary -------------------------------------------------------------------------------------------


class _Reader:
    """Little-endian values of a binary model file; every count is checked against the bytes left, so a corrupt
    count (2^64 keypoints) is one error naming the file, not an allocation or a loop that never ends."""

    def __init__(self, path: Path) -> None:
        self.path, self.data, self.at = path, path.read_bytes(), 0

    def take(self, fmt: str):
        values = struct.unpack_from("<" + fmt, self.data, self.at)
        self.at += struct.calcsize("<" + fmt)
        return values

    def count(self, item_bytes: int, what: str) -> int:
        """A ``uint64`` count of items at least ``item_bytes`` long each, checked against the rest of the file."""
        (n,) = self.take("Q")
        left = len(self.data) - self.at
        if n * item_bytes > left:
            raise ValueError(f"{self.path}: truncated or corrupt COLMAP binary model: {n} {what} of at least "
                             f"{item_bytes} bytes each do not fit in the {left} bytes left of the file")
        return n

    def name(self) -> str:
        end = self.data.find(b"\0", self.at)
        if end < 0:
            raise ValueError(f"{self.path}: truncated or corrupt COLMAP binary model: an image name has no end")
        text = self.data[self.at:end].decode("utf-8")
        self.at = end + 1
        return text

    def array(self, dtype, count: int) -> np.ndarray:
        dtype = np.dtype(dtype)
        out = np.frombuffer(self.data, dtype=dtype, count=count, offset=self.at)
        self.at += dtype.itemsize * count
        return out


def _read_cameras_bin(path: Path) -> dict[int, ColmapCamera]:
    r = _Reader(path)
    cameras = {}
    for _ in range(r.count(struct.calcsize("<iiQQ"), "cameras")):
        camera_id, model_id, width, height = r.take("iiQQ")
        if model_id not in CAMERA_MODEL_PARAMS:
            raise ValueError(f"{path}: camera {camera_id} has unknown model id {model_id}")
        name, n = CAMERA_MODEL_PARAMS[model_id]
        cameras[camera_id] = ColmapCamera(name, width, height, list(r.take("d" * n)))
    return cameras


_KEYPOINT = np.dtype([("x", "<f8"), ("y", "<f8"), ("id", "<i8")])
_IMAGE_BYTES = struct.calcsize("<idddddddi") + 1 + 8  # pose, camera, an empty name's NUL, the keypoint count


def _read_images_bin(path: Path) -> dict[int, ColmapImage]:
    r = _Reader(path)
    images = {}
    for _ in range(r.count(_IMAGE_BYTES, "images")):
        image_id, *pose, camera_id = r.take("idddddddi")
        name = r.name()
        _check_pose_numbers(pose, f"{path} image {image_id} ({name!r})")
        keypoints = r.array(_KEYPOINT, r.count(_KEYPOINT.itemsize, f"keypoints of image {name!r}"))
        images[image_id] = ColmapImage(name, camera_id, np.array(pose[:4]), np.array(pose[4:]),
                                       np.stack([keypoints["x"], keypoints["y"]], -1), keypoints["id"].astype(np.int64))
    return images


def _read_points_bin(path: Path) -> dict[int, np.ndarray]:
    r = _Reader(path)
    points = {}
    for _ in range(r.count(struct.calcsize("<QdddBBBdQ"), "points")):
        point_id, x, y, z = r.take("Qddd")
        r.take("BBBd")
        r.array("<i4", 2 * r.count(8, f"track entries of point {point_id}"))
        points[point_id] = np.array([x, y, z])
    return points


# --- writing ------------------------------------------------------------------------------------------


def write_colmap_model(folder: str | Path, model: ColmapModel, kind: str = "txt") -> Path:
    """Write ``model`` as ``cameras``/``images``/``points3D`` ``.txt`` or ``.bin`` in ``folder``, each atomically.
    3-D points are written without tracks (enough for COLMAP to open the model and to see the structure)."""
    folder = Path(folder)
    if kind not in ("txt", "bin"):
        raise ValueError(f"kind must be 'txt' or 'bin', got {kind!r}")
    folder.mkdir(parents=True, exist_ok=True)
    writers = {"cameras": _cameras_txt, "images": _images_txt, "points3D": _points_txt} if kind == "txt" else \
        {"cameras": _cameras_bin, "images": _images_bin, "points3D": _points_bin}
    for stem, write in writers.items():
        with atomic_path(folder / f"{stem}.{kind}") as tmp:
            data = write(model)
            tmp.write_text(data) if isinstance(data, str) else tmp.write_bytes(data)
    return folder


def _cameras_txt(model: ColmapModel) -> str:
    lines = ["# Camera list with one line of data per camera:", "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]"]
    lines += [" ".join([str(i), c.model, str(c.width), str(c.height), *map(repr, map(float, c.params))])
              for i, c in sorted(model.cameras.items())]
    return "\n".join(lines) + "\n"


def _images_txt(model: ColmapModel) -> str:
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)"]
    for i, im in sorted(model.images.items()):
        lines.append(" ".join([str(i), *map(repr, map(float, im.qvec)), *map(repr, map(float, im.tvec)),
                               str(im.camera_id), im.name]))
        lines.append(" ".join(f"{x!r} {y!r} {int(p)}" for (x, y), p in zip(im.xy.tolist(), im.point_ids.tolist())))
    return "\n".join(lines) + "\n"


def _points_txt(model: ColmapModel) -> str:
    lines = ["# 3D point list with one line of data per point:",
             "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)"]
    lines += [" ".join([str(i), *map(repr, map(float, p)), "128 128 128 0"]) for i, p in sorted(model.points.items())]
    return "\n".join(lines) + "\n"


def _cameras_bin(model: ColmapModel) -> bytes:
    out = [struct.pack("<Q", len(model.cameras))]
    for i, c in sorted(model.cameras.items()):
        if c.model not in _MODEL_IDS or len(c.params) != _MODEL_IDS[c.model][1]:
            raise ValueError(f"camera {i}: model {c.model!r} with {len(c.params)} parameters has no binary form")
        out.append(struct.pack("<iiQQ", i, _MODEL_IDS[c.model][0], c.width, c.height))
        out.append(struct.pack("<" + "d" * len(c.params), *c.params))
    return b"".join(out)


def _images_bin(model: ColmapModel) -> bytes:
    out = [struct.pack("<Q", len(model.images))]
    for i, im in sorted(model.images.items()):
        out.append(struct.pack("<idddddddi", i, *map(float, im.qvec), *map(float, im.tvec), im.camera_id))
        out.append(im.name.encode("utf-8") + b"\0")
        keypoints = np.zeros(len(im.point_ids), dtype=_KEYPOINT)
        keypoints["x"], keypoints["y"], keypoints["id"] = im.xy[:, 0], im.xy[:, 1], im.point_ids
        out.append(struct.pack("<Q", len(keypoints)) + keypoints.tobytes())
    return b"".join(out)


def _points_bin(model: ColmapModel) -> bytes:
    out = [struct.pack("<Q", len(model.points))]
    for i, p in sorted(model.points.items()):
        out.append(struct.pack("<QdddBBBdQ", i, *map(float, p), 128, 128, 128, 0.0, 0))
    return b"".join(out)
