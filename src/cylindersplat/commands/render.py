"""``cylindersplat render``: posed panoramas (or any 3DGS splat file) -> novel views (RGB + depth), a fly-through,
a PLY."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from ..utils.atomic import new_folders, output_set
from ._arguments import (
    check_output,
    field_of_view,
    finite_float,
    frame_count,
    image_resolution,
    memory_advice,
    positive_int,
    refuse_folder_as_splat_file,
)
from ._inference import add_input_arguments, reconstruct_from_args

VIEW_PATTERNS = ("view_*_rgb.png", "view_*_depth.png", "view_*_depth.npy", "view_*_depth_mm.png", "poses.json")
RENDER_PATTERNS = ("gaussians.ply", "flythrough.gif", "flythrough.mp4", "flythrough.webm", "flythrough_poses.json")
PLY_DEFAULT_HEIGHT = 512  # --ply without --output-resolution: 512x1024 panoramas, 512x682 pinhole views
LOW_COVERAGE = 0.05  # panoramas that show the scene in fewer of their pixels than this are warned about


def _yaw(degrees: float):
    """Rotation about the camera's own vertical (y) axis; positive turns toward +x (the panorama's right)."""
    import torch

    a = math.radians(degrees)
    turn = torch.eye(4)
    turn[0, 0], turn[0, 2], turn[2, 0], turn[2, 2] = math.cos(a), math.sin(a), -math.sin(a), math.cos(a)
    return turn


def _size(args, height: int) -> tuple[int, int]:
    """--output-resolution, else panoramas ``height x 2 height`` or pinhole views ``height x 4/3 height``."""
    if args.output_resolution:
        return tuple(args.output_resolution)
    return (height, 2 * height) if args.camera == "equirect" else (height, 2 * round(2 * height / 3))


def _camera(args, height: int, width: int):
    from ..inference.pipeline import pinhole_intrinsics
    from ..render import Equirect, Pinhole

    if args.camera == "pinhole":
        return Pinhole(pinhole_intrinsics(height, width, args.fov), height, width)
    if width != 2 * height:
        raise ValueError(f"panoramas need W == 2H, got --output-resolution {height}x{width}; "
                         "for other shapes render perspective views with --camera pinhole")
    return Equirect(height, width)


def camera_record(camera, fov: float | None = None) -> dict:
    """How a view was rendered, for the poses files written next to the images."""
    from ..render import Pinhole

    if isinstance(camera, Pinhole):
        k = camera.intrinsics
        return {"model": "pinhole", "height": camera.height, "width": camera.width, "K": k.tolist(),
                "fov_x_deg": fov, "note": "OpenCV intrinsics, pixel centres at +0.5 "
                "(principal point W/2, H/2 when centred)"}
    return {"model": "equirect", "height": camera.height, "width": camera.width}


def _memory_advice(refusal) -> str:
    """What fixes a render refused for memory, in this command's options."""
    fewer = "" if refusal.cameras == 1 else f"--view-batch {max(1, refusal.cameras // 2)} (views rendered at once), "
    return f"use {fewer}a smaller --output-resolution, or a GPU (--device cuda)"


def _earlier_render(out: Path, keep) -> list[Path]:
    """What an earlier render wrote into ``out`` (views, their poses.json, gaussians.ply, a fly-through): this
    render's files must never stand beside another's, whatever subset of them it writes, so those it does not
    replace are deleted once its own are all in place. ``keep``: paths not to touch (the --ply being rendered,
    which may lie there)."""
    kept = {Path(p).resolve() for p in keep if p is not None}
    view_dir = out / "views"
    stale = [p for pattern in VIEW_PATTERNS for p in view_dir.glob(pattern)] if view_dir.is_dir() else []
    stale += [out / name for name in RENDER_PATTERNS if (out / name).is_file()]
    return [p for p in stale if p.resolve() not in kept]


