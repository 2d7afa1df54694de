"""``cylindersplat export``: posed panoramas -> Gaussians as a standard 3DGS PLY."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._inference import add_input_arguments, reconstruct_from_args


def run(args: argparse.Namespace) -> int:
    from ..gaussians import save_ply, save_splat

    suffix = args.out.suffix.lower()
    if suffix not in (".ply", ".splat"):
        raise ValueError(f"--out must end in .ply (standard 3DGS PLY) or .splat (compact web-viewer format), got {args.out}")
    _, gaussians, _ = reconstruct_from_args(args)
    path = (save_splat if suffix == ".splat" else save_ply)(gaussians.to("cpu"), args.out)
    print(f"wrote {path} ({path.stat().st_size / 1e6:.1f} MB)")
    return 0


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "export", help="reconstruct posed panoramas into Gaussians and save them as a 3DGS PLY",
        description="Run a trained model on a folder of posed equirect panoramas and write the Gaussians as a "
        "standard 3DGS PLY (world frame of the poses; opens in SuperSplat and other 3DGS viewers). "
        "Input format: docs/inference.md.",
    )
    add_input_arguments(parser)
    parser.add_argument("--out", type=Path, default=Path("outputs/export/gaussians.ply"), help="output: .ply (standard 3DGS PLY, all SH) or .splat (32 bytes per Gaussian, "
                        "degree-0 colour; web viewers) (default outputs/export/gaussians.ply)")
    parser.set_defaults(func=run)
