"""Typed configuration of the CylinderSplat model, with named presets.

Presets (:func:`get_config`):

* ``"paper"`` - the configuration of the paper (512x1024 input, cylindrical triplanes with
  ``(N_r, N_z, N_theta) = (16, 64, 128)`` for cross-plane attention / decoding and
  ``(N'_r, N'_z, N'_theta) = (8, 32, 64)`` for triplane-to-image attention, 10 m radius and height).
  It has 13.76 M parameters against the paper's 13.6 M (+1.2 %). The paper does not give the widths
  of its layers; ours were chosen as the natural ResNet / ViT widths and then the token width was
  set so that the total lands on the published count (see ``docs/model.md`` for the breakdown).
* ``"tiny_paper"`` - the paper's model (every choice at the paper's default) with small widths and grids;
  forward + backward at 64x128 on a CPU in well under a second per view. The tests build it. It was called
  ``"tiny"`` until 2026-11-26; that name still works, with a ``FutureWarning``, because it now names another model:
  the ``tiny`` *training* preset's (``configs/tiny.yaml``: ``tiny_paper`` with issue 23's hidden-space recipe and
  finer triplanes, ``load_config("tiny").model``), which the shipped ``tiny-synth`` weights use (their stored config
  says ``name: tiny``).
* ``"paper_spherical"`` / ``"paper_cartesian"`` - the paper configuration with the ablation's
  spherical ``(rho, theta, lambda)`` or Cartesian ``(x, y, z)`` triplanes and the same number of
  cells (Cartesian: ``(64, 32, 64)`` over 20 m x 10 m x 20 m, so cells are ~0.3 m cubes).

Grid resolutions are given in the coordinate system's axis order ``(q0, q1, q2)``; for the
cylinder that is ``(r, theta, h)``, so the paper's ``(N_r, N_z, N_theta) = (16, 64, 128)`` is
``grid = (16, 128, 64)``.
"""

from __future__ import annotations

import dataclasses
import math
import sys
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from ..errors import InputError

__all__ = [
    "BackboneConfig",
    "AttentionConfig",
    "PixelBranchConfig",
    "VolumeBranchConfig",
    "FusionConfig",
    "ModelConfig",
    "PRESETS",
    "RENAMED_PRESETS",
    "get_config",
    "config_to_dict",
    "config_from_dict",
    "CHOICES",
    "COLOR_RULES",
    "UnknownConfigKey",
    "set_dotted",
    "get_dotted",
]

BranchMode = Literal["pixel", "volume", "both"]
CoordinateKind = Literal["cylindrical", "spherical", "cartesian"]

# volume.color -> what it is (model/rgb_retrieval.py builds them)
COLOR_RULES = {
    "retrieval": "Eq. 6: softmax over views of -(d_g - d_o) / T at the projection (the paper)",
    "surface": "colour of the observed surface points nearest the Gaussian (taps around the projection, sharp T in m)",
    "released_mlp": "the released code's MLP over every view's 3x3 colour taps and d_g - d_o",
    "decoded": "decoded from the triplane feature alone, no image lookup (the ablation's w/o RGB row)",
}

