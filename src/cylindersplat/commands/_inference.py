"""Options and steps shared by ``render`` and ``export``: model + a folder of posed panoramas -> Gaussians."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ._arguments import device, model_resolution, opacity_threshold


def add_input_arguments(parser: argparse.ArgumentParser, required: bool = True) -> None:
    parser.add_argument("--input", required=required, type=Path,
                        help="folder of equirect panoramas + poses.json (OpenCV c2w; see docs/inference.md)")
    parser.add_argument("--checkpoint", help="model .safetensors (from cylindersplat train / demo), a run folder (or "
                        "its checkpoints/latest), or a shipped model name (default: the shipped tiny-synth weights, "
                        "trained on procedural scenes)")
    parser.add_argument("--poses-file", type=Path, help="poses file (default INPUT/poses.json)")
    parser.add_argument("--allow-outside-paths", action="store_true",
                        help="read image/depth files the poses file names outside the input folder (absolute or ../ "
                        "paths, symlinks leading out); refused by default")
    parser.add_argument("--resolution", type=model_resolution,
                        help="HxW the model runs at (default: the model's nominal input height x 2)")
    parser.add_argument("--depth-prior",
                        help="for frames without a depth file: file:NAME (INPUT/priors/NAME/<stem>.png from "
                             "`cylindersplat data priors`), exported:NET.pt2 (any exported depth network), "
                             "unik3d:WEIGHTS, depth_anything_v2:MODEL, constant:METRES, none (zeros, on request only) "
                             "(default: every frame needs <stem>_depth.png/.npy)")
    parser.add_argument("--prior-scale", choices=["model", "photometric", "none"], default="model",
                        help="rescale each view's depth to the poses' metric scale by a cross-view colour search "
                             "before the model reads it (photometric: for relative or scale-off depth networks; needs "
                             "2+ views some distance apart), use it as given (none), or do what the model was trained "
                             "with (model, the default)")
    parser.add_argument("--min-opacity", type=opacity_threshold, default=0.005,
                        help="drop Gaussians at or below this opacity, in [0, 1) (default 0.005)")
    parser.add_argument("--skip-plausibility-checks", action="store_true",
                        help="accept depths whose median is outside 1 cm to 1 km (refused by default as a unit "
                        "mistake) and silence the scene-scale warnings (median depth beyond 100 m or below 5 cm, "
                        "camera spacing out of proportion with the depth)")
    parser.add_argument("--device", type=device, default="auto",
                        help="auto (CUDA when available), cpu, cuda[:N] (default auto)")


def model_size(config, given: tuple[int, int] | None, option: str = "--resolution") -> tuple[int, int]:
    """``given`` (HxW from ``option``), else the model's own resolution (``config.image_height`` x 2), said in one
    line: a dataset stored at 512x1024 run through a model made for 64x128 would need 64x the memory and time."""
    if given:
        return tuple(given)
    size = (config.image_height, 2 * config.image_height)
    print(f"running the model at {size[0]}x{size[1]}, its own resolution ({option} HxW to choose another)")
    return size


# a view whose depth the colour search finds this far off the poses' scale (either way) is warned about by default
SCALE_WARNING_FACTOR = 1.15


def _prior_scales(inputs):
    """(V,) factors that bring each view's depth to the poses' metric scale (photometric search; 1 where unsure)."""
    from ..model.prior_alignment import photometric_prior_scales

    return photometric_prior_scales(inputs.images[None], inputs.depths[None], inputs.c2w[None])[0]


def _warn_if_scale_off(inputs, folder: Path) -> None:
    """The default run does not rescale the depth, but a depth network's output a factor 2 off the poses' scale
    would give a garbled scene without a word: search anyway (well under a second at the model's size) and warn."""
    import math
    import warnings

    from ..validation import ScaleWarning

    scales = _prior_scales(inputs)
    off = [f"{name} x{float(s):.2f}" for name, s in zip(inputs.names, scales)
           if abs(math.log(float(s))) > math.log(SCALE_WARNING_FACTOR)]
    if off:
        warnings.warn(f"{folder}: the depth looks off the poses' scale, a cross-view colour search finds "
                      f"{', '.join(off)}; pass --prior-scale photometric to rescale it, or "
                      "--prior-scale none to use the depth as given without this check", ScaleWarning, stacklevel=2)


def _say_resized(folder: Path, names: list[str], size: tuple[int, int]) -> None:
    """One line when the panoramas are stored at another size than the model runs at (they are resized, and the
    views and fly-through are written at the model's size unless --output-resolution says otherwise)."""
    from PIL import Image

    try:
        with Image.open(folder / names[0]) as image:
            stored = (image.height, image.width)
    except (OSError, ValueError, IndexError):
        return
    if stored != tuple(size):
        print(f"the panoramas ({stored[0]}x{stored[1]}) are resized to {size[0]}x{size[1]} for the model")


def reconstruct_from_args(args: argparse.Namespace, layers: bool = False):
    """-> (inputs, gaussians, model) for the parsed options, with ``front`` (the model's front layer, see
    :func:`~cylindersplat.inference.pipeline.reconstruct_gaussians`) last when ``layers``; prints what it did."""
    from ..data.depth_prior import parse_depth_prior
    from ..inference import load_panorama_folder, reconstruct_gaussians
    from ..model.pretrained import DEFAULT_PRETRAINED, from_pretrained

    if args.checkpoint is None:
        print(f"using the shipped {DEFAULT_PRETRAINED} weights (trained on procedural scenes; "
              "--checkpoint for your own)")
    # refuses missing files, pickles, broken or diverged weights by name
    model = from_pretrained(args.checkpoint or DEFAULT_PRETRAINED, map_location=args.device)
    size = model_size(model.config, args.resolution)
    stride = model.config.backbone.token_stride
    if size[0] % stride:
        low = max(stride, size[0] // stride * stride)
        raise ValueError(f"--resolution {size[0]}x{size[1]}: this model needs a height divisible by {stride}, "
                         f"e.g. {low}x{2 * low} or {low + stride}x{2 * (low + stride)}")
    prior = parse_depth_prior(args.depth_prior) if args.depth_prior else None
    inputs = load_panorama_folder(args.input, size, depth_prior=prior, poses_file=args.poses_file,
                                  allow_outside_paths=args.allow_outside_paths,
                                  check_plausibility=not args.skip_plausibility_checks)
    _say_resized(args.input, inputs.names, size)
    alignment = model.config.prior_alignment if args.prior_scale == "model" else args.prior_scale
    if alignment == "photometric" and len(inputs.names) == 1:  # the search compares views: one has nothing to match
        print("depth used as given: the photometric depth-scale search needs 2 or more panoramas, this is 1")
    elif alignment == "photometric":
        # searched once, here, so the factors can be printed; the model then takes the rescaled depth as it is
        scales = _prior_scales(inputs)
        inputs.depths = inputs.depths * scales[:, None, None]
        print("depth rescaled to the poses' scale (photometric search): "
              + ", ".join(f"{name} x{float(s):.3f}" for name, s in zip(inputs.names, scales)))
    elif args.prior_scale == "model" and not args.skip_plausibility_checks and len(inputs.names) > 1:
        _warn_if_scale_off(inputs, args.input)
    model.config.prior_alignment = "none"
    blending = getattr(args, "pixel_blending", "model")  # render's --pixel-blending
    if blending != "model" and blending != model.config.render_pixel_blending:
        print(f"pixel Gaussians drawn with --pixel-blending {blending} (this model's own: "
              f"{model.config.render_pixel_blending})")
        model.config.render_pixel_blending = blending
    start = time.perf_counter()
    # the folder's depths were checked just above, by file name: no second, nameless round of the same checks
    gaussians, front = reconstruct_gaussians(model, inputs.images, inputs.depths, inputs.c2w, args.device,
                                             args.min_opacity, check_plausibility=False, layers=True)
    views = f"{len(inputs.names)} panorama{'s' if len(inputs.names) != 1 else ''}"
    print(f"reconstructed {len(gaussians):,} Gaussians from {views} at "
          f"{size[0]}x{size[1]} in {time.perf_counter() - start:.2f} s on {args.device}")
    return (inputs, gaussians, model, front) if layers else (inputs, gaussians, model)
