"""Gaussian renderers: one entry (:func:`render`) for every camera model and backend.

Public API::

    out = render_equirect(gaussians, c2w, height, width, background=None, backend="auto")
    out = render(gaussians, c2w, Equirect(512, 1024))          # the same, through the seam
    out = render(gaussians, c2w, Pinhole(K, 480, 640), backend="triton")
    out.rgb    # (*B, V, 3, H, W)
    out.depth  # (*B, V, H, W)  radial expected depth (alpha-weighted, not normalised by alpha)
    out.alpha  # (*B, V, H, W)

``gaussians`` is unbatched (``means (N, 3)``) with ``c2w (V, 4, 4)`` or ``(4, 4)``, or batched
(``means (B, N, 3)``) with ``c2w (B, V, 4, 4)``. Camera models (:mod:`.cameras`) project Gaussians;
backends (``"torch"`` reference, ``"triton"`` on CUDA, ``"numba"`` on the CPU, or your own via
:func:`register_backend`) rasterize projected Gaussians of any camera model; ``"auto"`` picks the device's.
:func:`render_layered` draws two sets as layers (a model's pixel Gaussians over its volume Gaussians; a
:class:`FrontLayer` says how, :meth:`cylindersplat.model.CylinderSplat.front_layer` gives a model's).
:class:`RenderGraph` replays a render of fixed sizes as CUDA graphs (:mod:`.graphs`).
"""

from .api import Backend, RenderOutput, available_backends, register_backend, render, render_equirect
from .cameras import CameraModel, Equirect, Pinhole, cubemap_face
from .cubemap import render_cubemap
from .graphs import RenderGraph
from .layered import FrontLayer, render_layered
from .pinhole import render_pinhole
from .projection import ProjectedGaussians, RasterSettings, UnsupportedSettings

__all__ = [
    "RenderOutput", "render", "render_equirect", "render_pinhole", "render_cubemap", "available_backends",
    "register_backend", "Backend", "CameraModel", "Equirect", "Pinhole", "cubemap_face", "ProjectedGaussians",
    "RasterSettings", "UnsupportedSettings", "FrontLayer", "render_layered", "RenderGraph",
]
