"""The one validation layer of the public entries: model inputs, poses, options, plausibility bounds.

Every check raises an :class:`~cylindersplat.errors.InputError` (a ``ValueError``) whose one-line message
names the value, where it came from and the fix; the CLI prints it as its error line. The library's entries
(:func:`~cylindersplat.inference.reconstruct_gaussians`, :func:`~cylindersplat.render.render`, the folder
reader) and the CLI's options call these instead of checking on their own.

Plausibility bounds (finite values that are almost surely a unit or format mistake), documented in
``docs/inference.md``:

* depth: the median positive depth of a view must lie in [:data:`MIN_DEPTH_M`, :data:`MAX_DEPTH_M`]
  (1 cm to 1 km; millimetres read as metres land above it, a wrong ``depth_scale`` on either side);
* pose: camera translations up to :data:`MAX_TRANSLATION_M` (10 km) from the origin (float32 loses
  centimetres beyond it: recentre the poses); a splat file whose Gaussians lie beyond it is warned about
  (:func:`check_splats_near_origin`).

Scale warnings (:func:`check_scene_scale`; a :class:`ScaleWarning`, the input is used as given): the scene's
median depth beyond :data:`INDOOR_MAX_MEDIAN_M` (100 m, deeper than any room) or below
:data:`MIN_SCENE_MEDIAN_M` (5 cm, smaller than any room: a scene scaled by 1e-3), and camera spacing out of
proportion with the depth (below :data:`MIN_SPACING_RATIO` or above :data:`MAX_SPACING_RATIO` times the median
depth: poses and depth in different units, or SfM poses of arbitrary scale).
"""

from __future__ import annotations

import math
import warnings

import torch
from torch import Tensor

from .errors import ImplausibleInputError, InputError
from .utils.notices import Notice

__all__ = ["check_images", "check_depths", "check_c2w", "check_depth_plausible", "check_translation_plausible",
           "check_opacity_threshold", "check_constant_depth", "farthest_camera", "camera_too_far",
           "check_splats_near_origin", "check_scene_scale", "ScaleWarning", "PLAUSIBILITY_OVERRIDE", "MIN_DEPTH_M",
           "MAX_DEPTH_M", "MAX_TRANSLATION_M"]

MIN_DEPTH_M = 0.01
MAX_DEPTH_M = 1000.0
MAX_TRANSLATION_M = 10_000.0
INDOOR_MAX_MEDIAN_M = 100.0  # a room is never this deep; outdoor scenes can be, so a warning, not a refusal
MIN_SCENE_MEDIAN_M = 0.05  # below this (and above MIN_DEPTH_M) a scene is smaller than any room: km read as m
MIN_SPACING_RATIO = 1e-3  # camera spacing / median depth: 1 mm apart in a 1 m room is no capture
MAX_SPACING_RATIO = 100.0  # cameras 300 m apart around 3 m of depth do not see the same scene


def _tensor(value, name: str) -> Tensor:
    if not isinstance(value, Tensor):
        raise InputError(f"{name} must be a torch.Tensor, got {type(value).__name__}")
    if not value.is_floating_point():
        raise InputError(f"{name} must be a float tensor, got {value.dtype} (convert with .float(); images: / 255)")
    return value


def _first_bad(mask: Tensor) -> str:
    """``"view 1"``: the first view (leading index) where ``mask`` is true."""
    return f"view {int(mask.flatten(1).any(1).nonzero()[0])}"


