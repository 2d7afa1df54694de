"""Poses of unposed 360° panoramas by structure from motion: COLMAP through pycolmap, equirectangular camera.

:func:`run_sfm` extracts SIFT features on the panoramas as they are (COLMAP's ``EQUIRECTANGULAR`` model maps a
pixel to a ray exactly as :mod:`cylindersplat.geometry` does, so no cube faces are cut), matches them (all pairs for
a handful of photos, neighbours in name order for video frames) and runs COLMAP's incremental mapper with options
for panorama walks:

* ``init_max_forward_motion = 1``: COLMAP's default 0.95 rejects an initial pair whose motion is along the
  optical axis, which for a perspective camera means a poor triangulation angle, but a panorama sees all around
  and walking forward is the usual capture;
* ``min_model_size = 2``, so two or three photos make a model;
* no intrinsics refinement (an equirectangular camera has none);
* one camera per image size (an equirectangular camera's parameters are its width and height).

COLMAP runs in a child process (:mod:`._colmap_worker`): where it aborts (a full temporary disk, a file-size limit)
the command still says so in one line and removes its temporary folder ``cylindersplat-sfm-*``, and
:func:`check_room` refuses to start when the room is plainly too small. Every panorama is checked first
(:func:`check_panoramas`): a regular file (no FIFO, symlink loop), a UTF-8 name, complete pixels.

pycolmap is an optional dependency (``pip install 'cylindersplat[sfm]'``); its absence is one
``ModuleNotFoundError`` line naming that command.
"""

from __future__ import annotations

import json
import os
import resource
import shutil
import signal
import stat
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["SFM_INSTALL", "SfmResult", "require_pycolmap", "check_panoramas", "panorama_sizes", "run_sfm",
           "EXHAUSTIVE_UP_TO", "observations"]

SFM_INSTALL = "pip install 'cylindersplat[sfm]'"
EXHAUSTIVE_UP_TO = 50  # matcher "auto": all pairs up to this many photos, else sequential (video frames)
# Room COLMAP's temporary database needs at least (a refusal only when plainly too small; an abort part-way is
# still one line): up to 8192 SIFT features of one panorama take about 1.2 MB, its matches far less.
ROOM_PER_PANORAMA = 2 * 2**20
ROOM_BASE = 16 * 2**20


def require_pycolmap():
    """The pycolmap module, or a ``ModuleNotFoundError`` whose one line says how to install it."""
    try:
        import pycolmap
    except ImportError as exc:
        raise ModuleNotFoundError(f"data poses needs pycolmap (COLMAP's Python bindings), which is not installed: "
                                  f"{SFM_INSTALL} (or pip install pycolmap)", name="pycolmap") from exc
    if not hasattr(pycolmap.CameraModelId, "EQUIRECTANGULAR"):
        raise ModuleNotFoundError(f"pycolmap {pycolmap.__version__} has no EQUIRECTANGULAR camera model, which data "
                                  f"poses needs: pip install -U 'pycolmap>=4.2'", name="pycolmap")
    return pycolmap


def _regular_file(path: Path) -> None:
    """Refuse what COLMAP cannot read or would hang on: a FIFO, device or folder named like an image, a symlink
    loop or a dangling link, a file name that is not UTF-8 (one line each)."""
    try:
        path.name.encode("utf-8")
    except UnicodeEncodeError:
        raise ValueError(f"{path.parent}: the file name {path.name!r} is not valid UTF-8, which COLMAP needs: rename "
                         "it (or move it out of the folder)") from None
    try:
        mode = os.stat(path).st_mode  # follows links: a loop or a dangling link fails here
    except OSError as exc:
        what = "a symlink loop" if exc.errno == 40 else f"unreadable ({exc.strerror})"
        raise ValueError(f"{path} is {what}: fix or remove it from the folder") from None
    if not stat.S_ISREG(mode):
        raise ValueError(f"{path} is not a regular file (a FIFO, device or folder named like an image): remove it "
                         "from the folder")


def panorama_sizes(images: list[Path]) -> dict[Path, tuple[int, int]]:
    """``(width, height)`` of each image, each checked to be a regular file that decodes completely (a truncated or
    empty PNG is one ``ValueError`` line naming it, not a panorama registered from half its pixels)."""
    from PIL import Image, UnidentifiedImageError

    sizes = {}
    for path in images:
        _regular_file(path)
        try:
            with Image.open(path) as image:
                image.load()  # decodes every pixel: a truncated file fails here
                sizes[path] = image.size
        except UnidentifiedImageError:
            empty = " (0 bytes)" if path.stat().st_size == 0 else ""
            raise ValueError(f"{path} is not an image file{empty}: fix or remove it from the folder") from None
        except (OSError, SyntaxError, ValueError, Image.DecompressionBombError) as exc:
            raise ValueError(f"{path} is damaged or truncated ({' '.join(str(exc).split())[:120]}): fix or remove it "
                             "from the folder") from None
    return sizes


