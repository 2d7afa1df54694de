"""OpenMVG ``sfm_data.json`` (cereal JSON) of spherical intrinsics.

=====================  ===================================================================================
File                   ``sfm_data.json``: ``"views"`` (file names), ``"intrinsics"``, ``"extrinsics"``
Camera                 the ``spherical`` intrinsic (``Camera_Spherical.hpp``)
Pose                   ``rotation`` R (world-to-camera) and ``center`` C: ``x_cam = R (X - C)``
Panorama pixels        a ray (x, y, z) goes to lon = atan2(x, z), lat = atan2(-y, sqrt(x^2 + z^2)),
                       ``u = w/2 + w lon / (2 pi)``, ``v = h/2 + w lat / (2 pi)``: the top row looks along +y,
                       ours along -y: OpenMVG's world is ours seen in a mirror that flips y
To ours                the world mirrored back, ``S = diag(1, -1, 1)``: ``c2w = [S R^T S | S C]``
                       (:func:`openmvg_to_c2w`)
Order                  posed views sorted by file name
=====================  ===================================================================================
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ...utils.atomic import atomic_write_text
from .conventions import PoseRecord, check_pose, check_scale, read_json, scaled

__all__ = ["openmvg_to_c2w", "c2w_to_openmvg", "read_openmvg", "write_openmvg"]

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
    data = wrapper.get("data", wrapper) if isinstance(wrapper, dict) else {}
    return data if isinstance(data, dict) else {}


def _entries(path: Path, data: dict, section: str):
    """``(key, value)`` of each ``{"key": int, "value": {...}}`` of a cereal list; one ``ValueError`` line naming
    the entry otherwise (a string, a list as key, no value object)."""
    for i, entry in enumerate(data[section]):
        value = entry.get("value") if isinstance(entry, dict) else None
        key = entry.get("key") if isinstance(entry, dict) else None
        if not isinstance(value, dict) or isinstance(key, bool) or not isinstance(key, int):
            raise ValueError(f'{path} "{section}" entry {i}: expected {{"key": <integer>, "value": {{...}}}}, '
                             f"got {entry!r:.80}")
        yield key, value


def _id(value) -> int | None:
    """An integer id of the file (``id_pose``, ``id_intrinsic``), else ``None`` (booleans are no ids)."""
    return value if isinstance(value, int) and not isinstance(value, bool) else None


def read_openmvg(path: str | Path, scale: float = 1.0) -> list[PoseRecord]:
    """Posed views of an OpenMVG ``sfm_data.json`` (cereal JSON: ``views``, ``intrinsics``, ``extrinsics``), sorted
    by file name; every posed view's intrinsic must be ``spherical``. Views without a pose are skipped."""
    path = Path(path)
    scale = check_scale(scale)
    data = read_json(path)
    if not isinstance(data, dict) or not all(isinstance(data.get(k), list)
                                             for k in ("views", "intrinsics", "extrinsics")):
        raise ValueError(f'{path}: not an OpenMVG sfm_data.json (expected "views", "intrinsics" and "extrinsics" '
                         "lists)")
    names_by_id: dict[int, str] = {}
    kinds = {}
    for key, value in _entries(path, data, "intrinsics"):
        poly_id, name = _id(value.get("polymorphic_id")), value.get("polymorphic_name")
        name = name if isinstance(name, str) else None
        if poly_id is not None and name:  # cereal names a type once, then refers to it by id (high bit cleared)
            names_by_id[poly_id & 0x7FFFFFFF] = name
        kinds[key] = name or names_by_id.get((poly_id or 0) & 0x7FFFFFFF)
    poses = {}
    for key, value in _entries(path, data, "extrinsics"):
        where = f"{path} extrinsic {key}"
        try:
            rot, centre = np.array(value["rotation"], dtype=np.float64), np.array(value["center"], dtype=np.float64)
        except (KeyError, TypeError, ValueError):
            raise ValueError(f'{where}: needs "rotation" (3x3) and "center" (3 numbers)') from None
        if rot.shape != (3, 3) or centre.shape != (3,) or not (np.isfinite(rot).all() and np.isfinite(centre).all()):
            raise ValueError(f'{where}: "rotation" must be 3x3 and "center" 3 finite numbers')
        poses[key] = (rot, centre)
    records = []
    for i, entry in enumerate(data["views"]):
        view = _cereal_data(entry) if isinstance(entry, dict) else {}
        name, pose_id = view.get("filename"), _id(view.get("id_pose"))
        if pose_id not in poses:
            continue  # not reconstructed
        if not isinstance(name, str) or not name.strip():
            raise ValueError(f'{path} view {i}: has a pose but no "filename" (got {name!r}), so the pose names no '
                             "panorama; re-export the sfm_data.json from OpenMVG")
        kind = kinds.get(_id(view.get("id_intrinsic")))
        if kind != "spherical":
            raise ValueError(f"{path} view {name!r}: intrinsic {view.get('id_intrinsic')!r} is {kind!r}; "
                             'cylindersplat needs 360° panoramas (OpenMVG\'s "spherical" intrinsic)')
        # A proper rotation (refuses reflections and shears), finite after scaling.
        c2w = check_pose(scaled(openmvg_to_c2w(*poses[pose_id]), scale), f"{path} view {name!r}")
        records.append(PoseRecord(name, c2w))
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
