"""Poses of unposed 360° panoramas by structure from motion: COLMAP through pycolmap, equirectangular camera.

:func:`run_sfm` extracts SIFT features on the panoramas as they are (COLMAP's ``EQUIRECTANGULAR`` model maps a
pixel to a ray exactly as :mod:`cylindersplat.geometry` does, so no cube faces are cut), matches them (all pairs for
a handful of photos, neighbours in name order for video frames) and runs COLMAP's incremental mapper with options
for panorama walks:

* ``init_max_forward_motion = 1``: COLMAP's default 0.95 rejects an initial pair whose motion is along the
  optical axis, which for a perspective camera means a poor triangulation angle, but a panorama sees all around
  and walking forward is the usual capture;
* ``min_model_size = 2``, so two or three photos make a model;
* no intrinsics refinement (an equirectangular camera has none).

pycolmap is an optional dependency (``pip install 'cylindersplat[sfm]'``); its absence is one
``ModuleNotFoundError`` line naming that command.
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

__all__ = ["SFM_INSTALL", "SfmResult", "require_pycolmap", "check_panoramas", "run_sfm", "EXHAUSTIVE_UP_TO", "observations"]

SFM_INSTALL = "pip install 'cylindersplat[sfm]'"
EXHAUSTIVE_UP_TO = 50  # matcher "auto": all pairs up to this many photos, else sequential (video frames)


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


def check_panoramas(images: list[Path], folder: Path) -> tuple[int, int]:
    """Refuse fewer than two images and non-2:1 ones (one line each, saying what to do); ``(H, W)`` of the first."""
    from PIL import Image

    if not images:
        raise FileNotFoundError(f"no panoramas in {folder} (.jpg/.png/...; <stem>_depth.* files are depth)")
    if len(images) < 2:
        raise ValueError(f"only one panorama in {folder} ({images[0].name}): poses need at least two overlapping "
                         "panoramas (a single one is at the origin: write its poses.json by hand, identity c2w)")
    size = None
    for path in images:
        with Image.open(path) as image:
            width, height = image.size
        if width != 2 * height:
            raise ValueError(f"{path} is {width}x{height}, not an equirectangular 360° panorama (width = 2 x height); "
                             "data poses reconstructs 360° panoramas only: for perspective photos run COLMAP itself")
        size = size or (height, width)
    return size


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
    pycolmap = require_pycolmap()
    _quiet_colmap(pycolmap)
    if matcher not in ("auto", "exhaustive", "sequential"):
        raise ValueError(f"matcher must be auto, exhaustive or sequential, got {matcher!r}")
    if matcher == "auto":
        matcher = "exhaustive" if len(images) <= EXHAUSTIVE_UP_TO else "sequential"
    threads = threads or max(1, min(os.cpu_count() or 1, 8))
    names = [p.relative_to(folder).as_posix() for p in images]
    start = time.perf_counter()
    pycolmap.set_random_seed(seed)
    with tempfile.TemporaryDirectory(prefix="cylindersplat-sfm-") as work:
        database = Path(work) / "database.db"
        progress(f"sfm: features of {len(names)} panoramas (SIFT, equirectangular camera)")
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = "EQUIRECTANGULAR"
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.num_threads = threads
        pycolmap.extract_features(database, folder, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
        progress(f"sfm: matching ({matcher}) [{time.perf_counter() - start:.1f} s]")
        matching = pycolmap.FeatureMatchingOptions()
        matching.num_threads = threads
        if matcher == "exhaustive":
            pycolmap.match_exhaustive(database, matching_options=matching, device=pycolmap.Device.cpu)
        else:
            pycolmap.match_sequential(database, matching_options=matching, device=pycolmap.Device.cpu)
        progress(f"sfm: incremental mapping [{time.perf_counter() - start:.1f} s]")
        options = pycolmap.IncrementalPipelineOptions()
        options.mapper.init_max_forward_motion = 1.0  # a panorama walk moves along the "optical axis": fine here
        options.min_model_size = 2
        options.num_threads = threads
        options.ba_refine_focal_length = options.ba_refine_principal_point = options.ba_refine_extra_params = False
        out = Path(work) / "sparse"
        out.mkdir()
        models = pycolmap.incremental_mapping(database, folder, out, options)
    seconds = time.perf_counter() - start
    models = sorted(models.values(), key=lambda r: r.num_reg_images(), reverse=True)
    registered = _registered(models[0]) if models else {}
    if len(registered) < 2:
        raise ValueError(_too_few(names, registered, folder))
    others = [sorted(_registered(m)) for m in models[1:]]
    in_model = set(registered)
    unregistered = [n for n in names if n not in in_model]
    rec = models[0]
    return SfmResult(rec, registered, unregistered, others, rec.num_points3D(), float(rec.compute_mean_reprojection_error()),
                     matcher, seconds)


def _registered(rec) -> dict[str, np.ndarray]:
    out = {}
    for image in rec.images.values():
        if image.has_pose:
            w2c = np.eye(4)
            w2c[:3] = image.cam_from_world().matrix()
            out[image.name] = np.linalg.inv(w2c)
    return out


def _too_few(names: list[str], registered: dict, folder: Path) -> str:
    placed = f"only {', '.join(sorted(registered))} could be placed" if registered else "no two could be placed together"
    shown = ", ".join(names[:8]) + (f" and {len(names) - 8} more" if len(names) > 8 else "")
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
        out[image.name] = (np.array(xy, dtype=np.float64).reshape(-1, 2), np.array(xyz, dtype=np.float64).reshape(-1, 3))
    return out
