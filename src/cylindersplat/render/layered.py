"""Two sets of Gaussians drawn as layers, the front one over the back one (issue 34: "seen surfaces are opaque").

A model's pixel Gaussians lie on the surfaces its inputs saw; its volume Gaussians fill the space no input saw.
Drawn in one depth-sorted pass (3DGS, the paper), a seen surface that its pixel Gaussians cover only partly
(between two splat centres its coverage is 0.6-0.99) lets whatever lies behind it show through: on the real
Matterport3D fixture, with one view in, the volume Gaussians behind seen surfaces cost 1.1-1.5 dB that way.

:func:`composite_layers` puts the front layer over the back layer and treats a pixel the front layer covers at
least ``cover[1]`` as opaque: there its colour and depth are the front layer's own, normalised by its coverage (as
a 2-D inpaint behind it would paint them). Below ``cover[0]`` the back layer shows through as in any over
operation (``front + (1 - alpha_front) * back``), with a smoothstep between the two. Where the back layer holds a
surface in front of the front layer (a hidden surface seen only from the target) the layers' order is wrong; with
targets between or near the inputs that is rare, and the one-pass drawing remains the default.

:func:`blend_front_surface` (``render_pixel_blending="surface"``) also changes how the front layer's
own Gaussians combine. The over operator lets the front-most of overlapping opaque splats win, which a target that
magnifies a surface shows as a lattice of splat discs, and where two inputs see the same surface it keeps one
view's splats instead of averaging both. Surface splatting (EWA surface splatting's epsilon-z-buffer) instead
normalises the Gaussian weights of every splat on the front surface: a pixel's colour is ``sum_i w_i c_i / sum_i
w_i`` over the Gaussians whose depth lies within ``tolerance`` (relative) of the front surface at their centre.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from jaxtyping import Float
from torch import Tensor

from ..gaussians import Gaussians
from ..geometry import world_to_camera
from .api import RenderOutput, render
from .cameras import CameraModel
from .projection import RasterSettings

__all__ = ["COVER", "SURFACE_TOLERANCE", "FrontLayer", "blend_front_surface", "composite_layers", "render_layered"]

COVER = (0.3, 0.6)  # front-layer coverage from which the back layer starts to be hidden, and is fully hidden
SURFACE_TOLERANCE = 0.1  # relative depth behind the front surface within which splats blend (0.1-0.2 measured alike)
SOLID_OPACITY = 0.5  # pixel Gaussians at least this opaque define the front surface
_BLEND_OPACITY = 1e-3  # opacity scale of the blending pass: compositing becomes a sum (transmittance stays ~1)
_BLEND_SETTINGS = {"alpha_min": 1e-12}  # ... and no weight is culled as too faint


@dataclass(frozen=True)
class FrontLayer:
    """The first ``count`` Gaussians of a set drawn as a layer over the rest; ``blend``: its own Gaussians combined by
    surface splatting (:func:`blend_front_surface`) instead of the over operator; ``opaque``: the layer hides the
    rest where it covers a pixel (:data:`COVER`), else the plain over operator puts it over them."""

    count: int
    blend: bool = False
    opaque: bool = True

    @property
    def cover(self) -> tuple[float, float] | None:
        """``render_layered``'s ``cover`` for this layer: :data:`COVER` when opaque, else the plain over operator."""
        return COVER if self.opaque else None

    @classmethod
    def of(cls, front: "FrontLayer | int | None") -> "FrontLayer | None":
        """``front`` as a :class:`FrontLayer` (an int is a count drawn with the over operator)."""
        return cls(int(front)) if isinstance(front, int) else front


def composite_layers(front: RenderOutput, back: RenderOutput,
                     cover: tuple[float, float] | None = COVER) -> RenderOutput:
    """The front render over the back one (both on black, same shapes: rgb ``(..., 3, H, W)``, depth and alpha
    ``(..., H, W)``, depth alpha-weighted), the front taken as opaque where its coverage reaches ``cover[1]``
    (``None``: never, the plain over operator)."""
    if cover is None:
        through = 1 - front.alpha
        return RenderOutput(front.rgb + through.unsqueeze(-3) * back.rgb, front.depth + through * back.depth,
                            front.alpha + through * back.alpha)
    low, high = cover
    if not 0.0 <= low < high <= 1.0:
        raise ValueError(f"cover must be two coverages 0 <= low < high <= 1, got {cover}")
    a = front.alpha
    s = ((a - low) / (high - low)).clamp(0.0, 1.0)
    s = s * s * (3 - 2 * s)  # smoothstep: 0 below low, 1 above high
    through = 1 - a
    over_rgb = front.rgb + through.unsqueeze(-3) * back.rgb
    over_depth = front.depth + through * back.depth
    over_alpha = a + through * back.alpha
    own = a.clamp_min(1e-6)
    rgb = s.unsqueeze(-3) * (front.rgb / own.unsqueeze(-3)) + (1 - s).unsqueeze(-3) * over_rgb
    depth = s * (front.depth / own) + (1 - s) * over_depth
    alpha = s + (1 - s) * over_alpha
    return RenderOutput(rgb, depth, alpha)