# Every string choice of the model config, defined once: validate() checks against it and the modules that
# dispatch on a choice (make_coordinates, build_color_module, fuse_gaussians, ...) cover exactly these values.
CHOICES: dict[str, tuple[str, ...]] = {
    "mode": ("pixel", "volume", "both"),
    "volume.coordinates": ("cylindrical", "spherical", "cartesian"),
    "volume.init": ("shared", "isolated"),
    "volume.scale_transform": ("paper", "exact", "cartesian"),
    "volume.color": tuple(COLOR_RULES),
    "volume.placement": ("per_camera", "central"),
    "volume.image_query": ("coarse", "full"),
    "volume.image_views": ("own", "all"),
    "fusion.strategy": ("concat", "depth_prune"),
    "fusion.side": ("both", "front", "hidden"),
    "fusion.pixel_clearing": ("none", "seen_through", "at_depth_edges"),
    "fusion.pixel_footprint": ("per_view", "covisible"),
    "render_layering": ("one_pass", "pixel_over_volume"),
    "render_pixel_blending": ("over", "surface"),
    "prior_alignment": ("none", "photometric"),
    "pixel.footprint": ("learned", "pixel", "surface"),
    "pixel.opacity": ("learned", "opaque"),
    "pixel.refine_depth": ("everywhere", "where_missing"),
    # The training run's choices: keys of the experiment config (training/config.py's TrainConfig and LossConfig),
    # checked when a preset or override sets them. loss.volume_loss names training/loss_terms/volume.py's
    # VOLUME_LOSS_MODES (a test keeps the two equal); train.stage2_render is model/curriculum.py's STAGE2_RENDERS.
    "train.amp": ("auto", "bf16", "off"),
    "train.stage2_render": ("volume", "fused"),
    "train.render_drawing": ("one_pass", "model"),
    "loss.use_lpips": ("auto", "on", "off"),
    "loss.volume_loss": ("scaled", "released"),
    "loss.pixel_stage_hidden": ("fill", "leave"),
    "data.augment": ("none", "captures"),  # training/config.py's DataConfig (cylindersplat.data.augment)
}


class UnknownConfigKey(InputError, AttributeError):
    """A dotted key that names no field of the config (a ``ValueError``, and an ``AttributeError`` as
    :meth:`ModelConfig.replace` raised before)."""


def set_dotted(tree: Any, key: str, value: Any, *, what: str = "key") -> None:
    """Write ``value`` at the dotted ``key`` (``"volume.grid"``) of ``tree``: the one dotted-path writer.

    ``tree`` is a nested dict (a preset, overrides, changes: missing sections are created) or a config dataclass
    (every name must be a field: :class:`UnknownConfigKey` names the key and the valid fields). Values are stored
    as given (a list stays one value). ``what`` names the key's kind in errors (``"override"``, ``"change"``).
    """
    parts = key.split(".")
    if not all(part.strip() for part in parts):
        raise InputError(f"{what} {key!r}: a dotted key needs a name before, between and after its dots")
    target = tree
    for depth, part in enumerate(parts):
        last = depth == len(parts) - 1
        if dataclasses.is_dataclass(target) and not isinstance(target, type):
            names = [f.name for f in dataclasses.fields(target)]
            if part not in names:
                section = ".".join(parts[:depth]) or type(target).__name__
                raise UnknownConfigKey(f"unknown config field {key!r}: {section} has no {part!r}; "
                                       f"valid: {', '.join(names)}")
            if last:
                setattr(target, part, value)
            else:
                target = getattr(target, part)
        elif isinstance(target, dict):
            if last:
                target[part] = value
            else:
                target = target.setdefault(part, {})
        else:
            section = ".".join(parts[:depth])
            clash = f" conflicts with another {what}:" if isinstance(tree, dict) else ":"
            raise InputError(f"{what} {key!r}{clash} {section} is the value {target!r:.40}, not a section")


def get_dotted(tree: Any, key: str) -> Any:
    """The value at the dotted ``key`` of a config dataclass or nested dict (the reader beside :func:`set_dotted`)."""
    for part in key.split("."):
        tree = tree[part] if isinstance(tree, dict) else getattr(tree, part)
    return tree


@dataclass
class BackboneConfig:
    """ResNet feature extractor (BasicBlocks, GroupNorm, circular padding along the panorama width).

    Input: RGB + normalised log depth prior + prior-valid mask (5 channels). The stem downsamples
    by 4; stage ``s`` by a further ``2**s`` so the last stage's stride (the token stride) is
    ``4 * 2**(len(widths) - 1)``.
    """

    in_channels: int = 5
    stem_width: int = 64
    widths: tuple[int, ...] = (64, 128, 256)
    blocks: tuple[int, ...] = (2, 2, 2)
    groups: int = 8  # GroupNorm groups; batch statistics are meaningless at batch size 1-2

    @property
    def token_stride(self) -> int:
        return 4 * 2 ** (len(self.widths) - 1)


