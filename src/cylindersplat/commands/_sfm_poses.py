"""``cylindersplat data poses FOLDER``: poses of unposed 360° panoramas by SfM (pycolmap), in metres."""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np

from ._arguments import device, positive_float, positive_int

MATCHERS = ("auto", "exhaustive", "sequential")


def _scale_arg(text: str) -> str | float:
    if text in ("auto", "none"):
        return text
    try:
        return positive_float(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"--scale must be auto, none or a positive number of metres per SfM unit, "
                                         f"got {text!r}") from None


def _warn(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr, flush=True)


def _depth_maps(args, folder: Path, names: list[str]) -> tuple[dict[str, np.ndarray], str]:
    """Metric radial depth per panorama name: the --depth-prior for every panorama, else the folder's depth files."""
    from ..data.folder import _find_depth
    from ..data.io import read_depth_npy, read_depth_png

    if args.depth_prior:
        from ..data.depth_prior import PriorQuery, parse_depth_prior
        from ..data.io import read_rgb

        prior = parse_depth_prior(args.depth_prior, device=args.device)
        maps = {}
        for name in names:
            path = folder / name
            query = PriorQuery(read_rgb(path), None, path, f"folder/{folder.name}/{name}", folder)
            maps[name] = prior(query).double().numpy()
        return maps, f"the depth prior {args.depth_prior}"
    maps = {}
    for name in names:
        depth = _find_depth(folder / name)
        if depth is None:
            continue
        try:
            if depth.suffix.lower() == ".npy":
                maps[name] = read_depth_npy(depth).double().numpy()
            else:
                maps[name] = read_depth_png(depth, scale=args.depth_scale).double().numpy()
        except (OSError, EOFError, SyntaxError) as exc:  # an empty or cut .npy/.png (ValueError names it already)
            raise ValueError(f"{depth} is not a readable depth file ({type(exc).__name__}: {exc}): fix or remove it, "
                             "or give --scale/--camera-height") from None
    return maps, f"{len(maps)} depth file(s) (<stem>_depth.*, PNG {args.depth_scale:g} per metre)"


def _metric_scale(args, folder: Path, result, c2w: dict[str, np.ndarray]):
    """``(metres per SfM unit, description or None)`` as --scale / --camera-height / the depth ask."""
    from ..data.poses.metric_scale import scale_from_camera_height, scale_from_depth
    from ..data.poses.sfm import observations

    if isinstance(args.scale, float):
        return args.scale, f"{args.scale:g} m per SfM unit (--scale)"
    if args.scale == "none":
        return 1.0, None
    obs = observations(result.reconstruction)
    if args.camera_height is not None:
        estimate = scale_from_camera_height(obs, c2w, args.camera_height)
        return estimate.scale, estimate.describe()
    names = sorted(c2w)
    maps, source = _depth_maps(args, folder, names)
    if not maps:
        _warn("no depth files (<stem>_depth.png/.npy) and no --depth-prior: the poses are in SfM units, not metres; "
              "give --depth-prior SPEC, --camera-height METRES or --scale METRES_PER_UNIT")
        return 1.0, None
    from PIL import Image

    sizes = {}
    for name in maps:
        with Image.open(folder / name) as image:
            sizes[name] = (image.height, image.width)
    estimate = scale_from_depth(obs, c2w, maps, sizes, source)
    if estimate.spread > 0.1:
        _warn(f"the depth and the SfM points disagree a lot (+-{100 * estimate.spread:.0f} % between points): check "
              "--depth-scale or the depth files")
    return estimate.scale, estimate.describe()


# What a COLMAP sparse model folder holds (COLMAP >= 3.12 adds rigs and frames): the only files --sparse-dir replaces.
COLMAP_MODEL_FILES = {f"{stem}.{kind}" for stem in ("cameras", "images", "points3D", "rigs", "frames")
                      for kind in ("txt", "bin")} | {"project.ini"}


def _inside(path: Path, folder: Path) -> bool:
    """Whether ``path`` is ``folder`` or lies in it, links followed (``realpath``: a symlink loop does not raise)."""
    path, folder = Path(os.path.realpath(path)), Path(os.path.realpath(folder))
    return path == folder or folder in path.parents


