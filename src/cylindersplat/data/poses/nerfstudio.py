"""nerfstudio ``transforms.json`` of equirectangular panoramas (``"camera_model": "EQUIRECTANGULAR"``).

=====================  ===================================================================================
File                   ``transforms.json``: ``"frames"``, each with ``file_path`` (relative to the file's
                       folder), ``transform_matrix`` and optionally ``depth_file_path``; ``camera_model``,
                       ``w``, ``h`` per frame or for all
Pose                   ``transform_matrix``: camera-to-world, OpenGL camera axes (+x right, +y up, +z back)
Panorama pixels        centre column on -z, top row on +y: our panorama turned into OpenGL axes
To ours                ``c2w = transform_matrix @ diag(1, -1, -1, 1)``
Order                  frames sorted by file name (as nerfstudio does)
=====================  ===================================================================================

Checked against nerfstudio's own projection formulas in ``tests/test_pose_formats.py``.
"""

from __future__ import annotations

from pathlib import Path

from .conventions import PoseRecord, check_pose, check_scale, parse_pose_matrix, read_json, scaled, to_opencv_c2w

__all__ = ["EQUIRECT_CAMERA_MODELS", "is_transforms_json", "read_transforms_json"]

EQUIRECT_CAMERA_MODELS = ("EQUIRECTANGULAR",)  # nerfstudio's name for 360° panoramas


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
    scale = check_scale(scale)
    data = read_json(path) if data is None else data
    if not is_transforms_json(data):
        raise ValueError(f'{path}: not a nerfstudio transforms.json (expected "frames" with "transform_matrix")')
    records = []
    for i, frame in enumerate(data["frames"]):
        where = f"{path} frame {i}"
        if not isinstance(frame, dict) or "transform_matrix" not in frame or "file_path" not in frame:
            raise ValueError(f'{where}: each frame needs "file_path" and "transform_matrix"')
        model = frame.get("camera_model", data.get("camera_model"))
        if model is None:
            raise ValueError(f"{path}: no camera_model (nerfstudio then assumes perspective images); cylindersplat "
                             'needs 360° equirectangular panoramas: "camera_model": "EQUIRECTANGULAR"')
        if str(model).upper() not in EQUIRECT_CAMERA_MODELS:
            raise ValueError(f"{where}: camera_model {model!r} is not a 360° panorama; cylindersplat needs "
                             '"camera_model": "EQUIRECTANGULAR" (equirectangular images, W = 2H)')
        w, h = frame.get("w", data.get("w")), frame.get("h", data.get("h"))
        numbers = isinstance(w, (int, float)) and isinstance(h, (int, float))
        if w is not None and h is not None and (not numbers or w != 2 * h):
            raise ValueError(f"{where}: an equirectangular image must be twice as wide as high, got w={w!r}, h={h!r}")
        for key in ("file_path", "depth_file_path"):
            if frame.get(key) is not None and not isinstance(frame[key], str):
                raise ValueError(f'{where}: "{key}" must be a file name, got {frame[key]!r}')
        if not isinstance(frame["file_path"], str):
            raise ValueError(f'{where}: "file_path" must be a file name, got {frame["file_path"]!r}')
        c2w = to_opencv_c2w(parse_pose_matrix(frame["transform_matrix"], where), "opengl_c2w")
        c2w = check_pose(scaled(c2w, scale), where)
        records.append(PoseRecord(frame["file_path"], c2w, frame.get("depth_file_path")))
    if not records:
        raise ValueError(f"{path}: no frames")
    return sorted(records, key=lambda r: r.image)
