"""``cylindersplat data``: generate synthetic panoramas, preview and inspect datasets."""

from __future__ import annotations

import argparse
import time

from ._arguments import equirect_resolution


def _spacing(text: str) -> tuple[float, float]:
    try:
        parts = [float(x) for x in text.split(":")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"spacing must be METRES or MIN:MAX, got {text!r}") from None
    if len(parts) not in (1, 2) or min(parts) <= 0 or parts[0] > parts[-1]:
        raise argparse.ArgumentTypeError(f"spacing must be METRES or MIN:MAX with 0 < MIN <= MAX, got {text!r}")
    return parts[0], parts[-1]


def _synth(args) -> int:
    from ..data.synth import LAYOUTS, SequenceConfig, write_synthetic_dataset

    layouts = tuple(args.layouts.split(",")) if args.layouts else LAYOUTS
    cfg = SequenceConfig(frames=args.frames, spacing=args.spacing, layouts=layouts,
                         outdoor_fraction=args.outdoor_fraction, random_yaw=not args.no_yaw)
    start = time.perf_counter()
    out = write_synthetic_dataset(args.out, args.scenes, args.resolution, cfg, seed=args.seed)
    seconds = time.perf_counter() - start
    print(f"wrote {args.scenes} scenes x {args.frames} frames to {out} in {seconds:.1f} s")
    return 0


def _preview(args) -> int:
    from ..data.preview import write_contact_sheet

    out = write_contact_sheet(args.data, args.out, count=args.count, height=args.height)
    print(f"wrote {out}")
    return 0


def _info(args) -> int:
    from ..data.preview import open_dataset

    ds = open_dataset(args.data)
    print(f"{type(ds).__name__}: {len(ds)} examples, stored size {ds.stored_size} (HxW)")
    for index in range(min(args.count, len(ds))):
        ref = ds.example(index)
        centres = [f.c2w[:3, 3].tolist() for f in ref.frames]
        extra = ", ".join(f"{k}={v}" for k, v in ref.metadata.items())
        print(f"  {ref.scene}: {len(ref.frames)} frames, context {list(ref.views.context)} -> "
              f"target {list(ref.views.target)}, {extra}, first centre {[round(c, 3) for c in centres[0]]}")
    return 0


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
    synth.add_argument("--scenes", type=int, default=10, help="number of scenes (default 10)")
    synth.add_argument("--resolution", type=equirect_resolution, default=(256, 512), help="HxW with W = 2H (default 256x512)")
    synth.add_argument("--frames", type=int, default=3, help="frames per sequence, on a line (default 3)")
    synth.add_argument("--spacing", type=_spacing, default=(0.5, 0.5),
                       help="metres between consecutive frames, or MIN:MAX drawn per scene (default 0.5)")
    synth.add_argument("--seed", type=int, default=0, help="dataset seed; scene i is fully determined by (seed, i)")
    synth.add_argument("--layouts", default="", help="comma list of room,l_shape,two_rooms,outdoor (default all)")
    synth.add_argument("--outdoor-fraction", type=float, default=0.2, help="share of outdoor scenes (default 0.2)")
    synth.add_argument("--no-yaw", action="store_true", help="identity camera rotations (PanoGRF-like) instead of a random yaw")
    synth.set_defaults(func=_synth)

    preview = sub.add_parser(
        "preview", help="contact sheet PNG: RGB and colourised depth of a few examples",
        description="Write a contact sheet of the first examples of a synthetic or png_render_* dataset.",
    )
    preview.add_argument("--data", required=True, help="dataset folder (synthetic output or png_render_* folder)")
    preview.add_argument("--out", required=True, help="output PNG path")
    preview.add_argument("--count", type=int, default=4, help="number of examples (rows, default 4)")
    preview.add_argument("--height", type=int, default=128, help="tile height in pixels (width = 2x, default 128)")
    preview.set_defaults(func=_preview)

    info = sub.add_parser("info", help="summarise a dataset folder", description="Print examples, views and poses.")
    info.add_argument("--data", required=True, help="dataset folder")
    info.add_argument("--count", type=int, default=5, help="examples to list (default 5)")
    info.set_defaults(func=_info)
