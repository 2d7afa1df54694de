"""``cylindersplat data``: generate synthetic panoramas, preview and inspect datasets, precompute depth priors."""

from __future__ import annotations

import argparse
import time

from ..dataset_layouts import DATASET_SPECS, LAYOUT_ALIASES
from ._arguments import device, equirect_resolution, fraction, nonnegative_int, positive_int

PROFILE_NAMES = ("default", "occlusion")  # cylindersplat.data.synth.PROFILES (not imported: keeps the CLI start fast)
PROTOCOL_NAMES = ("two_view", "one_view", "n_view", "released")  # cylindersplat.data.views.PROTOCOLS
OUTSIDE_HELP = ("folders of posed panoramas: read image/depth files their poses files name outside their folder "
                "(absolute or ../ paths); refused by default")


def _spacing(text: str) -> tuple[float, float]:
    try:
        parts = [float(x) for x in text.split(":")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"spacing must be METRES or MIN:MAX, got {text!r}") from None
    if len(parts) not in (1, 2) or min(parts) <= 0 or parts[0] > parts[-1]:
        raise argparse.ArgumentTypeError(f"spacing must be METRES or MIN:MAX with 0 < MIN <= MAX, got {text!r}")
    return parts[0], parts[-1]


def _offset(text: str) -> tuple[float, float]:
    try:
        parts = [float(x) for x in text.split(":")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"target offset must be METRES or MIN:MAX, got {text!r}") from None
    if len(parts) not in (1, 2) or min(parts) < 0 or parts[0] > parts[-1]:
        raise argparse.ArgumentTypeError(f"target offset must be METRES or MIN:MAX with 0 <= MIN <= MAX, got {text!r}")
    return parts[0], parts[-1]


def _layouts(text: str) -> tuple[tuple[str, ...], tuple[float, ...]] | None:
    """``room,l_shape`` or with weights ``room:1,two_rooms:3,outdoor`` (a missing weight is 1)."""
    from ..data.synth import LAYOUTS

    names, weights, weighted = [], [], False
    for item in filter(None, (x.strip() for x in text.split(","))):
        name, _, weight = item.partition(":")
        if name not in LAYOUTS:
            raise argparse.ArgumentTypeError(f"unknown layout {name!r}; choose from {','.join(LAYOUTS)}")
        try:
            value = float(weight) if weight else 1.0
        except ValueError:
            raise argparse.ArgumentTypeError(f"layout weight must be a number, got {item!r}") from None
        if value < 0:
            raise argparse.ArgumentTypeError(f"layout weight must be >= 0, got {item!r}")
        weighted |= bool(weight)
        names.append(name)
        weights.append(value)
    if not names:  # "" = every layout, as before
        return None
    return tuple(names), (tuple(weights) if weighted else ())


def _synth(args) -> int:
    from ..data.synth import profile_config, write_synthetic_dataset

    layouts, weights = args.layouts if args.layouts else (None, None)
    cfg = profile_config(
        args.profile, frames=args.frames, spacing=args.spacing, layouts=layouts, layout_weights=weights or None,
        outdoor_fraction=args.outdoor_fraction, random_yaw=False if args.no_yaw else None,
        target_offset=args.target_offset, occluders=args.occluders, through_doorways=args.through_doorways,
    )
    start = time.perf_counter()
    out = write_synthetic_dataset(args.out, args.scenes, args.resolution, cfg, seed=args.seed)
    seconds = time.perf_counter() - start
    scenes, frames = ("scene" if args.scenes == 1 else "scenes"), ("frame" if cfg.frames == 1 else "frames")
    print(f"wrote {args.scenes} {scenes} x {cfg.frames} {frames} ({args.profile} profile) to {out} in {seconds:.1f} s")
    return 0


def _preview(args) -> int:
    from ..data.preview import write_contact_sheet

    out = write_contact_sheet(args.data, args.out, count=args.count, height=args.height,
                              allow_outside_paths=args.allow_outside_paths)
    print(f"wrote {out}")
    return 0


