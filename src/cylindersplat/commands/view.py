"""``cylindersplat view``: Gaussians + input cameras in the browser (viser), as one HTML file, or as a PNG."""

from __future__ import annotations

import argparse
import contextlib
import os
from pathlib import Path

from ._arguments import field_of_view, image_resolution, port_number, positive_float, refuse_folder_as_splat_file
from ._inference import add_input_arguments, reconstruct_from_args


def _cameras_from_poses(path: Path, allow_outside: bool = False):
    """Cameras of a poses file; panoramas named in its frames are shown when they lie beside it (inside its
    folder unless ``allow_outside``)."""
    import numpy as np
    from PIL import Image

    from ..data.confine import confined_path
    from ..inference import read_poses_file
    from ..viewer import ViewCamera

    cameras = []
    for i, (name, c2w, _) in enumerate(read_poses_file(path)):
        image = None
        file = name and confined_path(path.parent, name, f'{path} frame {i} "image"', allow_outside)
        if file and file.is_file():
            with Image.open(file) as im:
                image = np.asarray(im.convert("RGB"))
        cameras.append(ViewCamera(c2w, name or f"camera {i}", image))
    return cameras


def check_sources(args: argparse.Namespace) -> None:
    """A splat file, or --input with --checkpoint: one of the two."""
    if args.splats is not None and (args.input is not None or args.checkpoint is not None):
        raise ValueError("give either a splat file or --input/--checkpoint, not both")
    if args.splats is not None:
        refuse_folder_as_splat_file(args.splats)
    if args.splats is None and args.input is None:
        raise ValueError("give a splat file (scene.ply, .spz, .compressed.ply, .sog) or --input (with --checkpoint, or "
                         "the shipped weights)")


def check_outputs(args: argparse.Namespace) -> None:
    """Refuse, before any work, an --html or --screenshot that would replace what the command reads: the splat
    file, the poses file, a panorama or depth file of the --input folder (or the other output)."""
    from ..data.folder import IMAGE_SUFFIXES, POSES_FILE
    from ._arguments import check_output

    reads = [(args.splats, "the splat file"), (args.poses_file, "the poses file")]
    if args.input is not None and args.poses_file is None:
        reads.append((Path(args.input) / POSES_FILE, "the poses file"))
    if args.html is not None and args.screenshot is not None and _same(args.html, args.screenshot):
        raise ValueError(f"--html and --screenshot name the same file {args.html}: give two")
    for option, target in (("--html", args.html), ("--screenshot", args.screenshot)):
        if target is None:
            continue
        check_output(target, folder=False, option=option)
        for source, what in reads:
            if source is not None and _same(target, source):
                raise ValueError(f"{option} {target} is {what} this command reads: give another {option}")
        if (args.input is not None and target.is_file() and os.path.realpath(target.parent) ==
                os.path.realpath(args.input) and target.suffix.lower() in (*IMAGE_SUFFIXES, ".npy")):
            raise ValueError(f"{option} {target} is a file of the --input folder {args.input} (a panorama or depth "
                             f"the folder reader takes): give another {option}")


def _same(a: Path, b: Path) -> bool:
    """Whether two paths name one file (links followed; what does not exist yet is compared by its path)."""
    return os.path.realpath(a) == os.path.realpath(b)


def load_scene(args: argparse.Namespace):
    """-> (gaussians on CPU, cameras) from a splat file (+ --poses-file) or --input/--checkpoint."""
    from ..viewer import ViewCamera

    if args.splats is not None:
        from ..gaussians import load_gaussians
        from ..validation import check_splats_near_origin

        gaussians = load_gaussians(args.splats)
        cameras = _cameras_from_poses(args.poses_file, args.allow_outside_paths) if args.poses_file else []
        print(f"loaded {len(gaussians):,} Gaussians from {args.splats}")
        check_splats_near_origin(gaussians.means, str(args.splats))
        return gaussians, cameras
    from ..data.io import to_uint8

    inputs, gaussians, _ = reconstruct_from_args(args)
    cameras = [ViewCamera(c2w.cpu(), name, to_uint8(image))
               for c2w, name, image in zip(inputs.c2w, inputs.names, inputs.images)]
    return gaussians.to("cpu"), cameras


# --screenshot's default sizes (HxW): a 4:3 pinhole view, a 2:1 panorama.
PINHOLE_SIZE = (480, 640)
PANORAMA_SIZE = (512, 1024)


