"""``cylindersplat render``: posed panoramas -> novel views (RGB + depth), a fly-through video, a PLY."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._arguments import model_resolution
from ._inference import add_input_arguments, reconstruct_from_args


def run(args: argparse.Namespace) -> int:
    import torch

    from ..gaussians import save_ply
    from ..inference import depth_limits, midpoint_poses, read_poses_file, render_views, write_flythrough, write_view

    from ..inference.video import check_video_format

    if args.frames < 0:
        raise ValueError("--frames must be >= 0")
    if args.fps < 1:
        raise ValueError("--fps must be >= 1")
    if args.frames:
        check_video_format(f"flythrough.{args.video_format}")  # before minutes of work, not after
    inputs, gaussians, _ = reconstruct_from_args(args)
    h, w = args.output_resolution or inputs.size
    background = tuple(args.background)
    near, far = depth_limits(inputs.depths)
    args.out.mkdir(parents=True, exist_ok=True)

    # Novel views: the poses given, else halfway between consecutive input cameras.
    if args.views:
        poses = torch.stack([pose for _, pose, _ in read_poses_file(args.views)])
    else:
        poses = midpoint_poses(inputs.c2w)
    views = render_views(gaussians, poses, h, w, background, progress=True, desc="novel views")
    view_dir = args.out / "views"
    view_dir.mkdir(exist_ok=True)
    stale = list(view_dir.glob("view_*_rgb.png")) + list(view_dir.glob("view_*_depth.png"))
    for path in stale:  # views of an earlier render into this folder: never mix them with this one's
        path.unlink()
    if stale:
        print(f"removed {len(stale)} view images of an earlier render in {view_dir}")
    for i in range(len(poses)):
        write_view(view_dir / f"view_{i:03d}_rgb.png", view_dir / f"view_{i:03d}_depth.png",
                   views.rgb[i], views.depth[i], views.alpha[i], near, far)
    print(f"wrote {len(poses)} novel views (RGB + depth colormap, {h}x{w}) to {view_dir}")

    if not args.no_ply:
        ply = save_ply(gaussians.to("cpu"), args.out / "gaussians.ply")
        print(f"wrote {ply}")
    if args.frames:
        video = write_flythrough(args.out / f"flythrough.{args.video_format}", gaussians, inputs.c2w, h, w,
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
    add_input_arguments(parser)
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
