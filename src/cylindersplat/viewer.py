"""Look at Gaussians and the input cameras: in the browser (viser), as one HTML file, or as a picture.

* :func:`serve` starts a `viser <https://viser.studio>`_ server (``pip install 'cylindersplat[view]'``)
  showing the splats (:meth:`viser.SceneApi.add_gaussian_splats`, sorted and drawn in the browser with
  WebGL) and one frustum per input panorama, textured with the panorama;
* :func:`write_html` writes the same scene as one self-contained HTML file (viser's embedded client
  with the scene inside; opens from disk, no server, no network);
* :func:`render_picture` renders a pinhole view or a panorama with our own renderer
  (:mod:`cylindersplat.render`), for machines without a browser.

The world frame is the poses' (OpenCV: +y down), so the viewer's up direction is -y. viser draws
degree-0 colour (higher SH bands are dropped) and stores covariances as float16 (relative error
~1e-3; variances below ~6e-8 m^2, i.e. scales under ~0.25 mm, lose precision).
"""

from __future__ import annotations

import contextlib
import io
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .gaussians import Gaussians
from .geometry.rotations import matrix_to_quaternion
from .render.cameras import CameraModel, Pinhole
from .render.covariance import covariance_3d
from .render.projection import PixelMap, RasterSettings
from .view_framing import default_view  # the first view: the scene framed from behind and above

__all__ = ["VIEW_INSTALL", "ViewCamera", "ViewerScene", "SplatArrays", "splat_arrays", "import_viser", "build_scene",
           "default_view", "serve", "write_html", "render_picture", "PinholeRows", "row_bytes", "picture_bands",
           "screenshot_budget", "SCREENSHOT_BUDGET_BYTES"]

VIEW_INSTALL = "pip install 'cylindersplat[view]'"
FRUSTUM_COLOR = (255, 140, 0)
# viser sends covariances to the page as float16 (largest finite value 65504): a standard deviation beyond
# sqrt(65504) m would arrive as Inf and the splat as NaN in the page's shader, so it is capped there.
MAX_VIEWER_SCALE_M = 255.0


def import_viser():
    """The ``viser`` module, or a ``ModuleNotFoundError`` that says how to install it."""
    try:
        import viser
    except ModuleNotFoundError as exc:
        raise ModuleNotFoundError(f"the viewer needs viser: {VIEW_INSTALL}", name="viser") from exc
    return viser


@dataclass
class SplatArrays:
    """What :meth:`viser.SceneApi.add_gaussian_splats` takes, as float32 numpy arrays."""

    centers: np.ndarray       # (N, 3) world positions
    covariances: np.ndarray   # (N, 3, 3) R diag(s^2) R^T
    rgbs: np.ndarray          # (N, 3) degree-0 colour in [0, 1]
    opacities: np.ndarray     # (N, 1) in [0, 1]


def splat_arrays(gaussians: Gaussians) -> SplatArrays:
    """Unbatched ``gaussians`` -> viser's arrays: colours from the SH DC term, covariances from scales (capped at
    :data:`MAX_VIEWER_SCALE_M`, to stay finite in viser's float16 buffer) and (normalised) quaternions."""
    if gaussians.batch_shape:
        raise ValueError(f"the viewer takes unbatched Gaussians, got batch shape {tuple(gaussians.batch_shape)}")
    g = gaussians.detach().to("cpu", torch.float32).validate()
    as_np = lambda t: np.ascontiguousarray(t.numpy(), dtype=np.float32)  # noqa: E731
    return SplatArrays(
        centers=as_np(g.means),
        covariances=as_np(covariance_3d(g.scales.clamp(max=MAX_VIEWER_SCALE_M), g.rotations)),
        rgbs=as_np(g.rgb.clamp(0.0, 1.0)),
        opacities=as_np(g.opacities[:, None]),
    )


@dataclass
class ViewCamera:
    """One input camera: OpenCV camera-to-world pose, a name, and its panorama (``(H, W, 3)`` uint8) if known."""

    c2w: Tensor
    name: str = ""
    image: np.ndarray | None = None


@dataclass
class ViewerScene:
    """Handles of what :func:`build_scene` added."""

    splats: object
    frustums: list = field(default_factory=list)
    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    look_at: tuple[float, float, float] = (0.0, 0.0, 1.0)


def _thumbnail(image: np.ndarray, height: int = 128) -> np.ndarray:
    from PIL import Image

    image = np.asarray(image)
    if image.shape[0] <= height:
        return np.ascontiguousarray(image[..., :3]).astype(np.uint8)
    pil = Image.fromarray(np.ascontiguousarray(image[..., :3]).astype(np.uint8))
    return np.asarray(pil.resize((round(image.shape[1] * height / image.shape[0]), height), Image.BILINEAR))