def check_images(images, stride: int | None = None, name: str = "images") -> None:
    """``images``: float ``(V, 3, H, W)``, V >= 1, finite, in [0, 1], W == 2H, H divisible by ``stride``
    (the model's token stride)."""
    images = _tensor(images, name)
    if images.ndim != 4 or images.shape[1] != 3 or images.shape[0] < 1:
        raise InputError(f"{name} must have shape (V, 3, H, W) with V >= 1 (RGB panoramas), got {tuple(images.shape)}")
    h, w = images.shape[-2:]
    if w != 2 * h:
        raise InputError(f"{name} are {h}x{w}, but equirect panoramas need W == 2H; resize them, e.g. to {h}x{2 * h}")
    if stride and h % stride:
        low = max(stride, h // stride * stride)
        raise InputError(f"{name} are {h}x{w}, but this model needs a height divisible by {stride}; resize them, e.g. "
                         f"to {low}x{2 * low}")
    finite = torch.isfinite(images)
    if not finite.all():
        raise InputError(f"{name} hold NaN or Inf values ({_first_bad(~finite)}); give finite RGB in [0, 1]")
    low, high = float(images.min()), float(images.max())
    if low < 0 or high > 1:
        hint = "divide 8-bit images by 255" if high > 1 else "clamp them"
        raise InputError(f"{name} must be RGB in [0, 1], got values in [{low:g}, {high:g}]; {hint}")


def check_depths(depths, images: Tensor, name: str = "depths") -> None:
    """``depths``: float ``(V, H, W)`` matching ``images`` ``(V, 3, H, W)``, finite, >= 0 (0 = unknown)."""
    depths = _tensor(depths, name)
    expected = (images.shape[0], *images.shape[-2:])
    if tuple(depths.shape) != expected:
        raise InputError(f"{name} must have shape (V, H, W) = {expected} to match the images, got "
                         f"{tuple(depths.shape)}; resize the depth maps to the images' size")
    finite = torch.isfinite(depths)
    if not finite.all():
        raise InputError(f"{name} hold NaN or Inf values ({_first_bad(~finite)}); use 0 for unknown depth")
    if (depths < 0).any():
        raise InputError(f"{name} hold negative values ({_first_bad(depths < 0)}, min {float(depths.min()):g}); depth "
                         "is a radial distance in metres >= 0 (0 = unknown)")


def check_c2w(c2w, count: int, name: str = "c2w") -> None:
    """``c2w``: ``(count, 4, 4)`` finite rigid camera-to-world poses (a rotation, not a reflection)."""
    from .geometry.poses import validate_c2w

    c2w = _tensor(c2w, name)
    if tuple(c2w.shape) != (count, 4, 4):
        raise InputError(f"{name} must have shape ({count}, 4, 4), one pose per image, got {tuple(c2w.shape)}")
    try:
        validate_c2w(c2w, name)
    except ValueError as exc:
        raise InputError(f"{exc}; give OpenCV camera-to-world matrices [R | t] with R a rotation (det +1)") from None
    check_translation_plausible(c2w, name)


PLAUSIBILITY_OVERRIDE = "--skip-plausibility-checks, or check_plausibility=False in Python"


def check_depth_plausible(depth: Tensor, where: str, override: str = PLAUSIBILITY_OVERRIDE) -> None:
    """The median positive depth of ``depth`` within [:data:`MIN_DEPTH_M`, :data:`MAX_DEPTH_M`] metres, else
    :class:`ImplausibleInputError` naming ``where``, the bound and how to skip the check (``override``, by
    default :data:`PLAUSIBILITY_OVERRIDE`: a real scene beyond the bounds is possible, if rare)."""
    # Datasets check every frame they load: a sample of every 8th row and column decides at a 64th of the
    # cost when it lies well inside the bounds (five orders of magnitude apart); near a bound the full median decides.
    quick = _median_positive(depth[..., ::8, ::8]) if depth.ndim >= 2 else None
    if quick is not None and 2 * MIN_DEPTH_M <= quick <= MAX_DEPTH_M / 2:
        return
    median = _median_positive(depth)
    if median is None:
        return  # all unknown: refused (or accepted for NoPrior) by the readers, which know why
    if MIN_DEPTH_M <= median <= MAX_DEPTH_M:
        return
    if median > MAX_DEPTH_M:
        bound, units = f"above {MAX_DEPTH_M:g} m", " (millimetres read as metres? check depth_scale or the .npy units)"
    else:
        bound, units = f"below {MIN_DEPTH_M:g} m", " (check depth_scale or the .npy units)"
    raise ImplausibleInputError(f"{where}: median depth {median:.3g} m is {bound}{units}; depth is radial metres "
                                f"({override}, to use it anyway)")


class ScaleWarning(Notice):
    """The scene's size or camera spacing suggests a unit mistake; the input is used as given."""


POSE_SCALE_FIX = "cylindersplat data import-poses --scale (metres per unit), or scale the translations in poses.json"
DEPTH_SCALE_FIX = '"depth_scale" of poses.json (depth file units per metre; .npy in metres)'


def check_scene_scale(depths: Tensor, c2w: Tensor, where: str) -> None:
    """Warn (:class:`ScaleWarning`) once per scene when its size is implausible for an indoor capture: the median
    positive depth of all ``depths`` beyond :data:`INDOOR_MAX_MEDIAN_M` or below :data:`MIN_SCENE_MEDIAN_M`, or the
    largest distance between two cameras of ``c2w`` out of proportion with it (:data:`MIN_SPACING_RATIO`,
    :data:`MAX_SPACING_RATIO`). The message names ``where``, the bound, the likely unit mistake and its fix."""
    median = _median_positive(depths)
    if median is None:
        return
    silence = "--skip-plausibility-checks silences this"
    if median > INDOOR_MAX_MEDIAN_M:
        _warn(f"{where}: median scene depth {median:.3g} m is beyond {INDOOR_MAX_MEDIAN_M:g} m, deeper than any "
              f"indoor room; if the scene is indoors, the depth is in the wrong units (fix {DEPTH_SCALE_FIX}); "
              f"{silence}")
        return
    if median < MIN_SCENE_MEDIAN_M:
        _warn(f"{where}: median scene depth {median * 100:.3g} cm is below {MIN_SCENE_MEDIAN_M * 100:g} cm, smaller "
              f"than any room: a scene scaled by 1e-3 (kilometres read as metres?); give depth in metres (fix "
              f"{DEPTH_SCALE_FIX}) and poses in metres ({POSE_SCALE_FIX}); {silence}")
        return
    centres = c2w[:, :3, 3].detach().double()
    spacing = float(torch.cdist(centres, centres).max()) if len(centres) > 1 else 0.0
    if spacing == 0.0:
        return  # one camera (or all at one spot): no spacing to compare
    ratio = spacing / median
    if ratio < MIN_SPACING_RATIO:
        _warn(f"{where}: the cameras are at most {spacing:.3g} m apart around a median depth of {median:.3g} m "
              f"({ratio:.2g}x, below {MIN_SPACING_RATIO:g}x): poses in kilometres or of arbitrary SfM scale? give "
              f"them in metres ({POSE_SCALE_FIX}); {silence}")
    elif ratio > MAX_SPACING_RATIO:
        _warn(f"{where}: the cameras are up to {spacing:.3g} m apart around a median depth of {median:.3g} m "
              f"({ratio:.3g}x, above {MAX_SPACING_RATIO:g}x): poses in millimetres or of arbitrary SfM scale? give "
              f"them in metres ({POSE_SCALE_FIX}); {silence}")


def _warn(message: str) -> None:
    warnings.warn(message, ScaleWarning, stacklevel=3)


def _median_positive(depth: Tensor) -> float | None:
    """The median of the positive (known) values of ``depth``; None if there is none."""
    depth = depth.detach()
    valid = depth[depth > 0]
    return float(valid.float().median()) if valid.numel() else None


def farthest_camera(c2w: Tensor) -> float:
    """The largest distance (m) of a camera of ``c2w`` from the origin."""
    return float(_farthest(c2w)) if c2w.numel() else 0.0


def camera_too_far(c2w: Tensor) -> Tensor:
    """Whether a camera of ``c2w`` lies beyond :data:`MAX_TRANSLATION_M` (``farthest_camera(c2w) >
    MAX_TRANSLATION_M``) as a device-side bool scalar, unread (a render that reads the device once reads it with
    its pair count)."""
    if not c2w.numel():
        return torch.zeros((), dtype=torch.bool, device=c2w.device)
    return _farthest(c2w) > MAX_TRANSLATION_M


def _farthest(c2w: Tensor) -> Tensor:
    return c2w[..., :3, 3].detach().double().norm(dim=-1).max()


def check_translation_plausible(c2w: Tensor, where: str) -> None:
    """Camera positions within :data:`MAX_TRANSLATION_M` of the origin (float32 has centimetres to spare there)."""
    far = farthest_camera(c2w)
    if far > MAX_TRANSLATION_M:
        raise ImplausibleInputError(f"{where}: a camera lies {far:.3g} m from the origin, "
                                    f"beyond {MAX_TRANSLATION_M:g} m; recentre the poses (subtract a common "
                                    "origin) and give them in metres")


def check_splats_near_origin(means: Tensor, where: str) -> None:
    """Warn (``RuntimeWarning``) when most Gaussians of a splat file lie beyond :data:`MAX_TRANSLATION_M` from the
    origin (georeferenced coordinates): their float32 positions there are only good to the step float32 keeps, and
    every render of them smears. The median distance decides (a few far sky Gaussians do not)."""
    if not means.numel():
        return
    median = float(means.detach().double().norm(dim=-1).median())
    if median > MAX_TRANSLATION_M:
        step = float(torch.finfo(torch.float32).eps) * 2.0 ** math.floor(math.log2(median))
        warnings.warn(f"{where}: the Gaussians lie {median:.3g} m from the origin (median), beyond "
                      f"{MAX_TRANSLATION_M:g} m: float32 keeps only {step:.2g} m steps there, so positions and "
                      "renders are wrong; recentre the scene (subtract a common origin from the Gaussians and the "
                      "poses)", RuntimeWarning, stacklevel=2)


def check_opacity_threshold(value, name: str = "min_opacity") -> float:
    """A minimum opacity in [0, 1) (1 would drop every Gaussian)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or not 0 <= value < 1:
        raise InputError(f"{name} must be a number in [0, 1) (Gaussians at or below it are dropped), got {value!r}")
    return float(value)


def check_constant_depth(depth, spec: str = "constant") -> float:
    """A constant depth prior's metres: finite, within [:data:`MIN_DEPTH_M`, :data:`MAX_DEPTH_M`]."""
    if isinstance(depth, bool) or not isinstance(depth, (int, float)) or not math.isfinite(depth) or depth <= 0:
        raise InputError(f"{spec}:{depth!r}: a constant depth prior needs a positive finite depth in metres, e.g. "
                         f"{spec}:2.5")
    if not MIN_DEPTH_M <= depth <= MAX_DEPTH_M:
        raise ImplausibleInputError(f"{spec}:{depth:g}: {depth:g} m is outside the plausible {MIN_DEPTH_M:g} to "
                                    f"{MAX_DEPTH_M:g} m; give the scene's typical distance in metres, e.g. {spec}:2.5")
    return float(depth)