@dataclass
class AttentionConfig:
    """L blocks alternating intra-view (frame) and cross-view (global) self-attention."""

    dim: int = 336
    depth: int = 6  # L: total number of attention blocks; even blocks are frame, odd are global
    heads: int = 6  # head width 56: a multiple of 8, as fused GPU attention kernels want
    mlp_ratio: float = 4.0
    ray_frequencies: int = 4  # Fourier frequencies of the ray-direction embedding


@dataclass
class PixelBranchConfig:
    decoder_widths: tuple[int, ...] = (128, 64, 64, 32)  # one per 2x upsampling step, coarse to fine
    feature_dim: int = 64  # channels of F_pano (the per-pixel feature map)
    head_hidden: int = 64  # hidden width of the per-pixel Gaussian head
    max_log_depth_offset: float = 0.7  # refined = prior * exp(max * tanh(.)): factor in [0.5, 2]
    min_depth: float = 0.05  # radial depth floor (m) when the prior is missing everywhere
    scale_range: tuple[float, float] = (0.25, 4.0)  # Gaussian std-dev in units of the pixel footprint
    # > 0: pixel opacity x exp(-g^2 / (2 edge_sigma^2)), g = largest |log depth| step to a neighbour pixel;
    # fades the "flying" Gaussians a smooth depth map strings across occlusion boundaries (0 = off)
    edge_sigma: float = 0.0
    # Issue 34 (docs/model.md, "Sharp pixel Gaussians"): "learned" scales/rotations from the head (the paper);
    # "pixel": isotropic, std-dev = refined depth x pi / H x footprint_px (the input pixel's own size, as a warp);
    # "surface": flat on the pixel's own patch of the surface it sees, footprint_px times its extent
    footprint: Literal["learned", "pixel", "surface"] = "learned"
    footprint_px: float = 0.35
    # "learned" opacity from the head (the paper), or "opaque": 1 on every seen surface (edge fading still applies)
    opacity: Literal["learned", "opaque"] = "learned"
    # "everywhere": the refined depth is prior x exp(offset) at every pixel (the paper); "where_missing": the prior is
    # kept where it is valid and the offset only moves the filled-in depth of its holes (a depth the user trusts)
    refine_depth: Literal["everywhere", "where_missing"] = "everywhere"


