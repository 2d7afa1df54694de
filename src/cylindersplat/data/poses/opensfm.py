"""OpenSfM / OpenDroneMap ``reconstruction.json`` of spherical cameras.

=====================  ===================================================================================
File                   ``reconstruction.json``: a list of reconstructions (the first is the largest), each with
                       ``"cameras"`` and ``"shots"`` (keyed by image name)
Camera                 ``projection_type`` ``spherical`` or ``equirectangular``
Pose                   world-to-camera: ``rotation`` an angle-axis vector R, ``translation`` t,
                       ``x_cam = R x_world + t``; camera axes x right, y down, z forward
Panorama pixels        OpenSfM's spherical model is ours exactly
To ours                ``c2w = [R^T | -R^T t]``
Order                  shots sorted by image name
=====================  ===================================================================================
"""

from __future__ import annotations

from pathlib import Path

import torch

from ...geometry.rotations import axis_angle_to_matrix
from .conventions import PoseRecord, check_pose, check_scale, read_json, scaled, to_opencv_c2w

__all__ = ["OPENSFM_SPHERICAL", "read_opensfm"]

OPENSFM_SPHERICAL = ("spherical", "equirectangular")


def read_opensfm(path: str | Path, scale: float = 1.0, reconstruction: int = 0) -> list[PoseRecord]:
    """Shots of one reconstruction (default the first, OpenSfM's largest) of an OpenSfM/OpenDroneMap
    ``reconstruction.json``, sorted by image name; every shot's camera must be spherical/equirectangular."""
    path = Path(path)
    scale = check_scale(scale)
    data = read_json(path)
    if isinstance(data, dict):
        data = [data]
    if not isinstance(data, list) or not data or not all(isinstance(r, dict) and "shots" in r for r in data):
        raise ValueError(f'{path}: not an OpenSfM reconstruction.json (a list of reconstructions with "cameras" '
                         'and "shots")')
    if not 0 <= reconstruction < len(data):
        raise ValueError(f"{path} holds {len(data)} reconstruction(s); --reconstruction {reconstruction} does not "
                         "exist")
    rec = data[reconstruction]
    cameras = rec.get("cameras", {})
    if not isinstance(rec["shots"], dict) or not isinstance(cameras, dict):
        raise ValueError(f'{path}: "shots" and "cameras" of reconstruction {reconstruction} must be objects keyed by '
                         "image and camera name")
    records = []
    for name, shot in sorted(rec["shots"].items()):
        where = f"{path} shot {name!r}"
        if not isinstance(shot, dict):
            raise ValueError(f'{where}: a shot must be an object with "camera", "rotation" and "translation"')
        camera = cameras.get(shot.get("camera"), {}) if isinstance(shot.get("camera"), str) else {}
        camera = camera if isinstance(camera, dict) else {}
        projection = camera.get("projection_type")
        if projection not in OPENSFM_SPHERICAL:
            raise ValueError(f"{where}: camera {shot.get('camera')!r} has projection_type {projection!r}; "
                             "cylindersplat needs 360° panoramas (projection_type spherical or equirectangular)")
        try:
            rot = axis_angle_to_matrix(shot["rotation"])
            t = torch.tensor(shot["translation"], dtype=torch.float64)
        except (KeyError, TypeError, ValueError, RuntimeError) as exc:
            raise ValueError(f'{where}: needs "rotation" (angle-axis, 3 numbers) and "translation" (3 numbers) '
                             f'({exc})') from None
        if rot.shape != (3, 3) or t.shape != (3,) or not torch.isfinite(t).all() or not torch.isfinite(rot).all():
            raise ValueError(f'{where}: "rotation" and "translation" must be 3 finite numbers each')
        w2c = torch.eye(4, dtype=torch.float64)
        w2c[:3, :3], w2c[:3, 3] = rot, t  # x_cam = R x_world + t, OpenCV camera axes
        records.append(PoseRecord(name, check_pose(scaled(to_opencv_c2w(w2c, "opencv_w2c"), scale), where)))
    if not records:
        raise ValueError(f"{path}: reconstruction {reconstruction} has no shots")
    return records
