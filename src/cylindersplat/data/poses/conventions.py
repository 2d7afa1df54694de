"""What a pose means: our ``poses.json`` conventions, the record every reader returns, and its checks.

=====================  ===================================================================================
Pose                   a 4x4 float64 camera-to-world ``c2w`` (``x_world = R x_cam + t``), metres
Camera axes            OpenCV: +x right, +y down, +z forward (:doc:`docs/conventions.md`)
Panorama pixels        equirectangular, W = 2H: centre column on +z, top row on -y, longitude growing to the
                       right (+x at 3/4 of the width), pixel centres at +0.5
``"convention"``       what a 4x4 of a ``poses.json`` means (:data:`POSE_CONVENTIONS`): OpenCV or OpenGL/Blender
                       camera axes (+y up, +z back), camera-to-world or world-to-camera;
                       :func:`to_opencv_c2w` turns each into ours
Scale                  SfM/SLAM reconstructions have none unless given one (GPS, a known distance): a reader's
                       ``scale`` multiplies every camera position (metres per reconstruction unit)
=====================  ===================================================================================

Every reader of :mod:`cylindersplat.data.poses` (one module per tool, each with its own table like this one) returns
:class:`PoseRecord`s: an image name (or ``None``), the OpenCV ``c2w``, an optional depth file and, for trajectories,
a timestamp. :func:`parse_pose_matrix` checks a 3x4/4x4 list to be a rigid pose (``data.folder`` reads our poses
files with it); :class:`PoseFormat` is a registry entry (:mod:`.registry`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import torch
from torch import Tensor

from ...geometry import validate_c2w
from ...utils.jsonfile import read_json_file
from .registry import PoseFormat  # (defined there, torch-free: the command line lists the formats without torch)

__all__ = ["POSE_CONVENTIONS", "PoseRecord", "PoseFormat", "parse_pose_matrix", "to_opencv_c2w", "check_pose",
           "check_scale", "scaled"]

# +y up, +z back -> +y down, +z forward
_GL_TO_CV = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))
# What a 4x4 pose may mean ("convention" of a poses file): camera axes OpenCV or OpenGL/Blender, c2w or w2c.
POSE_CONVENTIONS = ("opencv_c2w", "opengl_c2w", "blender_c2w", "opencv_w2c", "opengl_w2c")


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


def scaled(c2w: Tensor, scale: float) -> Tensor:
    """A copy of ``c2w`` with its position multiplied by ``scale`` (metres per unit)."""
    c2w = c2w.clone()
    c2w[:3, 3] *= scale
    return c2w


def check_scale(scale: float) -> float:
    """``scale`` as a float if it is a positive finite number; ``ValueError`` otherwise."""
    if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not math.isfinite(scale) or scale <= 0:
        raise ValueError(f"scale must be a positive number (metres per unit), got {scale!r}")
    return float(scale)


def read_json(path: Path):
    """A pose file's JSON (one-line errors for a missing, unreadable or malformed file)."""
    return read_json_file(path, "poses file")


def check_pose(c2w: Tensor, where: str) -> Tensor:
    """``c2w`` (4x4) if it is finite and rigid (a rotation, last row ``0 0 0 1``); ``ValueError`` naming ``where``
    otherwise. Every reader's last word: no NaN, shear or reflection reaches a ``poses.json``."""
    validate_c2w(c2w, name=where)
    return c2w
