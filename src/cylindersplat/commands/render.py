"""``cylindersplat render``: posed panoramas -> novel views (RGB + depth), a fly-through video, a PLY."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._arguments import model_resolution
from ._inference import add_input_arguments, reconstruct_from_args


def run(args: argparse.Namespace) -> int:
    import torch

    from ..gaussians import save_ply
    import numpy as np

    from ..inference import (
        depth_limits,
        midpoint_poses,
        normalized_depth,
        read_poses_file,
        render_views,
        write_flythrough,
        write_view,
    )
    from ..utils.atomic import atomic_path

    from ..inference.video import check_video_format

    if args.frames < 0:
        raise ValueError("--frames must be >= 0")
    if args.fps < 1:
        raise ValueError("--fps must be >= 1")
    if args.frames:
        check_video_format(f"flythrough.{args.video_format}")  # before minutes of work, not after
    if args.ply:  # an existing 3DGS scene: no model, no input panoramas
        from ..gaussians import load_ply

        if args.input or args.checkpoint:
            raise ValueError("give either --ply or --input/--checkpoint, not both")
        if not args.views or not args.output_resolution:
            raise ValueError("rendering a PLY needs --views (camera poses) and --output-resolution")
        gaussians = load_ply(args.ply, device=args.device)
        print(f"loaded {len(gaussians):,} Gaussians from {args.ply}")
        path_c2w = None
    else:
        if not args.input or not args.checkpoint:
            raise ValueError("give --input and --checkpoint (or --ply to render an existing 3DGS scene)")
        inputs, gaussians, _ = reconstruct_from_args(args)
        path_c2w = inputs.c2w
    h, w = args.output_resolution or inputs.size
    background = tuple(args.background)
    args.out.mkdir(parents=True, exist_ok=True)

    # Novel views: the poses given, else halfway between consecutive input cameras.
    if args.views:
        poses = torch.stack([pose for _, pose, _ in read_poses_file(args.views)])
    else:
        poses = midpoint_poses(inputs.c2w)
    if path_c2w is None:
        path_c2w = poses
    views = render_views(gaussians, poses, h, w, background, progress=True, desc="novel views")
    near, far = depth_limits(inputs.depths if not args.ply else normalized_depth(views.depth, views.alpha))
    view_dir = args.out / "views"
    view_dir.mkdir(exist_ok=True)
    stale = [p for pattern in ("view_*_rgb.png", "view_*_depth.png", "view_*_depth.npy") for p in view_dir.glob(pattern)]
    for path in stale:  # views of an earlier render into this folder: never mix them with this one's
        path.unlink()
    if stale:
        print(f"removed {len(stale)} view images of an earlier render in {view_dir}")
    for i in range(len(poses)):
        write_view(view_dir / f"view_{i:03d}_rgb.png", view_dir / f"view_{i:03d}_depth.png",
                   views.rgb[i], views.depth[i], views.alpha[i], near, far)
        if args.metric_depth:  # metres along each ray (0 where less than half covered), for measuring
            with atomic_path(view_dir / f"view_{i:03d}_depth.npy") as tmp:
                np.save(tmp, normalized_depth(views.depth[i], views.alpha[i]).numpy().astype(np.float32))
    print(f"wrote {len(poses)} novel views (RGB + depth colormap, {h}x{w}) to {view_dir}")

    if not args.no_ply and not args.ply:
        ply = save_ply(gaussians.to("cpu"), args.out / "gaussians.ply")
        print(f"wrote {ply}")
    if args.frames:
        video = write_flythrough(args.out / f"flythrough.{args.video_format}", gaussians, path_c2w, h, w,
                                 frames=args.frames, fps=args.fps, near=near, far=far, background=background)
        print(f"wrote {video} ({args.frames} frames, RGB above depth)")
    return 0


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "render", help="render novel views and a fly-through of your own posed panoramas",
        description="Reconstruct a folder of posed equirect panoramas with a trained model, then write novel views "
        "(RGB + depth colormap) at the poses of --views (default: halfway between consecutive inputs), a "
        "fly-through along the input cameras (GIF, or MP4 with imageio[ffmpeg]) and the Gaussians as a PLY. "
        "Input format: docs/inference.md.",
    )
    add_input_arguments(parser, required=False)
    parser.add_argument("--ply", type=Path, help="render this 3DGS PLY (from cylindersplat or any 3DGS tool) instead of "
                        "reconstructing; needs --views and --output-resolution")
    parser.add_argument("--metric-depth", action="store_true",
                        help="also write each view's depth in metres as view_NNN_depth.npy (float32)")
    parser.add_argument("--out", type=Path, default=Path("outputs/render"), help="output folder (default outputs/render)")
    parser.add_argument("--views", type=Path, help='JSON of novel-view poses ({"poses": [4x4, ...]} or "frames" with "c2w")')
    parser.add_argument("--output-resolution", type=model_resolution,
                        help="HxW of the rendered views (default: the input resolution)")
    parser.add_argument("--frames", type=int, default=48, help="fly-through frames; 0 skips the video (default 48)")
    parser.add_argument("--fps", type=int, default=12, help="fly-through frame rate (default 12)")
    parser.add_argument("--video-format", default="gif", choices=["gif", "mp4", "webm"], help="fly-through format (default gif)")
    parser.add_argument("--background", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("R", "G", "B"),
                        help="background colour in [0, 1] (default black)")
    parser.add_argument("--no-ply", action="store_true", help="do not write gaussians.ply")
    parser.set_defaults(func=run)