def _percent(share: float) -> str:
    return f"{100 * share:.2f} %"


def _info(args) -> int:
    from ..data.preview import default_views, example_occlusion, occlusion_summary, open_dataset

    targets = [name for name in args.targets.split(",") if name] if args.targets else None
    chosen = args.views or default_views(args.data, "info")  # the layout's own unless --views (360Loc: all_between)
    ds = open_dataset(args.data, views=chosen, targets=targets, allow_outside_paths=args.allow_outside_paths)
    size, which = ds.stored_size, ""
    if size is None and len(ds):  # a folder of panoramas fixes no size: show its first panorama's
        from PIL import Image

        with Image.open(ds.example(0).frames[0].rgb) as image:
            size, which = (image.height, image.width), ", first panorama"
    views = f"held_out ({', '.join(targets)})" if targets else chosen
    print(f"{type(ds).__name__}: {len(ds)} examples, stored size {size} (HxW{which}), views {views}")
    for index in range(min(args.count, len(ds))):
        ref = ds.example(index)
        centres = [f.c2w[:3, 3].tolist() for f in ref.frames]
        extra = ", ".join(f"{k}={v}" for k, v in ref.metadata.items())
        occ = example_occlusion(ds, index) if args.occlusion else None
        figures = ""
        if occ is not None:
            hidden = "/".join(_percent(s) for s in occ.occluded) if occ.occluded is not None else "n/a (no depth)"
            figures = f", baseline {occ.baseline:.3f} m, occluded {hidden}"
        print(f"  {ref.scene}: {len(ref.frames)} frames, context {list(ref.views.context)} -> "
              f"target {list(ref.views.target)}, {extra}, first centre {[round(c, 3) for c in centres[0]]}{figures}")
    summary = occlusion_summary(ds, args.occlusion) if args.occlusion else None
    if summary is not None:
        print(f"occluded share of the targets (pixels no context sees, GT depth, latitude-weighted) over "
              f"{summary['examples']} of {summary['of']} examples ({summary['targets']} targets): "
              f"mean {_percent(summary['mean'])}, median {_percent(summary['median'])}, "
              f"min {_percent(summary['min'])}, max {_percent(summary['max'])}; "
              f"{100 * summary['at_least_1pct']:.0f} % of examples >= 1 %; mean baseline {summary['baseline']:.3f} m")
    elif args.occlusion:
        print("occluded share: n/a (no ground-truth depth)")
    return 0


def _priors(args) -> int:
    from ..data.depth_prior.precompute import write_priors

    run = write_priors(args.data, args.net, name=args.name, out=args.out, layout=args.layout, split=args.split,
                       file_format=args.file_format, resolution=args.resolution, batch_size=args.batch_size,
                       device=args.device, overwrite=args.overwrite, net_size=args.net_size)
    print(f"depth priors {args.net} -> {run.tree}: {run.written} written, {run.skipped} already there "
          f"({run.frames} panoramas, {run.seconds:.1f} s on {args.device}); use them as "
          f"file:{args.name if args.out is None else run.tree}")
    return 0