def _screenshot(args: argparse.Namespace, gaussians, pose) -> Path:
    """--screenshot: the Gaussians above --min-opacity rendered from ``pose`` (in bands of rows where the whole
    picture would not fit in memory); a refusal names the options that make it fit."""
    from ..viewer import render_picture

    picture = gaussians[gaussians.opacities > args.min_opacity].to(args.device)
    try:
        return render_picture(args.screenshot, picture, pose, args.screenshot_size, args.fov, args.panorama)
    except MemoryError as exc:
        h, w = args.screenshot_size
        half = max(h // 2, 1)
        smaller = f"{half}x{2 * half if args.panorama else max(w // 2, 1)}"
        raise MemoryError(f"--screenshot at {h}x{w}: {str(exc).split('; ')[0]}; drop faint Gaussians with "
                          f"--min-opacity (now {args.min_opacity:g}; e.g. 0.1) or render a smaller --screenshot-size, "
                          f"e.g. {smaller}") from None


def run(args: argparse.Namespace) -> int:
    import torch

    from ..geometry import look_at_c2w
    from ..utils.atomic import output_set
    from ..viewer import default_view, import_viser, serve, write_html

    check_sources(args)
    check_outputs(args)
    if args.screenshot is None or args.html is not None:
        import_viser()  # a missing viewer package fails before the (slow) reconstruction
    if args.screenshot_size is None:  # the picture's kind decides its shape
        args.screenshot_size = PANORAMA_SIZE if args.panorama else PINHOLE_SIZE
    if args.panorama and args.screenshot_size[1] != 2 * args.screenshot_size[0]:
        raise ValueError(f"--panorama needs --screenshot-size HxW with W == 2H, got {args.screenshot_size}")
    gaussians, cameras = load_scene(args)
    both = args.html is not None and args.screenshot is not None  # one file alone is written atomically
    folder = os.path.commonpath([os.path.abspath(args.html.parent), os.path.abspath(args.screenshot.parent)]) \
        if both else "."
    with output_set(folder) if both else contextlib.nullcontext():  # both replace earlier files, or neither does
        if args.html is not None:
            write_html(args.html, gaussians, cameras, args.frustum_scale)
        if args.screenshot is not None:
            if args.panorama:
                pose = cameras[0].c2w if cameras else torch.eye(4)
            else:
                position, look_at = default_view(gaussians, cameras)
                pose = look_at_c2w(torch.tensor(position), torch.tensor(look_at)).float()
            _screenshot(args, gaussians, pose)
    if args.html is not None:  # in place once the set is whole
        print(f"wrote {args.html} ({args.html.stat().st_size / 1e6:.1f} MB; open it in a browser, no server needed)")
    if args.screenshot is not None:
        print(f"wrote {args.screenshot} ({'panorama' if args.panorama else 'pinhole view'}, "
              f"{args.screenshot_size[0]}x{args.screenshot_size[1]})")
    if args.html is None and args.screenshot is None:
        serve(gaussians, cameras, args.host, args.port, args.frustum_scale, args.duration)
    return 0


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "view", help="show Gaussians and the input cameras in the browser (viser), as one HTML file, or as a PNG",
        description="Serve a splat file (3DGS .ply, .spz, .compressed.ply, .sog) or the Gaussians reconstructed from "
        "--input panoramas with --checkpoint (as `cylindersplat export` builds them) in the browser, with one frustum "
        "per input camera. --html writes one self-contained page instead (no server), --screenshot a PNG rendered "
        "with cylindersplat's own renderer (no browser); with either, nothing is served. The browser parts need "
        "`pip install 'cylindersplat[view]'`. Guide: docs/viewer.md.",
    )
    parser.add_argument("splats", nargs="?", type=Path, help="splat file: .ply (3DGS), .compressed.ply, .spz or .sog "
                        "(the last three need splat-transform, see docs/viewer.md)")
    add_input_arguments(parser, required=False)
    # add_input_arguments' --poses-file also gives the cameras to show with a splat file.
    parser.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1; 0.0.0.0 for every "
                        "interface)")
    parser.add_argument("--port", type=port_number, default=8080,
                        help="port (default 8080; the next free one if taken; 0: one the system picks)")
    parser.add_argument("--duration", type=positive_float,
                        help="stop serving after this many seconds (default: until Ctrl+C)")
    parser.add_argument("--frustum-scale", type=positive_float, default=0.2,
                        help="size of the camera frustums in metres (default 0.2)")
    parser.add_argument("--html", type=Path, help="write the scene as one self-contained HTML file and do not serve")
    parser.add_argument("--screenshot", type=Path, help="render a PNG with cylindersplat's renderer (no browser) and "
                        "do not serve: a pinhole view from where the browser view starts (the input cameras' middle), "
                        "or --panorama; Gaussians at or below --min-opacity are left out, and a picture too large for "
                        "memory is rendered in bands of rows")
    parser.add_argument("--screenshot-size", type=image_resolution, default=None,
                        help="HxW of --screenshot (default 480x640, with --panorama 512x1024)")
    parser.add_argument("--fov", type=field_of_view, default=90.0,
                        help="horizontal field of view of --screenshot in degrees (default 90)")
    parser.add_argument("--panorama", action="store_true", help="--screenshot renders an equirect panorama from the "
                        "first input camera (or the origin) instead (a --screenshot-size must be H x 2H)")
    parser.set_defaults(func=run)