def _refuse_replacing_inputs(args) -> None:
    """Refuse, before any work, an --out where this render would replace or remove (as an earlier render's) a file
    it reads: a panorama, depth or poses file of --input (e.g. --input OUT/views, the views of an earlier render), a
    --views or --camera-path file (the --ply is never replaced: :func:`_earlier_render` keeps it)."""
    from ..data.folder import input_files

    reads = [(p, option) for p, option in ((args.views, "--views"), (args.camera_path, "--camera-path"))
             if p is not None]
    if args.input:  # (never with --ply: refused before)
        reads = [(p, "--input") for p in input_files(args.input, args.poses_file, args.allow_outside_paths)] + reads
    at_risk = {p.resolve() for p in _earlier_render(args.out, keep=[args.ply])}  # (the --ply is kept, not written)
    clashes = [(p, option) for p, option in reads if Path(p).resolve() in at_risk]
    if clashes:
        (first, option), more = clashes[0], len(clashes) - 1
        raise ValueError(f"--out {args.out} would replace or remove {first}{f' (and {more} more)' if more else ''}, "
                         f"which this render reads ({option}): choose another --out")


def _warn_if_little_covered(covered: int, pixels: int, camera) -> None:
    """Panoramas see every direction: one that shows the scene in a few % of its pixels points at a scene far
    smaller than the cameras' distances (a unit mistake, e.g. millimetres read as metres) or cameras outside it."""
    import warnings

    from ..render import Pinhole
    from ..validation import ScaleWarning

    if isinstance(camera, Pinhole) or not covered or covered / pixels >= LOW_COVERAGE:
        return  # (none covered: the renderer has said that nothing is visible)
    warnings.warn(f"the rendered views show the scene in only {100 * covered / pixels:.1f} % of their pixels: is "
                  "the scene (or the poses) in other units than metres, or are the cameras outside it? Gaussians "
                  "closer than 1 cm to a camera are not drawn", ScaleWarning, stacklevel=2)


def _planned(args, view_poses, video) -> list[Path]:
    """The files this render still has to write, named when one of them fails (none is then written)."""
    planned = [args.out / "views" / "poses.json"] if view_poses is not None else []
    planned += [args.out / "gaussians.ply"] if not args.no_ply and not args.ply else []
    planned += [video, args.out / "flythrough_poses.json"] if video is not None else []
    return planned