@dataclass
class VolumeBranchConfig:
    """Volume branch (paper Sec. 3.2).

    Ablation switches (defaults = the full model; see ``docs/model.md``, "Ablation switches"):

    * ``coordinates`` - ``cylindrical`` | ``spherical`` | ``cartesian`` triplanes (Table
      "Ablation Study", rows "Only Cylindrical / Spherical / Cartesian Volume Branch").
    * ``color`` - ``retrieval`` (Eq. 6) | ``decoded``: colour = sigmoid(MLP(volume head's colour
      feature)), no projection into the input images (row "Only Cylindrical Volume Branch (w/o RGB)").
    * ``placement`` - ``per_camera`` (one local triplane per input camera) | ``central``: OmniScene's
      single triplane centred on the mean camera centre with the first camera's rotation, whose
      triplane-to-image attention reads every view (row "Full (w/o Multi Triplane)").
    * ``scale_transform`` - ``paper`` (Eq. 4, ``|J| S_local``) | ``exact`` (``J diag(S^2) J^T``) |
      ``cartesian``: the head predicts Cartesian std-devs in metres directly, no Jacobian
      push-forward (Appendix "Derivation and Validity of Scale Transformation", Table
      "scale_ablation", row "Ours (Cartesian Scale)").
    * ``image_query`` - ``coarse`` (planes resampled to ``image_grid`` for the Eq. 2 queries, the
      update upsampled back) | ``full`` (Eq. 2 as printed: every cell of the plane at ``grid``
      resolution queries ``N'_c`` samples along the orthogonal axis).
    """

    coordinates: CoordinateKind = "cylindrical"
    radius: float = 10.0  # R_0 (m)
    height: float = 10.0  # Z_0 (m)
    grid: tuple[int, int, int] = (16, 128, 64)  # (N_r, N_theta, N_z): planes, cross-plane attn, decoding
    image_grid: tuple[int, int, int] = (8, 64, 32)  # (N'_r, N'_theta, N'_z): triplane-to-image attention
    channels: int = 128  # triplane feature channels
    heads: int = 4
    layers: int = 2  # rounds of (cross-plane attention, triplane-to-image attention)
    mlp_ratio: float = 2.0
    init: Literal["shared", "isolated"] = "shared"  # static scenes: shared; dynamic: isolated
    decoder_hidden: int = 128
    color_hidden: int = 64
    scale_transform: Literal["paper", "exact", "cartesian"] = "paper"  # Eq. 4 (|J| S), J diag(S^2) J^T, or metric S
    max_scale_cells: float = 1.0  # S_local <= this many cells along each axis
    min_scale_cells: float = 0.02
    # colour rule of the volume Gaussians (model/rgb_retrieval.py, COLOR_RULES): Eq. 6 retrieval (the paper), the
    # nearest observed surface, the released code's tap MLP, or decoded from the triplane
    color: Literal["retrieval", "surface", "released_mlp", "decoded"] = "retrieval"
    visibility_temperature: float = 1.0  # retrieval: w = softmax(-s / T); T = 1 m is the paper's Eq. 6
    surface_window: int = 4  # surface: (2r+1)^2 taps per view around the projection
    surface_temperature: float = 0.1  # surface: T in metres (sharp: the nearest observed points win)
    learn_temperature: bool = False  # surface: T is a trained parameter (initialised at surface_temperature)
    color_views: int = 3  # released_mlp: the most input views its MLP takes (fewer are zero-padded)
    placement: Literal["per_camera", "central"] = "per_camera"  # one triplane per camera, or one at the centre
    image_query: Literal["coarse", "full"] = "coarse"  # Eq. 2 queries at image_grid (coarse) or at grid (full)
    # Eq. 2 reads its own camera's F_pano (the paper) or every view's (the released code); per-camera triplanes only
    image_views: Literal["own", "all"] = "own"
    gaussians_per_cell: int = 1  # Gaussians decoded per triplane cell (the released configs: 3)


@dataclass
class FusionConfig:
    strategy: Literal["concat", "depth_prune"] = "concat"
    sigma: float = 0.1  # relative depth deviation giving opacity factor exp(-1/2)
    prune_threshold: float = 0.005  # opacities below this after attenuation are marked pruned
    # "front": only Gaussians in front of their own view's surface; "hidden": in front of any view's
    side: Literal["both", "front", "hidden"] = "both"
    # "seen_through": pixel Gaussians in front of another input view's refined surface (space that view saw
    # empty: flying pixels strung across depth edges) fade by the same rule, so the volume Gaussians behind show
    pixel_clearing: Literal["none", "seen_through", "at_depth_edges"] = "none"
    # "at_depth_edges" (issue 34): the same rule, weighted by how much the pixel sits on a depth edge of its own view
    # (1 - exp(-g^2 / (2 s^2)), g the largest |log depth| step to a neighbour, s = clearing_edge_step): flying
    # pixels only exist there, and on smooth depth (a constant or badly scaled prior) the views' disagreement is
    # the prior's error, which clearing would turn into holes in both views
    clearing_edge_step: float = 0.05
    # > 0 (with side="hidden"; issue 34): volume Gaussians also fade just *behind* every view's refined surface, by
    # 1 - exp(-e^2 / (2 clearance^2)) for a relative depth e behind it: inside a seen surface they can only leak
    # through the pixel Gaussians' partial coverage; far behind it (hidden space) they stay. 0 = off (the paper)
    surface_clearance: float = 0.0
    # "covisible" (issue 34, session 17): a pixel Gaussian's footprint (its scales, whatever pixel.footprint) divided
    # by sqrt(c), c the number of input views that see its point (each view's agreement with its refined depth,
    # exp(-e^2 / (2 sigma^2)), summed; its own view counts 1): where c views' splats tile one surface, each needs
    # 1/sqrt(c) of the area for the same coverage, so pixel.footprint_px is the footprint of a surface one view sees.
    # "per_view": footprint_px everywhere (the splat density of one view is not the surface's)
    pixel_footprint: Literal["per_view", "covisible"] = "per_view"


