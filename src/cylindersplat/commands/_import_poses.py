"""``cylindersplat data import-poses``: camera poses from 360° SfM/SLAM tools -> our ``poses.json``."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from ..utils.arguments import positive_float


class _FormatNames:
    """``--from`` choices: the pose registry's names, read when ``import-poses`` parses or prints its help (the
    registry imports torch; the rest of the command line does not wait for it)."""

    def _names(self) -> tuple[str, ...]:
        from ..data.poses.registry import POSE_FORMATS

        return tuple(POSE_FORMATS)

    def __contains__(self, name: object) -> bool:
        return name in self._names()

    def __iter__(self):
        return iter(self._names())


def _run(args: argparse.Namespace) -> int:
    from ..data.poses import PoseRecord, match_timestamps_to_images, pose_format, write_poses_json
    from ..inference.inputs import IMAGE_SUFFIXES
    from ..utils.atomic import output_set

    source, out = args.source, args.out
    source_format = pose_format(args.source_format)
    if out.is_dir() or out.suffix.lower() != ".json":
        raise ValueError(f"--out must be a .json file (e.g. my_scene/poses.json), got {out}")
    if args.fps is not None and source_format.images != "ordered":
        raise ValueError("--fps matches trajectory timestamps to frame numbers; it does not apply to --from "
                         f"{args.source_format}")
    if args.start_time is not None and args.fps is None:
        raise ValueError("--start-time is the timestamp of the first image when matching by --fps; give --fps too")
    if os.path.realpath(out) == os.path.realpath(source):  # --overwrite or not: the source is the user's
        raise ValueError(f"--out {out} is the source file it reads: give another --out (e.g. poses.json beside it)")
    if out.exists() and not args.overwrite:  # a hand-written or earlier poses file is never lost silently
        raise ValueError(f"{out} already exists (poses imported earlier, or written by hand) and is kept: give "
                         "--overwrite to replace it, or --out another file")
    records = source_format.read(source, args.scale, **{name: getattr(args, name) for name in source_format.options})
    base = out.parent.resolve()
    depth_scale = None
    if source_format.images == "relative":  # nerfstudio: names relative to transforms.json: keep them findable
        folder = source.parent.resolve()
        records = [PoseRecord(os.path.relpath(folder / r.image, base), r.c2w,
                              r.depth and os.path.relpath(folder / r.depth, base)) for r in records]
        if any(r.depth is not None and r.depth.lower().endswith(".npy") for r in records):
            raise ValueError(f"{source} has .npy depth files, which nerfstudio keeps in depth units (mm) but "
                             "poses.json reads in metres; use the transforms.json directly as the poses file "
                             "(render/export read it)")
        depth_scale = 1000
    if args.images is not None:
        if not args.images.is_dir():
            raise FileNotFoundError(f"--images: folder not found: {args.images}")
        # Each frame keeps its own name: only the folder is resolved, a symlinked image is not followed to its target.
        folder = args.images.resolve()
        if source_format.images == "ordered":
            images = sorted(p.name for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES
                            and not p.stem.endswith("_depth"))
            records = match_timestamps_to_images(records, [os.path.relpath(folder / name, base) for name in images],
                                                 args.fps, source, _start_time(args.start_time))
        elif source_format.images == "named":
            records = [PoseRecord(os.path.relpath(folder / _image_file(folder, r.image), base), r.c2w) for r in records]
        else:
            raise ValueError(f"--images does not apply to --from {args.source_format} (its frames name their "
                             "images)")
        # out may not exist yet: normpath, not resolve
        missing = [r.image for r in records if not Path(os.path.normpath(base / r.image)).is_file()]
        if missing:
            raise FileNotFoundError(f"{len(missing)} image(s) of the poses are not there, e.g. {base / missing[0]}")
    elif source_format.images == "ordered":
        records = [PoseRecord(None, r.c2w, None, r.timestamp) for r in records]
    records, extra = _near_origin(records, source, args.recentre)
    with output_set(out.parent):  # a failure keeps an earlier file and says so
        path = write_poses_json(out, records, depth_scale=depth_scale, source=f"{args.source_format}: {source}",
                                scale=args.scale, **extra)
    named = sum(r.image is not None for r in records)
    print(f"wrote {len(records)} poses (OpenCV camera-to-world, {args.scale:g} m per source unit) to {path}"
          + (f" with their {named} image names" if named else "; they pair with the folder's images in name order"))
    return 0


def _near_origin(records: list, source: Path, recentre: bool) -> tuple[list, dict]:
    """``(records, extra poses.json keys)``: with ``recentre``, the cameras moved so that the first lies at the
    origin (float64; ``"origin"``: the metres subtracted). Without it, cameras beyond
    :data:`~cylindersplat.validation.MAX_TRANSLATION_M` (georeferenced coordinates, such as UTM's millions of metres)
    are refused: render and export compute in float32, which has no centimetres left there."""
    import numpy as np
    import torch

    from ..data.poses import PoseRecord
    from ..validation import MAX_TRANSLATION_M, farthest_camera

    if recentre:
        origin = records[0].c2w[:3, 3].to(torch.float64).clone()
        moved = []
        for r in records:
            c2w = r.c2w.to(torch.float64).clone()
            c2w[:3, 3] -= origin
            moved.append(PoseRecord(r.image, c2w, r.depth, r.timestamp))
        return moved, {"origin": origin.tolist()}
    far = farthest_camera(torch.stack([r.c2w.to(torch.float64) for r in records]))
    if far > MAX_TRANSLATION_M:
        step = float(np.spacing(np.float32(far)))
        raise ValueError(f"{source}: the cameras lie up to {far:.3g} m from the origin (georeferenced coordinates?), "
                         f"beyond {MAX_TRANSLATION_M:g} m: render and export compute in float32, which keeps only "
                         f"{step:.2g} m steps there; give --recentre to move the first camera to the origin (the "
                         "offset is kept in poses.json as \"origin\")")
    return records, {}


def _image_file(folder: Path, name: str) -> str:
    """``name`` in ``folder``; a Metashape label without its suffix (``hall`` for ``hall.jpg``) is found by stem."""
    if (folder / name).is_file() or Path(name).suffix:
        return name
    from ..inference.inputs import IMAGE_SUFFIXES

    matches = [p.name for p in sorted(folder.glob(f"{name}.*")) if p.suffix.lower() in IMAGE_SUFFIXES]
    return matches[0] if matches else name


def _start_time(text: str | None) -> float | str:
    """--start-time: seconds, or ``first``; default 0."""
    if text is None:
        return 0.0
    if text == "first":
        return text
    try:
        return float(text)
    except ValueError:
        raise ValueError(f"--start-time must be seconds or 'first', got {text!r}") from None


def register(sub) -> None:
    """Add ``import-poses`` to the ``data`` subcommand's parsers."""
    parser = sub.add_parser(
        "import-poses",
        help="convert 360° camera poses of other tools (COLMAP, OpenSfM, nerfstudio, stella_vslam, ...) to poses.json",
        description="Convert the poses of equirectangular panoramas from another tool into our poses.json "
        "(OpenCV camera-to-world, metres): an OpenSfM/OpenDroneMap reconstruction.json (spherical cameras), a "
        "nerfstudio transforms.json (EQUIRECTANGULAR), or a stella_vslam/OpenVSLAM keyframe trajectory (TUM or "
        "KITTI format), a COLMAP sparse model (EQUIRECTANGULAR cameras, or the virtual pinhole cameras of COLMAP's "
        "panorama workflow), an Agisoft Metashape camera XML (spherical sensors) or an OpenMVG sfm_data.json "
        "(spherical intrinsics). SfM/SLAM results have an arbitrary scale: --scale gives metres per unit. See "
        "docs/inference.md; the readers and how to add one: docs/poses.md.")
    parser.add_argument("source", type=Path, help="reconstruction.json, transforms.json, a trajectory text file, a "
                        "COLMAP model folder (sparse/0), a Metashape cameras .xml or an OpenMVG sfm_data.json")
    # A metavar, so that argparse does not list the choices (importing the registry) when the argument is added.
    parser.add_argument("--from", dest="source_format", required=True, choices=_FormatNames(), metavar="FORMAT",
                        help="the source's format: %(choices)s")
    parser.add_argument("--out", type=Path, required=True, help="poses.json to write (in the input folder)")
    parser.add_argument("--scale", type=float, default=1.0,
                        help="metres per source unit: multiplies every camera position (default 1)")
    parser.add_argument("--images", type=Path,
                        help="folder of the panoramas: OpenSfM/COLMAP/Metashape/OpenMVG image names are looked up "
                        "there; TUM/KITTI poses are matched to its images in name order, or by timestamp with --fps")
    parser.add_argument("--fps", type=positive_float,
                        help="TUM: the pose at time t belongs to image number round(t * fps) of --images (frames "
                        "numbered from 0, as stella_vslam times a video)")
    parser.add_argument("--start-time", metavar="SECONDS|first",
                        help="with --fps: the timestamp of image 0 (default 0); 'first' takes the trajectory's first "
                        "timestamp, for SLAM runs that stamp poses with the clock")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out file (kept by default)")
    parser.add_argument("--recentre", "--recenter", action="store_true",
                        help="move the cameras so that the first lies at the origin (for georeferenced poses, "
                        "millions of metres out, where float32 has no centimetres left; the offset is stored in "
                        "poses.json as \"origin\"); cameras beyond 10 km are refused without it")
    parser.add_argument("--reconstruction", type=int, default=0,
                        help="OpenSfM: which reconstruction of the file (default 0, the largest)")
    parser.set_defaults(func=_run)