@memory_advice(_memory_advice)
def run(args: argparse.Namespace) -> int:
    import torch

    from ..data.poses import PoseRecord, write_poses_json
    from ..gaussians import save_ply
    from ..inference import depth_limits, flythrough_path, midpoint_poses, read_poses_file, write_flythrough, write_view
    from ..inference.pipeline import iter_views, raster_settings, sampled_depth_limits, write_metric_depth
    from ..inference.video import video_path_with_fallback

    if not all(math.isfinite(c) and 0 <= c <= 1 for c in args.background):
        raise ValueError("--background must be three numbers in [0, 1] (R G B), got "
                         f"{' '.join(map(str, args.background))}")
    check_output(args.out, folder=True)
    # Everything that can be checked is checked before minutes of reconstruction and rendering.
    view_poses = torch.stack([pose for _, pose, _ in read_poses_file(args.views)]) if args.views else None
    path_poses = torch.stack([pose for _, pose, _ in read_poses_file(args.camera_path)]) if args.camera_path else None
    video = None
    if args.frames or path_poses is not None:
        video, note = video_path_with_fallback(args.out / f"flythrough.{args.video_format}")
        if note:
            print(note)
    if args.ply:  # an existing 3DGS scene: no model, no input panoramas
        from ..gaussians.formats import READ_FORMATS, splat_format

        refuse_folder_as_splat_file(args.ply, "--ply")
        splat_format(args.ply, READ_FORMATS)  # an unknown format fails before anything is read
        if args.input or args.checkpoint:
            raise ValueError("give either --ply or --input/--checkpoint, not both")
        if view_poses is None and path_poses is None:
            raise ValueError("rendering a PLY needs camera poses: --views POSES (views, and a fly-through through "
                             "them) and/or --camera-path POSES (a fly-through along exactly those poses)")
    else:
        if not args.input:
            raise ValueError("give --input (with --checkpoint, or the shipped weights) or --ply to "
                             "render an existing 3DGS scene")
    if args.output_resolution:
        _camera(args, *args.output_resolution)  # a bad size fails now, not after the reconstruction
    _refuse_replacing_inputs(args)
    turn = _yaw(args.yaw)

    if args.ply:
        from ..gaussians import load_gaussians
        from ..validation import check_splats_near_origin

        gaussians = load_gaussians(args.ply, device=args.device)  # the loader of `view`: every splat format
        print(f"loaded {len(gaussians):,} Gaussians from {args.ply}")
        check_splats_near_origin(gaussians.means, str(args.ply))
        inputs, settings, front = None, None, None  # a splat file is drawn as 3DGS draws it
    else:
        inputs, gaussians, model, front = reconstruct_from_args(args, layers=True)
        settings = raster_settings(model.config)  # the model's own drawing (its render_dilation and layering)
    h, w = _size(args, inputs.size[0] if inputs is not None else PLY_DEFAULT_HEIGHT)
    camera = _camera(args, h, w)
    record = camera_record(camera, args.fov if args.camera == "pinhole" else None)
    background = tuple(args.background)

    # Novel views: the poses given, else halfway between consecutive input cameras (none for a PLY without --views).
    keys = inputs.c2w if inputs is not None else view_poses  # what a generated fly-through passes through
    if view_poses is None and inputs is not None:
        view_poses = midpoint_poses(inputs.c2w)
    if inputs is not None:
        near, far = depth_limits(inputs.depths)
    else:  # colours fixed before rendering, so views and frames are written as they come
        near, far = sampled_depth_limits(gaussians, (view_poses if view_poses is not None else path_poses) @ turn)
    view_dir = args.out / "views"
    said = []  # printed once every file is in place: a failure part-way writes (and says) none of them
    stale = lambda: _earlier_render(args.out, keep=[args.ply])  # noqa: E731
    folders = (args.out, view_dir) if view_poses is not None else (args.out,)  # a failure leaves none it made
    with new_folders(*folders), output_set(args.out, planned=_planned(args, view_poses, video), stale=stale) as outputs:
        if view_poses is not None:
            view_poses = view_poses @ turn
            records, index, covered = [], 0, 0
            for out in iter_views(gaussians, view_poses, h, w, background, args.view_batch, progress=True,
                                  desc="novel views", camera=camera, settings=settings, front=front):
                covered += int((out.alpha > 0.5).sum())
                for k in range(len(out.rgb)):  # written as rendered: memory holds one chunk of views
                    stem = f"view_{index:03d}"
                    write_view(view_dir / f"{stem}_rgb.png", view_dir / f"{stem}_depth.png", out.rgb[k], out.depth[k],
                               out.alpha[k], near, far)
                    if args.metric_depth:  # metres along each ray (0 where less than half covered), for measuring
                        write_metric_depth(view_dir / f"{stem}_depth.npy", view_dir / f"{stem}_depth_mm.png",
                                           out.depth[k], out.alpha[k])
                    records.append(PoseRecord(f"{stem}_rgb.png", view_poses[index],
                                              f"{stem}_depth.npy" if args.metric_depth else None))
                    index += 1
            extra = {"camera": record}
            if args.metric_depth:
                extra["depth_type"] = ("radial distance along each pixel's ray: view_NNN_depth.npy float32 metres, "
                                       "view_NNN_depth_mm.png 16-bit depth_scale units per metre; 0 = no surface")
            _warn_if_little_covered(covered, index * h * w, camera)
            write_poses_json(view_dir / "poses.json", records, depth_scale=1000 if args.metric_depth else None, **extra)
            what = "RGB + depth colormap" + (" + metric depth (.npy metres, 16-bit PNG mm)" if args.metric_depth
                                             else "")
            views, their = ("view", "its") if index == 1 else ("views", "their")
            said.append(f"wrote {index} {record['model']} {views} ({what}, {h}x{w}) and {their} poses.json to "
                        f"{view_dir}")

        if not args.no_ply and not args.ply:
            ply = save_ply(gaussians.to("cpu"), args.out / "gaussians.ply")
            said.append(f"wrote {ply}")
        if video is not None:
            if path_poses is not None:
                frames = path_poses @ turn
            else:
                frames = flythrough_path(keys, args.frames) @ turn
            written = write_flythrough(video, gaussians, None, h, w, fps=args.fps, near=near, far=far,
                                       background=background, camera=camera, poses=frames, chunk=args.view_batch,
                                       settings=settings, front=front)
            poses_file = write_poses_json(args.out / "flythrough_poses.json", [PoseRecord(None, p) for p in frames],
                                          fps=args.fps, camera=record)
            said.append(f"wrote {written} ({len(frames)} frames, RGB above depth) and {poses_file.name}")
    print("\n".join(said))
    if outputs.removed:
        print(f"removed {len(outputs.removed)} files of an earlier render in {args.out}")
    return 0


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "render", help="render novel views and a fly-through of your posed panoramas or of any 3DGS PLY",
        description="Reconstruct a folder of posed equirect panoramas with a trained model (or load any 3DGS PLY with "
        "--ply), then write views (RGB + depth colormap, optionally metric depth) at the poses of --views (default: "
        "halfway between consecutive inputs) with their poses.json, a fly-through (GIF, or MP4 with imageio-ffmpeg) "
        "along the input cameras or along --camera-path, and the Gaussians as a PLY. Panoramas by default, "
        "perspective views with --camera pinhole. Input format: docs/inference.md.",
    )
    add_input_arguments(parser, required=False)
    parser.add_argument("--ply", type=Path, metavar="SPLATS",
                        help="render this 3DGS scene instead of reconstructing: any splat file `view` reads (.ply, "
                        ".splat; .spz, .compressed.ply, .sog, .ksplat with splat-transform), from cylindersplat or any "
                        "3DGS tool; needs --views and/or --camera-path")
    parser.add_argument("--out", type=Path, default=Path("outputs/render"),
                        help="output folder (default outputs/render)")
    parser.add_argument("--views", type=Path, help="poses file of the views to render: poses.json (any \"convention\") "
                        "or nerfstudio transforms.json")
    parser.add_argument("--camera", choices=["equirect", "pinhole"], default="equirect",
                        help="equirect panoramas (default) or pinhole (perspective) views looking along each pose's +z")
    parser.add_argument("--fov", type=field_of_view, default=90.0,
                        help="pinhole horizontal field of view in degrees (default 90)")
    parser.add_argument("--yaw", type=finite_float, default=0.0,
                        help="turn every rendered camera by this many degrees about its own vertical axis, positive to "
                        "the right (e.g. to point a pinhole view elsewhere than the panorama's centre column)")
    parser.add_argument("--output-resolution", type=image_resolution,
                        help="HxW of the views and fly-through (default: the input resolution; with --ply 512x1024; "
                        "pinhole: that height at 3:4)")
    parser.add_argument("--view-batch", type=positive_int, metavar="N",
                        help="views (and fly-through frames) rendered at once (default: automatic, 4 at a time, fewer "
                        "when they would not fit in free memory)")
    parser.add_argument("--metric-depth", action="store_true",
                        help="also write each view's depth in metres: view_NNN_depth.npy (float32) and "
                        "view_NNN_depth_mm.png (16-bit millimetres)")
    parser.add_argument("--frames", type=frame_count, default=48,
                        help="frames of the generated fly-through through the input cameras (or --views); 0 skips "
                        "the video (default 48)")
    parser.add_argument("--camera-path", type=Path,
                        help="fly-through along exactly these poses, one frame each (poses file, e.g. an earlier "
                        "render's flythrough_poses.json); overrides --frames")
    parser.add_argument("--fps", type=positive_int, default=12, help="fly-through frame rate (default 12)")
    parser.add_argument("--video-format", default="gif", choices=["gif", "mp4", "webm"],
                        help="fly-through format (default gif; mp4/webm need imageio-ffmpeg, else a GIF is written)")
    parser.add_argument("--background", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("R", "G", "B"),
                        help="background colour in [0, 1] (default black)")
    parser.add_argument("--no-ply", action="store_true", help="do not write gaussians.ply")
    parser.add_argument("--pixel-blending", choices=["model", "over", "surface"], default="model",
                        help="how the pixel Gaussians of a seen surface combine: blended by their weights (surface; "
                        "sharper, 4 renders per view), the front-most one shown as 3DGS does (over; one render per "
                        "view, 2-3x faster), or as the model's config says (model, the default; the shipped weights: "
                        "surface)")
    parser.set_defaults(func=run)