def build_scene(server, gaussians: Gaussians, cameras: list[ViewCamera] = (),
                frustum_scale: float = 0.2) -> ViewerScene:
    """Add the splats (``/gaussians``) and one frustum per camera (``/cameras/NNN``) to a viser server,
    and point its initial camera at them (:func:`default_view`)."""
    cameras = list(cameras)
    arrays = splat_arrays(gaussians)
    server.scene.set_up_direction("-y")
    splats = server.scene.add_gaussian_splats(
        "/gaussians", centers=arrays.centers, covariances=arrays.covariances, rgbs=arrays.rgbs,
        opacities=arrays.opacities)
    frustums = []
    for i, cam in enumerate(cameras):
        c2w = cam.c2w.detach().to("cpu", torch.float64)
        # A panorama sees everything; the frustum marks where it was taken and where its centre column looks (+z).
        frustums.append(server.scene.add_camera_frustum(
            f"/cameras/{i:03d}", fov=math.radians(60.0), aspect=2.0, scale=frustum_scale, color=FRUSTUM_COLOR,
            image=None if cam.image is None else _thumbnail(cam.image),
            wxyz=matrix_to_quaternion(c2w[:3, :3]).numpy(), position=c2w[:3, 3].numpy()))
    position, look_at = default_view(gaussians, cameras)
    server.initial_camera.position = tuple(float(v) for v in position)
    server.initial_camera.look_at = tuple(float(v) for v in look_at)
    server.initial_camera.up = (0.0, -1.0, 0.0)
    return ViewerScene(splats, frustums, tuple(float(v) for v in position), tuple(float(v) for v in look_at))


def _quiet_server(viser, host: str, port: int):
    with contextlib.redirect_stdout(io.StringIO()):  # viser prints its address panel on start
        return viser.ViserServer(host=host, port=port, verbose=False)


def write_html(path: str | Path, gaussians: Gaussians, cameras: list[ViewCamera] = (),
               frustum_scale: float = 0.2) -> Path:
    """One self-contained HTML file showing the scene (viser's client with the scene embedded); atomic."""
    from .utils.atomic import atomic_path

    viser = import_viser()
    server = _quiet_server(viser, "127.0.0.1", 0)  # viser records the scene through a server; nothing is served
    try:
        build_scene(server, gaussians, cameras, frustum_scale)
        html = server.scene.as_html()
    finally:
        with contextlib.redirect_stdout(io.StringIO()):
            server.stop()
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(html, encoding="utf-8")
    return path


def serving_line(host: str, port: int, gaussians: int, cameras: int, duration: float | None) -> str:
    """What ``serve`` prints: the address, the scene's size, and how serving ends (Ctrl+C, or after ``duration``)."""
    shown = "localhost" if host in ("0.0.0.0", "::") else host
    ends = "Ctrl+C stops" if duration is None else f"stops after {duration:g} s (or Ctrl+C)"
    return f"viewer: http://{shown}:{port}  ({gaussians:,} Gaussians, {cameras} cameras; {ends})"


def serve(gaussians: Gaussians, cameras: list[ViewCamera] = (), host: str = "127.0.0.1", port: int = 8080,
          frustum_scale: float = 0.2, duration: float | None = None) -> None:
    """Serve the scene at ``http://host:port`` until interrupted (Ctrl+C) or ``duration`` seconds pass."""
    viser = import_viser()
    server = _quiet_server(viser, host, port)
    try:
        scene = build_scene(server, gaussians, cameras, frustum_scale)
        print(serving_line(host, server.get_port(), len(gaussians), len(scene.frustums), duration), flush=True)
        end = None if duration is None else time.monotonic() + duration
        while end is None or time.monotonic() < end:
            time.sleep(0.2 if end is None else max(min(0.2, end - time.monotonic()), 0.0))
    finally:
        with contextlib.redirect_stdout(io.StringIO()):
            server.stop()


# What one band of a screenshot may take (the reference renderer's own estimate): a picture that needs more is
# rendered in bands of rows, each within it; half the free memory where that is less.
SCREENSHOT_BUDGET_BYTES = 1 << 30


@dataclass(frozen=True)
class PinholeRows(CameraModel):
    """Rows ``top .. top + height - 1`` of the pinhole camera ``full``: its pixel map moved up by ``top``, so
    every Gaussian is kept or dropped and shaped exactly as in the whole picture (bands agree at their seams)."""

    full: Pinhole
    top: int
    height: int

    @property
    def width(self) -> int:
        return self.full.width

    @property
    def max_std(self) -> tuple[float, float]:
        return self.full.max_std

    def pixel_map(self, points: Tensor, settings: RasterSettings) -> PixelMap:
        m = self.full.pixel_map(points, settings)
        return PixelMap(m.u, m.v - self.top, m.depth, m.jacobian, m.valid)