@dataclass
class ModelConfig:
    name: str = "custom"
    image_height: int = 512  # nominal input size (the model itself accepts any H x 2H)
    image_width: int = 1024
    mode: BranchMode = "both"
    # "photometric": each input's depth prior is rescaled to the poses' metric scale by a cross-view colour search
    # before both branches read it (model/prior_alignment.py; our addition, issue 23); "none": used as given
    prior_alignment: Literal["none", "photometric"] = "none"
    backbone: BackboneConfig = field(default_factory=BackboneConfig)
    attention: AttentionConfig = field(default_factory=AttentionConfig)
    pixel: PixelBranchConfig = field(default_factory=PixelBranchConfig)
    volume: VolumeBranchConfig = field(default_factory=VolumeBranchConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)
    # Screen-space dilation (px^2) added to every 2-D covariance when this model's Gaussians are drawn in training,
    # evaluation and rendering; 0.3 is 3DGS's low-pass (the paper). Issue 34: it blurs pixel-sized splats below the
    # sharpness of a forward warp (docs/model.md, "Sharp pixel Gaussians"). Viewers of an exported PLY use their own.
    render_dilation: float = 0.3
    # "one_pass" (the paper): all Gaussians drawn in one depth-sorted pass. "pixel_over_volume" (issue 34): the pixel
    # Gaussians (seen surfaces) drawn as a layer over the volume Gaussians, opaque where they cover a pixel
    # (cylindersplat.render.layered): the volume fills what they leave uncovered instead of showing through their
    # partial coverage. Used by eval, render and the demo; training and exported splat files draw one pass
    render_layering: Literal["one_pass", "pixel_over_volume"] = "one_pass"
    # How the pixel Gaussians combine among themselves where eval, render and the demo draw them. "over" (3DGS, the
    # paper): the front-most splat wins. "surface" (issue 34): surface splatting, the normalised weights of every
    # pixel Gaussian on the front surface (cylindersplat.render.layered.blend_front_surface), which averages the
    # views that see a surface and shows no lattice of splat discs where the target magnifies it. The pixel
    # Gaussians are then drawn as a layer of their own over the volume's (with the over operator unless
    # render_layering makes it opaque). Training and exported splat files draw one pass
    render_pixel_blending: Literal["over", "surface"] = "over"

    def validate(self) -> "ModelConfig":
        """Raise ``ValueError`` naming the first inconsistent field; return ``self``."""
        bb, att, vol = self.backbone, self.attention, self.volume
        checks = [
            (len(bb.widths) == len(bb.blocks) and len(bb.widths) >= 1,
             "backbone.widths and backbone.blocks need equal, non-zero lengths"),
            (len(self.pixel.decoder_widths) == len(bb.widths) + 1,
             f"pixel.decoder_widths needs {len(bb.widths) + 1} entries (one per 2x upsampling step)"),
            (att.dim % att.heads == 0, f"attention.dim {att.dim} must be divisible by attention.heads {att.heads}"),
            (vol.channels % vol.heads == 0,
             f"volume.channels {vol.channels} must be divisible by volume.heads {vol.heads}"),
            (len(vol.grid) == 3 and min(vol.grid) >= 1, f"volume.grid must be 3 positive sizes, got {vol.grid}"),
            (len(vol.image_grid) == 3 and min(vol.image_grid) >= 1,
             f"volume.image_grid must be 3 positive sizes, got {vol.image_grid}"),
            (vol.placement != "central" or vol.init == "shared",
             ("volume.placement='central' needs volume.init='shared' (the single central triplane has no view "
              "of its own to be isolated to)")),
            (0 < vol.min_scale_cells < vol.max_scale_cells, "need 0 < volume.min_scale_cells < volume.max_scale_cells"),
            (vol.surface_window <= 8,
             f"volume.surface_window must be an integer 1..8 (pixels), got {vol.surface_window!r}"),
            (vol.surface_temperature > 0 and vol.visibility_temperature > 0, "volume temperatures must be > 0"),
            (self.pixel.footprint_px > 0, f"pixel.footprint_px must be > 0 (pixels), got {self.pixel.footprint_px!r}"),
            (self.render_dilation >= 0, f"render_dilation must be >= 0 px^2, got {self.render_dilation!r}"),
            (self.fusion.surface_clearance >= 0,
             f"fusion.surface_clearance must be >= 0 (relative depth), got {self.fusion.surface_clearance!r}"),
        ]
        for ok, message in self._choice_checks() + checks + self._size_checks():
            if not ok:
                raise ValueError(f"invalid model config: {message}")
        return self

    def _choice_checks(self) -> list[tuple[bool, str]]:
        """Every string choice of the model among its :data:`CHOICES` (the table's ``train.``/``loss.`` keys are the
        experiment config's)."""
        checks = []
        fields = {f.name for f in dataclasses.fields(self)}
        for key, allowed in CHOICES.items():
            if key.split(".")[0] not in fields:
                continue
            value = get_dotted(self, key)
            checks.append((value in allowed, f"{key} must be one of {', '.join(allowed)}; got {value!r}"))
        return checks

    def _size_checks(self) -> list[tuple[bool, str]]:
        """Every layer size (the integers of the sections: widths, dims, heads, grids, ...) >= 1 and every
        number finite: a negative or zero size would fail deep inside a layer instead."""
        checks = []
        for section in ("backbone", "attention", "pixel", "volume", "fusion"):
            part = getattr(self, section)
            for f in dataclasses.fields(part):
                value = getattr(part, f.name)
                values = value if isinstance(value, tuple) else (value,)
                numbers = [v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool)]
                if any(not math.isfinite(v) for v in numbers):
                    checks.append((False, f"{section}.{f.name} must be finite, got {value!r}"))
                ints = [v for v in numbers if isinstance(v, int)]
                if ints and min(ints) < 1:
                    checks.append((False, f"{section}.{f.name} must be >= 1, got {value!r}"))
        return checks

    def replace(self, **changes: Any) -> "ModelConfig":
        """Copy with top-level fields or dotted sub-fields replaced: ``replace(**{"volume.init": "isolated"})``."""
        cfg = config_from_dict(config_to_dict(self))
        for key, value in changes.items():
            set_dotted(cfg, key, value)
        return cfg


