"""Gaussian renderers: direct equirectangular (reference + fast backends), pinhole and cubemap.

Public API::

    out = render_equirect(gaussians, c2w, height, width, background=None, backend="auto")
    out.rgb    # (*B, V, 3, H, W)
    out.depth  # (*B, V, H, W)  radial expected depth (alpha-weighted, not normalised by alpha)
    out.alpha  # (*B, V, H, W)

``gaussians`` is unbatched (``means (N, 3)``) with ``c2w (V, 4, 4)`` or ``(4, 4)``, or batched
(``means (B, N, 3)``) with ``c2w (B, V, 4, 4)``.
"""

from .api import RenderOutput, available_backends, render_equirect
from .cubemap import render_cubemap
from .pinhole import render_pinhole

__all__ = ["RenderOutput", "render_equirect", "render_pinhole", "render_cubemap", "available_backends"]