def check_panoramas(images: list[Path], folder: Path) -> tuple[int, int]:
    """Refuse fewer than two images, non-2:1 ones and files that are no complete image (one line each, saying
    what to do); ``(H, W)`` of the first."""
    if not images:
        raise FileNotFoundError(f"no panoramas in {folder} (.jpg/.png/...; <stem>_depth.* files are depth)")
    if len(images) < 2:
        raise ValueError(f"only one panorama in {folder} ({images[0].name}): poses need at least two overlapping "
                         "panoramas (a single one is at the origin: write its poses.json by hand, identity c2w)")
    sizes = panorama_sizes(images)
    for path, (width, height) in sizes.items():
        if width != 2 * height:
            raise ValueError(f"{path} is {width}x{height}, not an equirectangular 360° panorama (width = 2 x height); "
                             "data poses reconstructs 360° panoramas only: for perspective photos run COLMAP itself")
    width, height = sizes[images[0]]
    return height, width


def check_room(count: int, work_root: str | None = None) -> None:
    """Refuse to start when the temporary folder's disk or the file-size limit (``ulimit -f``) leaves too little
    room for COLMAP's database of ``count`` panoramas (COLMAP would abort part-way)."""
    root = work_root or tempfile.gettempdir()
    need = ROOM_BASE + ROOM_PER_PANORAMA * count
    free = shutil.disk_usage(root).free
    if free < need:
        raise ValueError(f"the temporary folder {root} has {free / 2**20:.0f} MB free; structure from motion on "
                         f"{count} panoramas needs about {need / 2**20:.0f} MB there: free space or set TMPDIR to a "
                         "folder on a disk with room")
    limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    if limit != resource.RLIM_INFINITY and limit < need:
        raise ValueError(f"the file-size limit (ulimit -f) is {limit / 2**20:.1f} MB; structure from motion on {count} "
                         f"panoramas writes a database of about {need / 2**20:.0f} MB: raise the limit (ulimit -f "
                         "unlimited)")


@dataclass
class SfmResult:
    """The largest model: its image names with ``cam_from_world`` (4x4, model units), the names not in it, and
    figures. ``reconstruction`` is the pycolmap object (for scale estimation and writing); ``others`` names the
    images of other, disconnected models."""

    reconstruction: object
    c2w: dict[str, np.ndarray]
    unregistered: list[str]
    others: list[list[str]] = field(default_factory=list)
    points: int = 0
    reprojection_error: float = float("nan")
    matcher: str = "exhaustive"
    seconds: float = 0.0


def _stderr(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _quiet_colmap(pycolmap) -> None:
    """COLMAP logs every step on stderr (INFO, and WARNING/ERROR lines for what our own one-line errors say
    better); our own lines say the progress. Its fatal errors still show."""
    try:
        pycolmap.logging.minloglevel = 3
    except AttributeError:  # older pycolmap: leave its logging as it is
        pass


def run_sfm(images: list[Path], folder: Path, matcher: str = "auto", threads: int | None = None,
            progress: Callable[[str], None] = _stderr, seed: int = 0) -> SfmResult:
    """SfM on ``images`` (files in ``folder``): COLMAP with an equirectangular camera (module docstring).

    ``matcher``: ``"exhaustive"`` (all pairs), ``"sequential"`` (each photo with its 10 neighbours in name order and
    loop detection off: video frames), ``"auto"`` (exhaustive up to :data:`EXHAUSTIVE_UP_TO` photos). Fewer than two
    registered images is a ``ValueError`` naming the images and what to try. Nothing is written outside a
    temporary folder (the database); the caller writes the results.
    """
    from PIL import Image

    pycolmap = require_pycolmap()
    _quiet_colmap(pycolmap)
    if matcher not in ("auto", "exhaustive", "sequential"):
        raise ValueError(f"matcher must be auto, exhaustive or sequential, got {matcher!r}")
    if matcher == "auto":
        matcher = "exhaustive" if len(images) <= EXHAUSTIVE_UP_TO else "sequential"
    threads = threads or max(1, min(os.cpu_count() or 1, 8))
    names = [p.relative_to(folder).as_posix() for p in images]
    groups: dict[tuple[int, int], list[str]] = {}  # (width, height) -> names: one camera per image size
    for path, name in zip(images, names):
        _regular_file(path)
        with Image.open(path) as image:
            groups.setdefault(image.size, []).append(name)
    check_room(len(names))
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="cylindersplat-sfm-") as work:
        job = {"work": work, "folder": str(folder), "groups": [[w, h, group] for (w, h), group in groups.items()],
               "matcher": matcher, "threads": threads, "seed": seed}
        sizes = "" if len(groups) == 1 else f", one camera per size: {_size_mix(groups)}"
        progress(f"sfm: features of {len(names)} panoramas (SIFT, equirectangular camera{sizes})")
        _run_worker(Path(work), job, progress, start)
        out = Path(work) / "sparse"
        models = [pycolmap.Reconstruction(str(d)) for d in sorted(out.iterdir()) if d.is_dir()] if out.is_dir() else []
    seconds = time.perf_counter() - start
    models = sorted(models, key=lambda r: r.num_reg_images(), reverse=True)
    registered = _registered(models[0]) if models else {}
    if len(registered) < 2:
        raise ValueError(_too_few(names, registered, folder, groups))
    others = [sorted(_registered(m)) for m in models[1:]]
    in_model = set(registered)
    unregistered = [n for n in names if n not in in_model]
    rec = models[0]
    return SfmResult(rec, registered, unregistered, others, rec.num_points3D(),
                     float(rec.compute_mean_reprojection_error()), matcher, seconds)