def _dataset_layout(text: str) -> str:
    """--layout: ``auto`` or a layout name of the registry (an older alias becomes its name); an argparse type."""
    return text if text == "auto" else LAYOUT_ALIASES.get(text, text)


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "data", help="generate, preview and inspect panoramic datasets",
        description="Data tools: a procedural panorama generator and dataset previews. See docs/data.md.",
    )
    sub = parser.add_subparsers(dest="data_command", metavar="ACTION")
    parser.set_defaults(func=lambda args: (parser.print_help(), 2)[1])

    synth = sub.add_parser(
        "synth", help="render procedural indoor/outdoor panorama sequences (RGB + radial depth + poses)",
        description="Render seeded procedural scenes along straight camera lines. Output layout: "
        "DIR/<scene>/NN/{rgb.png,depth.png (16-bit mm)}, poses.json, meta.json. Re-running resumes.",
    )
    synth.add_argument("--out", required=True, help="output folder")
    synth.add_argument("--scenes", type=positive_int, default=10, help="number of scenes (default 10)")
    synth.add_argument("--resolution", type=equirect_resolution, default=(256, 512),
                       help="HxW with W = 2H (default 256x512)")
    synth.add_argument("--frames", type=positive_int, default=3, help="frames per sequence, on a line (default 3)")
    synth.add_argument("--spacing", type=_spacing, default=None,
                       help="metres between consecutive frames, or MIN:MAX drawn per scene (default 0.5; "
                            "occlusion profile 0.5:1.0)")
    synth.add_argument("--seed", type=int, default=0, help="dataset seed; scene i is fully determined by (seed, i)")
    synth.add_argument("--layouts", type=_layouts, default=None,
                       help="comma list of room,l_shape,two_rooms,outdoor (default all), optionally weighted: "
                       "room:1,two_rooms:3,outdoor (outdoor's share is --outdoor-fraction)")
    synth.add_argument("--outdoor-fraction", type=fraction, default=None,
                       help="share of outdoor scenes (default 0.2; occlusion profile 0.15)")
    synth.add_argument("--no-yaw", action="store_true",
                       help="identity camera rotations (PanoGRF-like) instead of a random yaw")
    disocclusion = synth.add_argument_group(
        "disocclusion", "targets that see what no context sees (all off by default; --profile occlusion sets them; "
        "an explicit flag overrides the profile)")
    disocclusion.add_argument("--profile", choices=sorted(PROFILE_NAMES), default="default",
                              help="named settings: 'default' (straight line) or 'occlusion' (target off the line, "
                              "occluders, doorways, 1-2 m baselines)")
    disocclusion.add_argument("--target-offset", type=_offset, default=None, metavar="METRES|MIN:MAX",
                              help="move the middle frame (the two_view target) this far off the line, mostly sideways "
                              "(occlusion profile 0.4:1.0)")
    disocclusion.add_argument("--occluders", type=nonnegative_int, default=None, metavar="N",
                              help="extra objects (pillars, cabinets, screens, ...) standing near the camera "
                                   "path (occlusion profile 6)")
    disocclusion.add_argument("--through-doorways", type=fraction, default=None, metavar="SHARE",
                              help="share of doorway scenes whose camera line walks through the "
                                   "doorway (occlusion profile 0.7)")
    synth.set_defaults(func=_synth)

    preview = sub.add_parser(
        "preview", help="contact sheet PNG: RGB and colourised depth of a few examples",
        description="Write a contact sheet of the first examples of a synthetic dataset, a png_render_* folder, a "
        "360Loc root or a folder of posed panoramas (poses.json or transforms.json, docs/inference.md; every frame in "
        "poses-file order, depth tiles black where a frame has no depth file).",
    )
    preview.add_argument("--data", required=True,
                         help="dataset folder (synthetic output, png_render_* folder, or a folder of posed "
                              "panoramas or of such folders)")
    preview.add_argument("--out", required=True, help="output PNG path")
    preview.add_argument("--count", type=positive_int, default=4, help="number of examples (rows, default 4)")
    preview.add_argument("--height", type=positive_int, default=128,
                         help="tile height in pixels (width = 2x, default 128)")
    preview.add_argument("--allow-outside-paths", action="store_true", help=OUTSIDE_HELP)
    preview.set_defaults(func=_preview)

    info = sub.add_parser(
        "info", help="summarise a dataset folder: examples, poses, baselines, occluded share of the targets",
        description="Print examples, views and poses, each example's context baseline and the share of each "
        "target's pixels that no context view sees (from ground-truth depth at the stored resolution), and "
        "their average over the dataset. Reads every layout of the dataset registry: synthetic datasets, png_render_* "
        "folders, 360Loc roots (no depth: n/a) and folders of posed panoramas (poses.json or transforms.json, "
        "docs/inference.md; frames without a depth file: n/a).")
    info.add_argument("--data", required=True,
                      help="dataset folder (synthetic output, png_render_* folder, 360Loc root, or a folder of posed "
                      "panoramas or of such folders)")
    info.add_argument("--count", type=nonnegative_int, default=5, help="examples to list (default 5)")
    info.add_argument("--views", default=None, choices=PROTOCOL_NAMES + ("all_between",),
                      help="view protocol (default two_view; a folder of panoramas: over its frames in poses-file "
                      "order; a 360Loc root: all_between, its only one)")
    info.add_argument("--targets", help="folder of panoramas: comma list of frames (image names or stems) held out as "
                      "targets, the other frames being the inputs (instead of --views), as in eval --targets")
    info.add_argument("--occlusion", type=nonnegative_int, default=64, metavar="N",
                      help="average the occluded share over N evenly spaced examples (default 64; 0: skip it)")
    info.add_argument("--allow-outside-paths", action="store_true", help=OUTSIDE_HELP)
    info.set_defaults(func=_info)

    from ._import_poses import register as register_import_poses

    register_import_poses(sub)

    from ._sfm_poses import register as register_sfm_poses

    register_sfm_poses(sub)

    priors = sub.add_parser(
        "priors", help="run a depth network once over a dataset and store its depth as prior files",
        description="Run a depth network over every panorama of a dataset (synthetic, PanoGRF png_render_* folder, "
        "360Loc root or an input folder with poses.json) and store radial depth per frame in DATA/priors/NAME/ "
        "(mirroring the panoramas' paths; 16-bit PNG millimetres or .npy metres) with prior.json (network, "
        "version/checksum, resolution, date). Use the files as file:NAME (data.depth_prior, loss.depth_reference, "
        "eval --depth-prior/--pcc-reference, render --depth-prior). Re-running skips frames already written by the "
        "same network. See docs/data.md, 'Depth priors'.")
    priors.add_argument("--data", required=True, help="dataset folder")
    priors.add_argument("--net", required=True, metavar="SPEC",
                        help="exported:NET.pt2|.pt (torch.export / TorchScript), unik3d:WEIGHTS_DIR_OR_HUB_ID, "
                        "depth_anything_v2:MODEL_DIR_OR_HUB_ID (needs transformers)")
    priors.add_argument("--name", help="prior name: files go to DATA/priors/NAME and are read as file:NAME")
    priors.add_argument("--out", help="write the tree here instead (e.g. for read-only data); read it as file:OUT")
    priors.add_argument("--file-format", "--format", dest="file_format", choices=["png", "npy"], default="png",
                        help="png: 16-bit millimetres, 0 = unknown, up to 65.5 m (default); npy: float32 metres "
                        "(--format is its older name)")
    priors.add_argument("--resolution", type=equirect_resolution,
                        help="HxW the network sees and the files have (default: each panorama's stored size)")
    priors.add_argument("--net-size", type=equirect_resolution,
                        help="exported networks: HxW the network runs at (for networks exported with fixed shapes; "
                        "its output is resized back)")
    priors.add_argument("--layout", type=_dataset_layout, choices=["auto", *DATASET_SPECS], default="auto",
                        help="dataset layout, as train and eval name it (default: detected; "
                             "'input' is folder's older name)")
    priors.add_argument("--split", default="all", help="360Loc: train, test or all locations (default all)")
    priors.add_argument("--batch-size", type=positive_int, default=4, help="panoramas per network call (default 4)")
    priors.add_argument("--device", type=device, default="auto",
                        help="auto (CUDA when available), cpu, cuda[:N] (default auto)")
    priors.add_argument("--overwrite", action="store_true", help="recompute every frame, replacing an existing tree")
    priors.set_defaults(func=_priors)
