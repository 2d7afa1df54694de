"""``cylindersplat demo``: render the built-in Gaussian room to panoramas, depth maps and a PLY.

Needs no download; it exercises the renderer, the depth colormap and the PLY writer end to end.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import torch


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo",
        help="render the built-in Gaussian room (no download needed)",
        description="Render the built-in demo room from a few camera positions: equirect RGB PNGs, "
        "depth colormaps, and the scene as a standard 3DGS PLY (opens in SuperSplat etc.).",
    )
    p.add_argument("--out", type=Path, default=Path("outputs/demo"), help="output folder (default: outputs/demo)")
    p.add_argument("--height", type=int, default=256, help="panorama height; width is 2x (default: 256)")
    p.add_argument("--views", type=int, default=3, help="number of camera positions along a line (default: 3)")
    p.add_argument("--density", type=float, default=12.0, help="Gaussians per metre of surface (default: 12)")
    p.add_argument("--device", default="cpu", help="torch device (default: cpu)")
    p.set_defaults(func=run)


def to_uint8(image: torch.Tensor) -> np.ndarray:
    """``(3, H, W)`` float in [0, 1] -> ``(H, W, 3)`` uint8."""
    return (image.detach().clamp(0, 1).permute(1, 2, 0).cpu().numpy() * 255 + 0.5).astype(np.uint8)


def run(args: argparse.Namespace) -> int:
    from ..gaussians import save_ply
    from ..geometry import make_c2w
    from ..render import render_equirect
    from ..scenes import demo_room
    from ..utils.colormap import colorize_depth

    if args.views < 1:
        raise ValueError("--views must be at least 1")
    args.out.mkdir(parents=True, exist_ok=True)
    gaussians = demo_room(args.density).to(args.device)
    xs = torch.linspace(-1.0, 1.0, args.views) if args.views > 1 else torch.zeros(1)
    poses = torch.stack([make_c2w(translation=torch.tensor([float(x), 0.0, 0.3 * float(x)])) for x in xs]).to(args.device)
    start = time.perf_counter()
    out = render_equirect(gaussians, poses, args.height, 2 * args.height, background=(1.0, 1.0, 1.0))
    elapsed = time.perf_counter() - start
    for i in range(args.views):
        iio.imwrite(args.out / f"rgb_{i:02d}.png", to_uint8(out.rgb[i]))
        # Radial expected depth is alpha-weighted; normalise it and blank out barely covered pixels.
        depth = out.depth[i] / out.alpha[i].clamp_min(1e-6)
        depth = torch.where(out.alpha[i] > 0.5, depth, torch.zeros_like(depth))
        iio.imwrite(args.out / f"depth_{i:02d}.png", colorize_depth(depth, as_uint8=True))
    ply = save_ply(gaussians, args.out / "demo_room.ply")
    print(
        f"rendered {len(gaussians)} Gaussians into {args.views} panoramas of {args.height}x{2 * args.height} "
        f"in {elapsed:.2f} s on {args.device}\nwrote {args.out}/rgb_*.png, depth_*.png and {ply}"
    )
    return 0