def _size_mix(groups: dict[tuple[int, int], list[str]]) -> str:
    return ", ".join(f"{len(names)} of {w}x{h}" for (w, h), names in sorted(groups.items(), key=lambda g: -len(g[1])))


def _run_worker(work: Path, job: dict, progress: Callable[[str], None], start: float) -> None:
    """COLMAP's steps in a child process (:mod:`._colmap_worker`): its progress lines are passed on; a Python
    error there, or an abort (full disk, file-size limit), is one ``ValueError`` line naming the step."""
    (work / "job.json").write_text(json.dumps(job))
    log = work / "colmap.log"
    stage, error = "starting COLMAP", None
    worker = Path(__file__).with_name("_colmap_worker.py")
    with open(log, "wb") as stderr:
        child = subprocess.Popen([sys.executable, str(worker), str(work / "job.json")], stdout=subprocess.PIPE,
                                 stderr=stderr, text=True, errors="replace")
        try:
            for line in child.stdout:
                line = line.rstrip("\n")
                if line.startswith("stage: "):
                    stage = line[len("stage: "):]
                    if not stage.startswith(("extracting", "done")):
                        progress(f"sfm: {stage} [{time.perf_counter() - start:.1f} s]")
                elif line.startswith("error: "):
                    error = line[len("error: "):]
            code = child.wait()
        finally:
            if child.poll() is None:  # Ctrl-C or an error here: the child must not outlive us
                child.kill()
                child.wait()
    if code == 0:
        return
    if code < 0:
        try:
            name = signal.Signals(-code).name
        except ValueError:
            name = f"signal {-code}"
        what = f"COLMAP stopped with {name}"
    else:
        what = f"COLMAP failed ({error})" if error else f"COLMAP exited with status {code}"
    detail = _last_colmap_error(log)
    raise ValueError(f"structure from motion failed while {stage}: {what}{detail}; is the disk of the temporary "
                     f"folder {tempfile.gettempdir()} full or a file-size limit (ulimit -f) reached? free space, set "
                     "TMPDIR to a disk with room or raise the limit")


def _last_colmap_error(log: Path) -> str:
    """`` (COLMAP: <its last check or error line>)`` from the child's stderr, or ``""``."""
    try:
        lines = [line.strip() for line in log.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        return ""
    for line in reversed(lines):
        if "Check failed" in line or line.startswith(("E", "F")) and "]" in line:
            return f" (COLMAP: {line.split('] ', 1)[-1][:160]})"
    return ""


def _registered(rec) -> dict[str, np.ndarray]:
    out = {}
    for image in rec.images.values():
        if image.has_pose:
            w2c = np.eye(4)
            w2c[:3] = image.cam_from_world().matrix()
            out[image.name] = np.linalg.inv(w2c)
    return out


def _too_few(names: list[str], registered: dict, folder: Path, groups: dict | None = None) -> str:
    placed = (f"only {', '.join(sorted(registered))} could be placed" if registered
              else "no two could be placed together")
    shown = ", ".join(names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")
    if groups is not None and len(groups) > 1:
        return (f"structure from motion failed on the {len(names)} panoramas of {folder} ({shown}): {placed}; they "
                f"come in {len(groups)} sizes ({_size_mix(groups)}), and panoramas of different sizes match poorly: "
                "resize them to one size (e.g. the largest), or give poses from another tool (data import-poses)")
    return (f"structure from motion failed on the {len(names)} panoramas of {folder} ({shown}): {placed}; they share "
            "too few matching features (no overlap, or textureless walls): take panoramas closer together (1-2 m "
            "indoors, each seeing what the previous one saw), or give poses from another tool (data import-poses)")


def observations(rec) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Per registered image of a pycolmap reconstruction: ``(xy (P, 2), xyz (P, 3))``, the pixel of each keypoint
    that has a 3-D point (COLMAP pixel coordinates: top-left corner at 0) and that point (model units)."""
    out = {}
    for image in rec.images.values():
        if not image.has_pose:
            continue
        xy, xyz = [], []
        for point in image.points2D:
            if point.has_point3D():
                xy.append(point.xy)
                xyz.append(rec.points3D[point.point3D_id].xyz)
        out[image.name] = (np.array(xy, dtype=np.float64).reshape(-1, 2),
                           np.array(xyz, dtype=np.float64).reshape(-1, 3))
    return out
