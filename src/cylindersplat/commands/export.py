"""``cylindersplat export``: posed panoramas -> Gaussians as a 3DGS PLY, .splat, .spz, .compressed.ply or .sog."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..utils.atomic import new_folders, output_set
from ._arguments import check_output
from ._inference import add_input_arguments, reconstruct_from_args


def run(args: argparse.Namespace) -> int:
    from ..gaussians.formats import WRITE_FORMATS, require_splat_transform, save_gaussians, splat_format

    fmt = splat_format(args.out)  # before the (slow) reconstruction: a bad name or a missing tool fails at once
    if fmt not in (".ply", ".splat"):
        require_splat_transform(f"writing {fmt}")
    check_output(args.out, folder=False)
    _, gaussians, _ = reconstruct_from_args(args)
    # a failure names what was not written, keeps an earlier file and leaves no folder it made
    with new_folders(args.out.parent), output_set(args.out.parent):
        path = save_gaussians(gaussians.to("cpu"), args.out, spz_version=args.spz_version)
    print(f"wrote {path} ({WRITE_FORMATS[fmt]}; {path.stat().st_size / 1e6:.1f} MB)")
    return 0


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "export", help="reconstruct posed panoramas into Gaussians and save them (3DGS PLY, .splat, "
                       ".spz, .compressed.ply, .sog)",
        description="Run a trained model on a folder of posed equirect panoramas and write the Gaussians as a "
        "standard 3DGS PLY (world frame of the poses; opens in SuperSplat and other 3DGS viewers) or a compressed "
        "splat format (.spz, .compressed.ply, .sog: through PlayCanvas splat-transform). "
        "Input format: docs/inference.md.",
    )
    add_input_arguments(parser)
    parser.add_argument("--out", type=Path, default=Path("outputs/export/gaussians.ply"),
                        help="output, format by name: .ply (standard 3DGS PLY, all SH), .splat (32 bytes per Gaussian, "
                        "degree-0 colour), .spz (Niantic), .compressed.ply (PlayCanvas/SuperSplat) or .sog "
                        "(PlayCanvas); the last three need splat-transform (npm install -g "
                        "@playcanvas/splat-transform) (default outputs/export/gaussians.ply)")
    parser.add_argument("--spz-version", type=int, choices=(3, 4),
                        help="SPZ version for .spz (default 4, splat-transform's; 3 is the older gzip container)")
    parser.set_defaults(func=run)