def blend_front_surface(
    gaussians: Gaussians,
    c2w: Float[Tensor, "... 4 4"],
    camera: CameraModel,
    drawn: RenderOutput,
    backend: str = "auto",
    settings: RasterSettings | None = None,
    tolerance: float = SURFACE_TOLERANCE,
    solid_opacity: float = SOLID_OPACITY,
) -> RenderOutput:
    """``drawn`` (the render of unbatched ``gaussians`` from ``c2w``, on black) with its colour replaced by the
    normalised Gaussian-weighted mean of the splats on its front surface; its coverage and depth are kept.

    A Gaussian is on the front surface of a camera when its mean's depth is at most ``(1 + tolerance)`` times the
    depth of the solid splats (opacity >= ``solid_opacity``, drawn opaque; where they cover at least half the
    pixel) at the pixel its mean falls on.
    The weights are the Gaussians' own (opacity x footprint), so edge-faded splats weigh less; a second render of
    the surface's Gaussians at a tiny opacity makes the over operator a sum."""
    if tolerance <= 0:
        raise ValueError(f"tolerance must be > 0 (relative depth), got {tolerance}")
    settings = settings or RasterSettings()
    poses = c2w.reshape(-1, 4, 4).to(gaussians.means)
    num_cameras, (h, w) = len(poses), (camera.height, camera.width)
    alpha = drawn.alpha.reshape(num_cameras, h, w)
    with torch.no_grad():  # which splats blend is a choice, not a parameter: no gradient through it
        # The front surface is that of the solid splats: faint ones in front (edge-faded, flying pixels) would pull
        # an expected depth forward and leave the surface behind them out of its own blend.
        solid = (gaussians.opacities.detach() >= solid_opacity).to(gaussians.opacities)
        front = render(replace(gaussians, opacities=solid), poses, camera, backend=backend, settings=settings)
        depth, cover = front.depth.reshape(num_cameras, h, w), front.alpha.reshape(num_cameras, h, w)
        surface = torch.where(cover > 0.5, depth / cover.clamp_min(1e-6), torch.full_like(depth, float("inf")))
        points = world_to_camera(gaussians.means.detach().double()[None], poses.double())  # (C, N, 3)
        pixels = camera.pixel_map(points[None], settings)
        u = pixels.u[0].floor().long()
        u = u % w if camera.wrap_u else u.clamp(0, w - 1)
        v = pixels.v[0].floor().long().clamp(0, h - 1)
        front_depth = surface.view(num_cameras, -1).gather(1, v * w + u)
        on_surface = pixels.valid[0] & (pixels.depth[0] <= front_depth * (1 + tolerance))
    per_camera = Gaussians(**{name: value[None].expand(num_cameras, *value.shape)
                              for name, value in gaussians.tensors().items()})
    weights = replace(per_camera, opacities=per_camera.opacities * on_surface.to(gaussians.opacities) * _BLEND_OPACITY)
    summed = render(weights, poses[:, None], camera, backend=backend, settings=replace(settings, **_BLEND_SETTINGS))
    total = summed.alpha.reshape(num_cameras, 1, h, w)
    mean = summed.rgb.reshape(num_cameras, 3, h, w) / total.clamp_min(1e-30)
    rgb = drawn.rgb.reshape(num_cameras, 3, h, w)
    rgb = torch.where(total > 1e-9, mean * alpha[:, None], rgb)
    return RenderOutput(rgb.reshape(drawn.rgb.shape), drawn.depth, drawn.alpha)


def render_layered(
    front: Gaussians,
    back: Gaussians,
    c2w: Float[Tensor, "... 4 4"],
    camera: CameraModel,
    background: Tensor | tuple[float, float, float] | None = None,
    backend: str = "auto",
    settings: RasterSettings | None = None,
    cover: tuple[float, float] | None = COVER,
    blend: bool = False,
) -> RenderOutput:
    """:func:`~cylindersplat.render.render` of two unbatched sets of Gaussians as layers (:func:`composite_layers`;
    ``cover=None``: the plain over operator), with ``background`` behind both; ``blend``: the front layer's colour by
    surface splatting (:func:`blend_front_surface`)."""
    first = render(front, c2w, camera, backend=backend, settings=settings)
    if blend and front.num_gaussians:
        first = blend_front_surface(front, c2w, camera, first, backend=backend, settings=settings)
    if back.num_gaussians == 0:
        out = first
    else:
        out = composite_layers(first, render(back, c2w, camera, backend=backend, settings=settings), cover)
    if background is None:
        return out
    colour = background if isinstance(background, Tensor) else out.rgb.new_tensor(background)
    colour = colour.to(out.rgb)
    colour = colour.view(*colour.shape[:-1], 3, 1, 1) if colour.dim() > 1 else colour.view(3, 1, 1)
    return RenderOutput(out.rgb + (1 - out.alpha).unsqueeze(-3) * colour, out.depth, out.alpha)
