"""The benchmarks' views: the camera models ``bench render`` and ``bench gsplat_compare`` time (the scene is
:func:`cylindersplat.scenes.random_indoor` seen from its centre, identity pose)."""

from __future__ import annotations

import torch

from cylindersplat.render import Equirect, Pinhole

__all__ = ["CAMERAS", "pinhole_intrinsics", "view_camera"]

CAMERAS = ("equirect", "pinhole")


def pinhole_intrinsics(height: int, device="cpu") -> torch.Tensor:
    """``K (3, 3)`` of the benchmarks' pinhole view: ``height x 2 height`` pixels, 90 degrees horizontally, centred
    (:func:`cylindersplat.inference.pipeline.pinhole_intrinsics`, the renderer's own)."""
    from cylindersplat.inference.pipeline import pinhole_intrinsics as centred_intrinsics

    return centred_intrinsics(height, 2 * height, 90.0).to(device)


def view_camera(kind: str, height: int):
    """The benchmarks' view of ``random_indoor`` from its centre (identity pose), ``height x 2 height``: the
    panorama (``"equirect"``) or a 90-degree pinhole view (``"pinhole"``, gsplat's kind of camera: ``bench
    gsplat_compare`` times the same one)."""
    if kind == "pinhole":
        return Pinhole(pinhole_intrinsics(height), height, 2 * height)
    return Equirect(height, 2 * height)