def row_bytes(gaussians: Gaussians, c2w: Tensor, camera: Pinhole) -> Tensor:
    """``(H,)`` float64: the reference renderer's memory for each row of ``camera``'s picture, from the projected
    Gaussians' (clipped) 3-sigma boxes: every pixel of a box a fragment, every box row per tile a row span. An
    upper bound (the support is an ellipse inside the box), known before anything is rasterized."""
    from .render.projection import flatten_cameras, project_gaussians
    from .render.rasterize import BYTES_PER_FRAGMENT, BYTES_PER_ROW_SPAN

    h, w = camera.height, camera.width
    flat, flat_c2w, _ = flatten_cameras(gaussians.detach(), c2w.to(device=gaussians.device, dtype=gaussians.dtype))
    proj = project_gaussians(flat, flat_c2w, camera, RasterSettings())
    uv, extent = proj.uv.detach().double(), proj.extent.detach().double()
    i0 = torch.ceil(uv[:, 1] - extent[:, 1] - 0.5).clamp(min=0).long()
    i1 = torch.floor(uv[:, 1] + extent[:, 1] - 0.5).clamp(max=h - 1).long()
    columns = (torch.floor(uv[:, 0] + extent[:, 0] - 0.5).clamp(max=w - 1)
               - torch.ceil(uv[:, 0] - extent[:, 0] - 0.5).clamp(min=0) + 1).clamp(min=0)
    keep = (i1 >= i0) & (columns > 0)
    per_row = columns * BYTES_PER_FRAGMENT + (columns // RasterSettings().tile_size + 2) * BYTES_PER_ROW_SPAN
    change = torch.zeros(h + 1, dtype=torch.float64, device=uv.device)
    change.index_add_(0, i0[keep], per_row[keep]).index_add_(0, i1[keep] + 1, -per_row[keep])
    return change.cumsum(0)[:h].clamp(min=0).cpu()


def picture_bands(need: Tensor, budget: float) -> list[tuple[int, int]]:
    """``[(top, height), ...]`` covering all rows of ``need`` (bytes per row), each band within ``budget``;
    a ``MemoryError`` where one row alone exceeds it."""
    worst = int(need.argmax()) if len(need) else 0
    if len(need) and float(need[worst]) > budget:
        raise MemoryError(f"row {worst} of the picture alone needs about {_amount(float(need[worst]))}, more than "
                          f"the {_amount(budget)} one band may use")
    bands, top, total = [], 0, 0.0
    for row, cost in enumerate(need.tolist()):
        if row > top and total + cost > budget:
            bands.append((top, row - top))
            top, total = row, 0.0
        total += cost
    bands.append((top, len(need) - top))
    return bands


def _amount(size: float) -> str:
    return f"{size / 2**30:.1f} GiB" if size >= 2**30 else f"{size / 2**20:.0f} MiB"


def screenshot_budget(device) -> float:
    """Bytes one band may use: :data:`SCREENSHOT_BUDGET_BYTES`, or half of the free memory where that is less."""
    from .render.rasterize import available_memory

    free = available_memory(torch.device(device))
    return float(SCREENSHOT_BUDGET_BYTES if free is None else min(SCREENSHOT_BUDGET_BYTES, free / 2))


def render_picture(path: str | Path, gaussians: Gaussians, c2w: Tensor, size: tuple[int, int] = (480, 640),
                   fov_deg: float = 90.0, panorama: bool = False, background=(1.0, 1.0, 1.0),
                   backend: str = "auto") -> Path:
    """Render one view with our renderer and write it as a PNG (atomic): a pinhole camera with horizontal
    field of view ``fov_deg``, or an equirect panorama (``panorama=True``, ``size`` must be ``(H, 2H)``).

    The pinhole picture's memory is estimated first (:func:`row_bytes`); one that needs more than
    :func:`screenshot_budget` is rendered in bands of rows, each within it (the same picture, in pieces); a
    ``MemoryError`` says how much one row alone would need where even that does not fit."""
    from PIL import Image

    from .render import Equirect, render
    from .utils.atomic import atomic_path

    h, w = size
    g = gaussians.detach()
    c2w = c2w.to(device=g.device, dtype=g.dtype)
    if panorama:
        rgb = render(g, c2w, Equirect(h, w), background=background, backend=backend).rgb
    else:
        if not 1.0 <= fov_deg < 179.0:
            raise ValueError(f"field of view must be in [1, 179) degrees, got {fov_deg}")
        f = 0.5 * w / math.tan(math.radians(fov_deg) / 2)
        camera = Pinhole(torch.tensor([[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]]), h, w)
        bands = picture_bands(row_bytes(g, c2w, camera), screenshot_budget(g.device))
        rgb = torch.cat([render(g, c2w, PinholeRows(camera, top, rows), background=background, backend=backend).rgb
                         for top, rows in bands], dim=-2)
    picture = (rgb.clamp(0, 1) * 255 + 0.5).to(torch.uint8).permute(1, 2, 0).cpu().numpy()
    path = Path(path)
    with atomic_path(path) as tmp:
        Image.fromarray(picture).save(tmp, format="PNG")
    return path