def paper_config() -> ModelConfig:
    return ModelConfig(name="paper")


def tiny_paper_config() -> ModelConfig:
    return ModelConfig(
        name="tiny_paper",
        image_height=64,
        image_width=128,
        backbone=BackboneConfig(stem_width=16, widths=(16, 32, 48), blocks=(1, 1, 1), groups=4),
        attention=AttentionConfig(dim=48, depth=6, heads=4, mlp_ratio=2.0, ray_frequencies=2),
        pixel=PixelBranchConfig(decoder_widths=(32, 16, 16, 16), feature_dim=16, head_hidden=16),
        volume=VolumeBranchConfig(
            grid=(4, 16, 8), image_grid=(2, 8, 4), channels=16, heads=2, layers=1, decoder_hidden=32, color_hidden=16
        ),
    )


def paper_spherical_config() -> ModelConfig:
    cfg = paper_config().replace(**{"volume.coordinates": "spherical"})
    cfg.name = "paper_spherical"
    return cfg


def paper_cartesian_config() -> ModelConfig:
    cfg = paper_config().replace(
        **{"volume.coordinates": "cartesian", "volume.grid": (64, 32, 64), "volume.image_grid": (32, 16, 32)}
    )
    cfg.name = "paper_cartesian"
    return cfg


PRESETS = {
    "paper": paper_config,
    "tiny_paper": tiny_paper_config,
    "paper_spherical": paper_spherical_config,
    "paper_cartesian": paper_cartesian_config,
}
# earlier preset name -> its preset now (get_config takes it with a FutureWarning saying so)
RENAMED_PRESETS = {"tiny": "tiny_paper"}