def _check_outputs(folder: Path, images: list[Path], out: Path, sparse: Path, overwrite: bool) -> None:
    """Refuse outputs that would lose what the user has (one line each, before any work): an existing poses file or
    model without ``--overwrite``, and, even with it, a ``--sparse-dir`` that is a file, holds the panoramas or the
    poses file, or holds anything but a COLMAP model (it is replaced as a whole)."""
    if _inside(folder, sparse) or any(_inside(image, sparse) for image in images):
        raise ValueError(f"--sparse-dir {sparse} holds the input panoramas ({folder}), and the COLMAP model replaces "
                         "that folder as a whole: give a new folder (default: sparse/0 beside the poses file)")
    if _inside(out, sparse):
        raise ValueError(f"--sparse-dir {sparse} would hold the poses file {out}: give a folder beside it, not "
                         "above it")
    if sparse.exists() and not sparse.is_dir():
        raise ValueError(f"--sparse-dir {sparse} is a file, not a folder: give a new folder for the COLMAP model")
    if sparse.is_dir():
        foreign = sorted(p.name for p in sparse.iterdir() if p.name not in COLMAP_MODEL_FILES or not p.is_file())
        if foreign:
            shown = ", ".join(foreign[:4]) + (f" and {len(foreign) - 4} more" if len(foreign) > 4 else "")
            raise ValueError(f"--sparse-dir {sparse} holds files that are not a COLMAP model ({shown}), and the model "
                             "replaces that folder as a whole: give a new or empty folder")
    if overwrite:
        return
    if out.exists():
        raise ValueError(f"{out} already exists (poses of an earlier run, imported or written by hand) and is kept: "
                         "give --overwrite to replace it and its COLMAP model, or --out another file")
    if sparse.is_dir() and any(sparse.iterdir()):
        raise ValueError(f"{sparse} already holds a COLMAP model and is kept: give --overwrite to replace it, or "
                         "--sparse-dir another folder")


def _write_outputs(out: Path, sparse: Path, write_model, write_poses) -> None:
    """Write the model (``write_model(folder)``) and the poses file (``write_poses(path)``) beside their final
    places, then swap both in; on any failure the earlier ones stay as they were and no temporary is left.
    ``sparse`` gets the permissions of a folder made with ``mkdir`` (umask honoured)."""
    sparse.parent.mkdir(parents=True, exist_ok=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{sparse.name}.", suffix=".tmp", dir=sparse.parent))
    fd, poses_tmp = tempfile.mkstemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent)
    os.close(fd)
    poses_tmp, backup = Path(poses_tmp), None
    try:
        umask = os.umask(0o022)
        os.umask(umask)
        os.chmod(staging, 0o777 & ~umask)  # mkdtemp makes 0700
        write_model(str(staging))
        write_poses(poses_tmp)
        os.chmod(poses_tmp, 0o666 & ~umask)
        if sparse.exists():
            backup = Path(tempfile.mkdtemp(prefix=f".{sparse.name}.old.", suffix=".tmp", dir=sparse.parent))
            os.replace(sparse, backup)
        os.replace(staging, sparse)
        try:
            os.replace(poses_tmp, out)
        except BaseException:
            os.replace(sparse, staging)  # the earlier model back where it was
            if backup is not None:
                os.replace(backup, sparse)
                backup = None
            raise
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        poses_tmp.unlink(missing_ok=True)
        if backup is not None and not sparse.exists():
            os.replace(backup, sparse)
            backup = None
        raise
    finally:
        if backup is not None:
            shutil.rmtree(backup, ignore_errors=True)


