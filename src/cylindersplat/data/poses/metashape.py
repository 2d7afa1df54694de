"""Agisoft Metashape camera XML (File > Export > Export Cameras) of spherical sensors.

=====================  ===================================================================================
File                   ``<document><chunk>`` with ``<sensors>``, ``<components>`` and ``<cameras>``
Camera                 ``<sensor type="spherical">``
Pose                   a camera's ``<transform>``: 4x4 camera-to-chunk-local (a rigid motion), camera axes x
                       right, y down, z forward; then its component's and the chunk's ``<transform>``
                       (``rotation`` 9, ``translation`` 3, ``scale`` 1: similarities)
Panorama pixels        the spherical sensor maps a ray ``(X, Y, Z)`` to ``u = w/2 + w/(2 pi) atan2(X, Z)``,
                       ``v = h/2 + w/(2 pi) atan2(Y, sqrt(X^2 + Z^2))`` (the manual's camera-model appendix): ours
To ours                ``chunk @ component @ transform``, its scale moved from the rotation to the position
Order                  aligned cameras (those with a ``<transform>``) sorted by ``label``
=====================  ===================================================================================
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ...utils.atomic import atomic_write_text
from .conventions import PoseRecord, check_pose, check_scale, scaled

__all__ = ["metashape_to_c2w", "read_metashape_xml", "write_metashape_xml"]

# How far a rotation read from a file may be from orthonormal (files hold 16-17 digits; a shear is far larger).
ROTATION_TOLERANCE = 1e-5


def _floats(text: str | None, count: int, where: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in (text or "").split()], dtype=np.float64)
    except ValueError:
        raise ValueError(f"{where}: expected {count} numbers, got {(text or '')[:60]!r}") from None
    if values.size != count or not np.isfinite(values).all():
        raise ValueError(f"{where}: expected {count} finite numbers, got {values.size}")
    return values


def _rotation_scale(m: np.ndarray, where: str, up_to_scale: bool) -> float:
    """The scale ``s`` of a 3x3 ``m = s R`` (``R`` a rotation); ``ValueError`` naming ``where`` if ``m`` is a
    reflection, degenerate, sheared or (``up_to_scale=False``) scaled."""
    det = float(np.linalg.det(m))
    if not det > 0:
        raise ValueError(f"{where} is not a rotation (determinant {det:.3g}: a reflection or degenerate); "
                         "re-export the cameras from Metashape")
    s = float(np.cbrt(det))
    error = float(np.abs((m / s) @ (m / s).T - np.eye(3)).max())
    if error > ROTATION_TOLERANCE:
        raise ValueError(f"{where} is not a rotation{' up to scale' if up_to_scale else ''} (sheared: "
                         f"max |R R^T - I| = {error:.3g}); re-export the cameras from Metashape")
    if not up_to_scale and abs(s - 1.0) > ROTATION_TOLERANCE:
        raise ValueError(f"{where} is not a rotation (scaled by {s:.6g}; a camera's transform is rigid, the scale "
                         "belongs to the chunk); re-export the cameras from Metashape")
    return s


def _metashape_component(element, where: str) -> np.ndarray:
    """A chunk's or component's ``<transform>`` (``rotation`` 9, ``translation`` 3, ``scale`` 1) as the 4x4
    similarity from the chunk's local frame to its world; identity where there is none. ``rotation`` must be a
    rotation (up to scale: some exports fold the scale into it) and ``scale`` positive."""
    out = np.eye(4)
    transform = element.find("transform") if element is not None else None
    if transform is None:
        return out
    rot, trans, scale = transform.find("rotation"), transform.find("translation"), transform.find("scale")
    if rot is not None:
        out[:3, :3] = _floats(rot.text, 9, f"{where} <rotation>").reshape(3, 3)
        _rotation_scale(out[:3, :3], f"{where} <rotation>", up_to_scale=True)
    if scale is not None:
        factor = _floats(scale.text, 1, f"{where} <scale>")[0]
        if not factor > 0:
            raise ValueError(f"{where} <scale> must be positive, got {factor:g}")
        out[:3, :3] *= factor
    if trans is not None:
        out[:3, 3] = _floats(trans.text, 3, f"{where} <translation>")
    return out


def metashape_to_c2w(transform, chunk=None, where: str = "Metashape transform") -> Tensor:
    """A Metashape camera ``<transform>`` (4x4 camera-to-chunk-local, camera axes x right, y down, z forward) and
    its chunk/component similarity ``chunk`` (4x4, scale included) -> OpenCV c2w in the chunk's world frame.

    The similarity's scale multiplies positions only; rotations keep their unit length. ``ValueError`` naming
    ``where`` for a camera transform that is not rigid (projective last row, shear, scale, reflection)."""
    t = np.asarray(transform, dtype=np.float64).reshape(4, 4)
    if np.abs(t[3] - [0.0, 0.0, 0.0, 1.0]).max() > ROTATION_TOLERANCE:
        raise ValueError(f"{where}: the last row is {' '.join(f'{v:g}' for v in t[3])}, not 0 0 0 1 (a projective "
                         "transform, not a camera pose); re-export the cameras from Metashape")
    _rotation_scale(t[:3, :3], where, up_to_scale=False)
    m = (np.eye(4) if chunk is None else np.asarray(chunk, dtype=np.float64)) @ t
    scale = _rotation_scale(m[:3, :3], f"{where} in the chunk's frame", up_to_scale=True)
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
    path = Path(path)
    scale = check_scale(scale)
    if not path.is_file():
        raise FileNotFoundError(f"missing Metashape XML: {path}")
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise ValueError(f"{path}: not an XML file ({exc})") from None
    chunk = root if root.tag == "chunk" else root.find("chunk")
    if chunk is None or chunk.find("cameras") is None:
        raise ValueError(f"{path}: not a Metashape camera XML (expected <document><chunk> with <sensors> and "
                         "<cameras>)")
    sensors = {s.get("id"): (s.get("type") or "frame") for s in chunk.iter("sensor")}
    chunk_transform = _metashape_component(chunk, f"{path} chunk")
    components = {c.get("id"): _metashape_component(c, f"{path} component {c.get('id')}")
                  for c in chunk.iter("component")}
    records = []
    for camera in chunk.find("cameras").iter("camera"):
        label = camera.get("label")
        where = f"{path} camera {label!r}"
        transform = camera.find("transform")
        if transform is None:
            continue  # not aligned
        if not label or not label.strip():
            raise ValueError(f"{path} camera id={camera.get('id')!r}: no label (the photo's file name), so its pose "
                             "names no panorama; re-export the cameras from Metashape")
        kind = sensors.get(camera.get("sensor_id"))
        if kind != "spherical":
            raise ValueError(f"{where}: sensor {camera.get('sensor_id')!r} is of type {kind!r}; cylindersplat needs "
                             '360° panoramas (sensor type="spherical")')
        component = components.get(camera.get("component_id"))
        similarity = chunk_transform @ component if component is not None else chunk_transform
        c2w = metashape_to_c2w(_floats(transform.text, 16, f"{where} <transform>"), similarity, f"{where} <transform>")
        records.append(PoseRecord(label, check_pose(scaled(c2w, scale), where)))
    if not records:
        raise ValueError(f"{path}: no aligned camera (no <camera> with a <transform>)")
    return sorted(records, key=lambda r: r.image)


def write_metashape_xml(path: str | Path, records: list[PoseRecord], width: int, height: int) -> Path:
    """``records`` as a Metashape camera XML with one spherical sensor (``width`` x ``height``) and no chunk
    transform (camera transforms are in our world frame). Written atomically."""
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
