"""COLMAP sparse models of 360° panoramas: ``EQUIRECTANGULAR`` cameras, or the panorama workflow's virtual cameras.

=====================  ===================================================================================
File                   a sparse model folder (``cameras``/``images`` ``.txt`` or ``.bin``; or one holding
                       ``sparse/0``), read by :mod:`.colmap_model` without pycolmap
Camera                 ``EQUIRECTANGULAR`` (or ``SPHERICAL``, its later name), W = 2H; or perspective cameras cut
                       out of panoramas (``python/examples/panorama_sfm.py``: images ``<virtual camera>/<pano>``)
Pose                   ``cam_from_world``: quaternion ``w x y z`` (Hamilton) and translation t,
                       ``x_cam = R x_world + t``; OpenCV camera axes
Panorama pixels        COLMAP's EQUIRECTANGULAR camera is our panorama exactly (checked against pycolmap's
                       ``Camera.cam_ray_from_img`` in ``tests/test_pose_files.py``)
To ours                ``c2w = [R^T | -R^T t]``; virtual cameras: each panorama's pose from its rig
                       (:func:`panoramas_from_virtual_cameras`)
Order                  sorted by image (panorama) name
=====================  ===================================================================================
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ...geometry.rotations import matrix_to_quaternion, nearest_rotation, quaternion_wxyz_to_matrix
from .colmap_model import ColmapCamera, ColmapImage, ColmapModel, read_colmap_model, write_colmap_model
from .conventions import PoseRecord, check_pose, check_scale, scaled, to_opencv_c2w

__all__ = ["COLMAP_EQUIRECT_MODELS", "colmap_to_c2w", "c2w_to_colmap", "read_colmap", "write_colmap",
           "panoramas_from_virtual_cameras"]

# COLMAP's 360° camera model: EQUIRECTANGULAR (pycolmap 4.2.1, params w, h); SPHERICAL is the later name.
COLMAP_EQUIRECT_MODELS = ("EQUIRECTANGULAR", "SPHERICAL")


def colmap_to_c2w(qvec, tvec) -> Tensor:
    """COLMAP's ``cam_from_world`` (quaternion ``w, x, y, z`` and translation: ``x_cam = R x_world + t``) -> OpenCV
    c2w. COLMAP's camera frame is OpenCV's (x right, y down, z forward), and its EQUIRECTANGULAR model maps pixels to
    rays exactly as ours does (centre column +z, top row -y, longitude growing to the right, pixel centres at
    +0.5; checked against pycolmap's ``Camera.cam_ray_from_img`` in tests/test_pose_files.py), so no axis change."""
    w2c = torch.eye(4, dtype=torch.float64)
    w2c[:3, :3] = quaternion_wxyz_to_matrix(qvec)
    w2c[:3, 3] = torch.as_tensor(np.asarray(tvec, dtype=np.float64))
    return to_opencv_c2w(w2c, "opencv_w2c")


def c2w_to_colmap(c2w) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV c2w -> COLMAP ``(qvec wxyz, tvec)`` of ``cam_from_world`` (the inverse of :func:`colmap_to_c2w`)."""
    c2w = np.asarray(c2w, dtype=np.float64)
    rot = c2w[:3, :3].T
    return matrix_to_quaternion(torch.from_numpy(rot.copy())).numpy(), -rot @ c2w[:3, 3]


def read_colmap(path: str | Path, scale: float = 1.0) -> list[PoseRecord]:
    """Panorama poses of a COLMAP sparse model (``.txt`` or ``.bin``; a model folder or one holding ``sparse/0``),
    sorted by image name.

    * ``EQUIRECTANGULAR`` (or ``SPHERICAL``) cameras: one record per image (:func:`colmap_to_c2w`).
    * Perspective cameras cut from panoramas (COLMAP's panorama workflow, ``python/examples/panorama_sfm.py``:
      images ``<virtual camera folder>/<panorama name>``, several per panorama, one shared centre): one record per
      panorama, its pose recovered by :func:`panoramas_from_virtual_cameras`.
    """
    scale = check_scale(scale)
    model = read_colmap_model(path, points=False)
    if not model.images:
        raise ValueError(f"{path}: the COLMAP model has no registered images")
    spherical = {i for i, c in model.cameras.items() if c.model.upper() in COLMAP_EQUIRECT_MODELS}
    for i, c in model.cameras.items():
        if i in spherical and c.width != 2 * c.height:
            raise ValueError(f"{path}: camera {i} is {c.model} {c.width}x{c.height}; an equirectangular panorama "
                             "must be twice as wide as high")
    if all(im.camera_id in spherical for im in model.images.values()):
        records = [PoseRecord(im.name, check_pose(scaled(colmap_to_c2w(im.qvec, im.tvec), scale),
                                                  f"{path} image {im.name!r}")) for im in model.images.values()]
        return sorted(records, key=lambda r: r.image)
    if spherical:
        raise ValueError(f"{path}: the model mixes equirectangular and perspective cameras; export the panoramas' "
                         "images only")
    cams = [(im.name, colmap_to_c2w(im.qvec, im.tvec)) for im in model.images.values()]
    records = panoramas_from_virtual_cameras(cams, str(path))
    return [PoseRecord(r.image, check_pose(scaled(r.c2w, scale), f"{path} panorama {r.image!r}")) for r in records]


def _virtual_camera_key(name: str) -> tuple[str, str] | None:
    """``"pano_camera3/hall.jpg"`` -> ``("pano_camera3", "hall.jpg")``: the virtual camera's folder and the panorama."""
    folder, sep, rest = name.partition("/")
    return (folder, rest) if sep and rest else None


def _natural(text: str):
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
    cam_from_ref = {f: nearest_rotation(s) for f, s in sums.items()}
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
        c2w[:3, :3] = torch.from_numpy(nearest_rotation(rot))
        c2w[:3, 3] = torch.from_numpy(centre / len(views))
        records.append(PoseRecord(pano, c2w))
    return records


def write_colmap(folder: str | Path, records: list[PoseRecord], width: int, height: int, kind: str = "txt") -> Path:
    """``records`` (named OpenCV c2w) as a COLMAP sparse model of one ``EQUIRECTANGULAR`` camera
    (``width`` x ``height``), without 3-D points; images numbered from 1 in ``records`` order."""
    if any(r.image is None for r in records):
        raise ValueError("COLMAP images need names: every pose needs its image")
    images = {}
    for i, r in enumerate(records, 1):
        qvec, tvec = c2w_to_colmap(r.c2w)
        images[i] = ColmapImage(r.image, 1, qvec, tvec)
    return write_colmap_model(folder, ColmapModel({1: ColmapCamera("EQUIRECTANGULAR", width, height,
                                                                   [float(width), float(height)])}, images, {}), kind)
