"""Reading and writing panoramas, 16-bit depth PNGs and pose text files, with clear errors.

Every reader raises ``FileNotFoundError`` (missing file) or ``ValueError`` (unreadable/corrupt file,
wrong size, non-2:1 panorama, non-finite numbers) with the offending path in the message.

Resizing (when a dataset is read at a lower resolution than stored):

* images: PIL's Lanczos filter on the 8-bit image (as PanSplat does), then ``/ 255``;
* depth: ``"area"`` (default) is a *validity-aware* box filter for integer down-scaling factors
  (each output pixel is the mean of the valid, non-zero input pixels of its block, 0 when the block
  has none) so holes neither shrink depths toward 0 nor blur across invalid pixels; ``"nearest"``
  samples the input pixel whose centre is nearest to the output pixel centre (also used for
  non-integer factors and up-sampling). Lanczos is never used for depth: it rings at occlusion edges.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np
import torch
from jaxtyping import Float
from PIL import Image, UnidentifiedImageError
from torch import Tensor

from ..utils.atomic import atomic_path

__all__ = [
    "DEPTH_PNG_SCALE",
    "open_image",
    "read_rgb",
    "read_depth_png",
    "read_depth_npy",
    "write_rgb",
    "to_uint8",
    "write_depth_png",
    "read_matrix_txt",
    "resize_depth",
    "check_panorama_size",
]

DEPTH_PNG_SCALE = 1000.0  # 16-bit PNG units per metre (millimetres, PanoGRF convention)


def check_panorama_size(height: int, width: int, path: Path | str, expected: tuple[int, int] | None = None) -> None:
    """Raise ``ValueError`` naming ``path`` unless the size is 2:1 (and equals ``expected`` (H, W))."""
    if width != 2 * height:
        raise ValueError(f"{path}: panorama must be 2:1 (W == 2H), got {width}x{height} (WxH)")
    if expected is not None and (height, width) != tuple(expected):
        raise ValueError(f"{path}: expected {expected[1]}x{expected[0]} (WxH), got {width}x{height}")


# Larger images are refused before they are decoded (a 200 MP RGB image is 600 MB as 8-bit and 2.4 GB
# as float; the model runs at a fraction of that anyway). PIL's own decompression-bomb limit is replaced by it.
MAX_IMAGE_PIXELS = 200_000_000


def _too_large(path: Path, width: int, height: int) -> ValueError:
    return ValueError(f"{path}: {width}x{height} (WxH) is {width * height / 1e6:.3g} megapixels, more than the "
                      f"{MAX_IMAGE_PIXELS / 1e6:.3g} MP this reads; downscale it first (e.g. to 4096x2048)")


def _missing(path: Path):
    """Raise the error of a file that is not there: a symlink that leads nowhere (a loop, a missing target) says so."""
    if path.is_symlink():
        raise FileNotFoundError(f"{path} is a symlink that leads to no file (a loop, or its target is missing); "
                                "replace it with the file")
    raise FileNotFoundError(f"missing file: {path}")


def open_image(path: Path | str) -> Image.Image:
    """Open and fully decode an image file; corrupt or truncated files raise ``ValueError``, and so do images of
    more than ``MAX_IMAGE_PIXELS`` pixels (checked from the header, before decoding)."""
    path = Path(path)
    if not path.is_file():
        _missing(path)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # our limit below decides
            with Image.open(path) as img:
                if img.width * img.height > MAX_IMAGE_PIXELS:
                    raise _too_large(path, img.width, img.height)
                img.load()
                return img.copy()
    except Image.DecompressionBombError as exc:  # beyond PIL's hard limit (2x its warning size): refused at open
        size = re.search(r"\((\d+) pixels\)", str(exc))
        pixels = int(size.group(1)) if size else None
        if pixels is None or pixels > MAX_IMAGE_PIXELS:
            limit = f"the {MAX_IMAGE_PIXELS / 1e6:.3g} MP this reads"
        else:
            limit = f"PIL's limit of {2 * (Image.MAX_IMAGE_PIXELS or 0) / 1e6:.3g} MP (PIL.Image.MAX_IMAGE_PIXELS)"
        raise ValueError(f"{path}: {f'{pixels / 1e6:.3g} megapixels, ' if pixels else ''}more than {limit}; "
                         "downscale it first (e.g. to 4096x2048)") from None
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise ValueError(f"{path}: cannot decode image ({exc})") from exc


def read_rgb(
    path: Path | str, size: tuple[int, int] | None = None, expected: tuple[int, int] | None = None
) -> Float[Tensor, "3 H W"]:
    """Panorama -> float ``(3, H, W)`` in ``[0, 1]``.

    8-bit RGB/RGBA/palette/CMYK images are converted to RGB (alpha dropped); grayscale is repeated
    over the channels, 16-bit grayscale scaled by 65535, float images must already lie in [0, 1].
    ``expected`` (H, W) checks the stored size; ``size`` (H, W) resizes with Lanczos.
    """
    img = open_image(path)
    check_panorama_size(img.height, img.width, path, expected)
    img = _to_rgb8(img, path)
    if size is not None and (img.height, img.width) != tuple(size):
        check_panorama_size(size[0], size[1], f"{path} (requested size)")
        img = img.resize((size[1], size[0]), Image.LANCZOS)
    return torch.from_numpy(np.asarray(img, dtype=np.uint8).copy()).permute(2, 0, 1).float() / 255.0


def _to_rgb8(img: Image.Image, path) -> Image.Image:
    """8-bit RGB from any image mode PIL decodes, scaling high-bit-depth and float data explicitly
    (PIL's own ``convert("RGB")`` clips 16-bit values to 255 and float ones to 0/1)."""
    if img.mode in ("RGB", "RGBA", "RGBX", "P", "PA", "L", "LA", "CMYK", "YCbCr", "1"):
        return img.convert("RGB")
    arr = np.asarray(img)
    if img.mode.startswith("I;16"):
        gray = arr.astype(np.float64) / 65535.0
    elif img.mode == "I":
        gray = arr.astype(np.float64) / (65535.0 if arr.max(initial=0) <= 65535 else float(np.iinfo(np.int32).max))
    elif img.mode == "F":
        if not np.isfinite(arr).all() or arr.min(initial=0) < 0 or arr.max(initial=0) > 1:
            raise ValueError(f"{path}: float image values must be finite and in [0, 1] "
                             f"(got {np.nanmin(arr):.3g}..{np.nanmax(arr):.3g}); save it as an 8-bit PNG/JPEG")
        gray = arr.astype(np.float64)
    else:
        raise ValueError(f"{path}: unsupported image mode {img.mode!r}; save it as an 8-bit RGB PNG or JPEG")
    gray8 = np.clip(np.round(gray * 255.0), 0, 255).astype(np.uint8)
    return Image.fromarray(np.repeat(gray8[..., None], 3, axis=-1))


def read_depth_png(
    path: Path | str,
    size: tuple[int, int] | None = None,
    expected: tuple[int, int] | None = None,
    scale: float = DEPTH_PNG_SCALE,
    resize_mode: str = "area",
) -> Float[Tensor, "H W"]:
    """16-bit depth PNG (``scale`` units per metre, 0 = hole) -> float ``(H, W)`` metres."""
    img = open_image(path)
    check_panorama_size(img.height, img.width, path, expected)
    if img.mode == "L":
        raise ValueError(f"{path}: 8-bit depth PNG; depth must be a 16-bit PNG ({scale:g} units per metre, "
                         "e.g. millimetres) or a float .npy in metres")
    if img.mode not in ("I;16", "I;16B", "I;16L", "I"):
        raise ValueError(f"{path}: depth PNG must be single-channel 16-bit, got mode {img.mode}")
    depth = torch.from_numpy(np.asarray(img).astype(np.float32)) / scale
    if size is not None:
        depth = resize_depth(depth, size, mode=resize_mode)
    return depth


def read_depth_npy(path: Path | str, size: tuple[int, int] | None = None, resize_mode: str = "area",
                   expected: tuple[int, int] | None = None) -> Tensor:
    """Float depth in metres from a ``.npy`` file ``(H, W)`` of numbers (not booleans, records or objects),
    stored at ``expected`` (H, W) when given; NaN/Inf/negative become 0 (invalid)."""
    path = Path(path)
    if not path.is_file():
        _missing(path)
    try:
        arr = np.load(path)
    except (ValueError, OSError) as exc:
        raise ValueError(f"{path}: cannot read .npy ({exc})") from exc
    if not isinstance(arr, np.ndarray):  # np.load opens a .npz archive whatever the file is named
        arr.close()
        raise ValueError(f"{path}: a .npz archive, not a .npy array; save the depth map alone with numpy.save "
                         "(float32 metres, H x W)")
    if arr.dtype.kind not in "fiu":  # bool masks, structured records, strings: not a depth map
        raise ValueError(f"{path}: depth must be a float array of metres, got dtype {arr.dtype}")
    arr = np.squeeze(arr)
    if arr.ndim != 2:
        raise ValueError(f"{path}: depth must be 2-D (H, W), got shape {arr.shape}")
    check_panorama_size(arr.shape[0], arr.shape[1], path, expected)
    depth = torch.from_numpy(np.nan_to_num(arr.astype(np.float32), nan=0.0, posinf=0.0, neginf=0.0)).clamp(min=0)
    return resize_depth(depth, size, mode=resize_mode) if size is not None else depth


def to_uint8(image: Float[Tensor, "3 H W"]) -> np.ndarray:
    """Float ``(3, H, W)`` in ``[0, 1]`` (any device or float dtype) -> uint8 ``(H, W, 3)``, rounded."""
    return (image.detach().float().clamp(0, 1) * 255.0 + 0.5).to(torch.uint8).permute(1, 2, 0).cpu().numpy()


def write_rgb(path: Path | str, image: Float[Tensor, "3 H W"] | np.ndarray) -> None:
    """Save float ``(3, H, W)`` in ``[0, 1]`` (or uint8 ``(H, W, 3)``) as an 8-bit PNG."""
    if isinstance(image, Tensor):
        image = to_uint8(image)
    with atomic_path(path) as tmp:
        Image.fromarray(np.ascontiguousarray(image)).save(tmp, format="PNG", compress_level=1)


def write_depth_png(path: Path | str, depth: Float[Tensor, "H W"] | np.ndarray, scale: float = DEPTH_PNG_SCALE) -> None:
    """Save metric depth as a 16-bit PNG; depths beyond the 16-bit range or non-finite become 0."""
    d = depth.detach().cpu().numpy() if isinstance(depth, Tensor) else np.asarray(depth)
    d = np.nan_to_num(d.astype(np.float64), nan=0.0, posinf=0.0, neginf=0.0) * scale
    d = np.where((d > 0) & (d < 65535.5), np.round(d), 0).astype(np.uint16)
    with atomic_path(path) as tmp:
        Image.fromarray(d).save(tmp, format="PNG", compress_level=1)


def read_matrix_txt(path: Path | str, shape: tuple[int, ...]) -> np.ndarray:
    """Whitespace-separated numbers (e.g. ``rot.txt`` 3x3, ``tran.txt`` 3) reshaped to ``shape``."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"missing file: {path}")
    try:
        values = np.array(path.read_text().split(), dtype=np.float64)
    except ValueError as exc:
        raise ValueError(f"{path}: not a list of numbers ({exc})") from exc
    if values.size != int(np.prod(shape)):
        raise ValueError(f"{path}: expected {int(np.prod(shape))} numbers for shape {shape}, got {values.size}")
    if not np.isfinite(values).all():
        raise ValueError(f"{path}: contains non-finite values")
    return values.reshape(shape)


def resize_depth(depth: Float[Tensor, "*b H W"], size: tuple[int, int], mode: str = "area") -> Tensor:
    """Resize depth maps; see the module docstring for ``"area"`` vs ``"nearest"``."""
    h, w = depth.shape[-2:]
    out_h, out_w = size
    if (h, w) == (out_h, out_w):
        return depth
    if mode not in ("area", "nearest"):
        raise ValueError(f"unknown depth resize mode {mode!r} (use 'area' or 'nearest')")
    if mode == "area" and h % out_h == 0 and w % out_w == 0:
        fh, fw = h // out_h, w // out_w
        blocks = depth.reshape(*depth.shape[:-2], out_h, fh, out_w, fw)
        valid = (blocks > 0) & torch.isfinite(blocks)
        total = torch.where(valid, blocks, torch.zeros_like(blocks)).sum(dim=(-3, -1))
        count = valid.sum(dim=(-3, -1))
        return torch.where(count > 0, total / count.clamp(min=1), torch.zeros_like(total))
    rows = ((torch.arange(out_h) + 0.5) * h / out_h).floor().long().clamp(max=h - 1)
    cols = ((torch.arange(out_w) + 0.5) * w / out_w).floor().long().clamp(max=w - 1)
    return depth[..., rows[:, None], cols[None, :]]