def _run(args: argparse.Namespace) -> int:
    from ..data.folder import _folder_images
    from ..data.poses import PoseRecord, write_poses_json
    from ..data.poses.poses_json import SFM_UNITS
    from ..data.poses.sfm import check_panoramas, require_pycolmap, run_sfm

    folder = args.folder
    if not folder.is_dir():
        raise FileNotFoundError(f"folder not found: {folder}")
    out = args.out if args.out is not None else folder / "poses.json"
    if out.is_dir() or out.suffix.lower() != ".json":
        raise ValueError(f"--out must be a .json file (e.g. {folder / 'poses.json'}), got {out}")
    sparse = args.sparse_dir if args.sparse_dir is not None else out.parent / "sparse" / "0"
    images = _folder_images(folder)
    _check_outputs(folder, images, out, sparse, args.overwrite)  # before the minutes of SfM, not after
    check_panoramas(images, folder)
    pycolmap = require_pycolmap()
    result = run_sfm(images, folder, args.matcher, threads=args.threads)
    names = sorted(result.c2w)
    c2w = {n: result.c2w[n] for n in names}
    scale, how = _metric_scale(args, folder, result, c2w)
    # The output frame: the first panorama at the origin with identity rotation (upright panoramas: world +y down).
    anchor = np.eye(4) if args.keep_sfm_frame else np.linalg.inv(c2w[names[0]])
    posed = {}
    for name in names:
        pose = anchor @ c2w[name]
        pose[:3, 3] *= scale
        posed[name] = pose
    base = out.parent.resolve()
    import torch

    records = [PoseRecord(os.path.relpath(folder.resolve() / n, base), torch.from_numpy(posed[n])) for n in names]
    summary = {"registered": names, "not_registered": result.unregistered, "points": result.points,
               "mean_reprojection_error_px": round(result.reprojection_error, 4), "matcher": result.matcher,
               "metres_per_sfm_unit": scale, "scale": how or SFM_UNITS, "colmap": pycolmap.__version__}
    # The sparse model in the same frame and units as the poses, so that a user can open both together.
    rec = result.reconstruction
    rec.transform(pycolmap.Sim3d(scale, pycolmap.Rotation3d(anchor[:3, :3]), scale * anchor[:3, 3]))
    _write_outputs(out, sparse, rec.write_text, lambda path: write_poses_json(
        path, records, depth_scale=args.depth_scale, source="cylindersplat data poses (COLMAP SfM, equirectangular "
        "camera)", sfm=summary))
    total = len(names) + len(result.unregistered)
    print(f"registered {len(names)} of {total} panoramas, {result.points} points, mean reprojection error "
          f"{result.reprojection_error:.2f} px ({result.matcher} matching, {result.seconds:.1f} s)")
    if result.unregistered:
        _warn(f"not registered (no pose written): {', '.join(result.unregistered)}; they share too few features "
              "with the others: add panoramas between them, or try --matcher exhaustive")
    for other in result.others:
        _warn(f"a separate model also holds {', '.join(other)} (not connected to the poses written); add panoramas "
              "that link the two groups")
    print(f"scale: {how}" if how else "scale: none (poses in SfM units)")
    print(f"wrote {out} ({len(records)} poses, OpenCV camera-to-world, "
          f"{'SfM frame' if args.keep_sfm_frame else 'first panorama at the origin'}) and the COLMAP model {sparse}")
    return 0


def register(sub) -> None:
    """Add ``poses`` to the ``data`` subcommand's parsers."""
    parser = sub.add_parser(
        "poses", help="poses of unposed 360° panoramas by structure from motion (pycolmap), scaled to metres",
        description="Run COLMAP's structure from motion (pycolmap, an optional extra: pip install "
        "'cylindersplat[sfm]') on the equirectangular panoramas of FOLDER with COLMAP's EQUIRECTANGULAR camera, and "
        "write FOLDER/poses.json (OpenCV camera-to-world, the first panorama at the origin) so that FOLDER is an input "
        "folder, plus the sparse model (COLMAP text format) in sparse/0 beside it. The metric scale comes from the "
        "folder's depth files (<stem>_depth.png/.npy), a --depth-prior, or --camera-height. See docs/inference.md.")
    parser.add_argument("folder", type=Path, help="folder of 2:1 equirectangular panoramas (and optional depth files)")
    parser.add_argument("--out", type=Path, help="poses file to write (default FOLDER/poses.json)")
    parser.add_argument("--sparse-dir", type=Path, help="where the COLMAP model goes (default: sparse/0 beside --out)")
    parser.add_argument("--matcher", choices=MATCHERS, default="auto",
                        help="exhaustive: every pair (photos); sequential: neighbours in name order (video frames); "
                        "auto: exhaustive up to 50 panoramas (default)")
    parser.add_argument("--scale", type=_scale_arg, default="auto", metavar="auto|none|M",
                        help="auto (default): metres from the depth files or --depth-prior (or --camera-height); "
                        "none: keep SfM units; a number: metres per SfM unit")
    parser.add_argument("--depth-scale", type=positive_float, default=1000.0,
                        help="units per metre of 16-bit depth PNGs (default 1000 = millimetres); also written to "
                        "poses.json")
    parser.add_argument("--depth-prior", metavar="SPEC",
                        help="depth for the scale from a prior instead of depth files (file:NAME, exported:NET.pt2, "
                        "unik3d:..., as render --depth-prior)")
    parser.add_argument("--camera-height", type=positive_float, metavar="METRES",
                        help="scale from the camera's height above a visible floor (upright panoramas)")
    parser.add_argument("--keep-sfm-frame", action="store_true",
                        help="keep COLMAP's world frame (scaled) instead of putting the first panorama at the origin")
    parser.add_argument("--threads", type=positive_int, default=None, help="CPU threads for COLMAP (default: up to 8)")
    parser.add_argument("--device", type=device, default="cpu", help="device of a network --depth-prior (default cpu)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace an existing poses file and COLMAP model (kept by default); a --sparse-dir that "
                        "holds anything but a COLMAP model is never replaced")
    parser.set_defaults(func=_run)