def get_config(name: str = "paper", **changes: Any) -> ModelConfig:
    """A named preset, optionally with fields replaced (see :meth:`ModelConfig.replace`)."""
    if name in RENAMED_PRESETS:
        new = RENAMED_PRESETS[name]
        warnings.warn(f"model preset {name!r} is now {new!r} (the paper's model at tiny sizes, what the tests build); "
                      f"the name {name!r} will go: it also names the model of the {name!r} training preset "
                      f"(configs/{name}.yaml, load_config({name!r}).model), which the shipped tiny-synth weights use",
                      FutureWarning, stacklevel=_caller_level())
        name = new
    if name not in PRESETS:
        raise ValueError(f"unknown model preset {name!r}; available: {sorted(PRESETS)}")
    cfg = PRESETS[name]()
    return (cfg.replace(**changes) if changes else cfg).validate()


def _caller_level() -> int:
    """The ``stacklevel`` of the first caller outside this package, for a warning raised by the function that calls
    this one (so it points at the user's line, not at ``from_config``)."""
    package = str(Path(__file__).resolve().parents[1])
    frame, level = sys._getframe(1), 1
    while frame.f_back is not None and frame.f_code.co_filename.startswith(package):
        frame, level = frame.f_back, level + 1
    return level


def config_to_dict(cfg: ModelConfig) -> dict[str, Any]:
    return dataclasses.asdict(cfg)


def config_from_dict(data: dict[str, Any]) -> ModelConfig:
    """Inverse of :func:`config_to_dict` (lists from JSON become tuples)."""
    sub = {
        "backbone": BackboneConfig,
        "attention": AttentionConfig,
        "pixel": PixelBranchConfig,
        "volume": VolumeBranchConfig,
        "fusion": FusionConfig,
    }
    if not isinstance(data, dict):
        raise TypeError(f"a model config is a mapping, got {type(data).__name__}")
    data = _upgrade(data)
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        if key in sub:
            if not isinstance(value, dict):
                raise TypeError(f"{key} must be a mapping, got {value!r:.60}")
            value = sub[key](**{k: tuple(v) if isinstance(v, list) else v for k, v in value.items()})
            _check_types(value, f"{key}.")
        kwargs[key] = value
    config = ModelConfig(**kwargs)
    _check_types(config, "")
    return config


def _upgrade(data: dict[str, Any]) -> dict[str, Any]:
    """Configs stored by earlier versions: ``volume.retrieval_window = r > 0`` was the nearest-surface rule (now
    ``volume.color = "surface"`` with ``surface_window = r`` and its temperature), ``0`` Eq. 6."""
    volume = data.get("volume")
    if not isinstance(volume, dict) or "retrieval_window" not in volume:
        return data
    volume = dict(volume)
    window = volume.pop("retrieval_window")
    if isinstance(window, int) and window > 0 and volume.get("color", "retrieval") == "retrieval":
        temperature = volume.get("visibility_temperature", 1.0)
        volume.update(color="surface", surface_window=window, surface_temperature=temperature)
    return dict(data, volume=volume)


def _check_types(section: Any, prefix: str) -> None:
    """Each field of the kind its default has (a stored ``image_height: "abc"`` fails here, by name, not deep
    inside a layer); ints are accepted for floats, booleans only for booleans."""
    def same_kind(value: Any, default: Any) -> bool:
        if isinstance(value, bool) != isinstance(default, bool):
            return False
        return isinstance(value, (int, float) if isinstance(default, float) else type(default))

    for f in dataclasses.fields(section):
        value, default = getattr(section, f.name), f.default
        if default is dataclasses.MISSING or default is None or dataclasses.is_dataclass(value):
            continue
        if isinstance(default, tuple):
            ok = isinstance(value, tuple) and all(same_kind(v, default[0]) for v in value) if default else True
        else:
            ok = same_kind(value, default)
        if not ok:
            raise TypeError(f"{prefix}{f.name} must be like {default!r}, got {value!r:.60}")
