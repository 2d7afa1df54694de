"""Every splat file format by its name: ``save_gaussians`` / ``load_gaussians``.

* ``.ply`` (standard 3DGS PLY, all SH) and ``.splat`` (32 bytes per Gaussian) are written and read here
  (:mod:`.ply`, :mod:`.splat`);
* ``.spz`` (Niantic's compressed format), ``.compressed.ply`` (PlayCanvas / SuperSplat's chunked
  quantised PLY) and ``.sog`` (PlayCanvas's WebP-texture bundle) go through PlayCanvas
  **splat-transform**, a maintained converter from the npm registry (Node.js): we hand it our standard
  PLY and it writes the format (its ``.spz`` writer is Niantic's reference encoder compiled to
  WebAssembly). Reading those formats (and ``.ksplat``) converts them back to a standard PLY the same
  way. No encoder for these formats is written here.

:func:`load_gaussians` is the one reader of every format: every command that takes a splat file (``view``,
``render --ply``) goes through it.

splat-transform is found through ``$CYLINDERSPLAT_SPLAT_TRANSFORM`` (its executable, or a command such
as ``npx @playcanvas/splat-transform``), then ``splat-transform`` on ``PATH``, then ``.tools/bin/splat-transform``
in the clone of an editable install (where ``bash scripts/install_optional.sh formats`` puts it), then
``~/.local/bin/splat-transform`` (where it put it before).
Coordinates are written as they are (OpenCV world frame of the poses, no axis flip): splat-transform
stores ``.spz`` with the coordinate system "unspecified" and converts nothing in either direction.

splat-transform runs with a timeout proportionate to the work (:func:`splat_transform_timeout`: at least
:data:`MIN_TIMEOUT_S`, more for more Gaussians or a larger file); ``$CYLINDERSPLAT_SPLAT_TRANSFORM_TIMEOUT``
(seconds) sets it. A run past it is ended (with anything it started) and reported in one line.
"""

from __future__ import annotations

import math
import os
import shlex
import shutil
import signal
import subprocess
import tempfile
from pathlib import Path

import torch

from ..utils.atomic import atomic_path, written_at_once
from .container import Gaussians
from .ply import load_ply, save_ply
from .splat import load_splat, save_splat

__all__ = [
    "SPLAT_TRANSFORM_ENV", "SPLAT_TRANSFORM_INSTALL", "TIMEOUT_ENV", "SplatTransformError", "splat_transform_timeout",
    "WRITE_FORMATS", "READ_FORMATS",
    "splat_format", "find_splat_transform", "require_splat_transform", "save_gaussians", "load_gaussians",
]

SPLAT_TRANSFORM_ENV = "CYLINDERSPLAT_SPLAT_TRANSFORM"
SPLAT_TRANSFORM_PACKAGE = "@playcanvas/splat-transform@3"
TIMEOUT_ENV = "CYLINDERSPLAT_SPLAT_TRANSFORM_TIMEOUT"
# scripts/install_optional.sh's default prefix: the clone's own folder (src/cylindersplat/gaussians -> the clone)
PROJECT_TOOLS = Path(__file__).resolve().parents[3] / ".tools"
# About ten times the measured rates (200k Gaussians on 2 busy cores: .sog written in 3.7 s, its k-means on the
# CPU being the slowest path; .spz 0.9 s; any 3 MB file read in 0.6 s), so that only a hung tool reaches them;
# a floor for Node.js start-up on a busy machine.
MIN_TIMEOUT_S = 120.0
SECONDS_PER_GAUSSIAN = 2e-4  # writing: 200 s more per million Gaussians
SECONDS_PER_BYTE = 1e-5  # reading: 10 s more per MB of file
SPLAT_TRANSFORM_INSTALL = ("install PlayCanvas splat-transform (Node.js >= 20): `bash scripts/install_optional.sh "
                           f"formats` (into the clone's .tools/) or `npm install -g {SPLAT_TRANSFORM_PACKAGE}`, or set "
                           f"{SPLAT_TRANSFORM_ENV} to its executable")

#: Output formats -> what they are. The last three need splat-transform.
WRITE_FORMATS = {
    ".ply": "standard 3DGS PLY, all SH coefficients",
    ".splat": "antimatter15 .splat, 32 bytes per Gaussian, degree-0 colour",
    ".compressed.ply": "PlayCanvas/SuperSplat compressed PLY (chunks of 256, 16 bytes per Gaussian + SH)",
    ".spz": "Niantic SPZ (quantised, zstd/gzip)",
    ".sog": "PlayCanvas SOG (WebP textures, k-means codebooks)",
}
#: Input formats (the PLY and .splat are read here, the others through splat-transform).
READ_FORMATS = (".ply", ".compressed.ply", ".spz", ".sog", ".splat", ".ksplat")


class SplatTransformError(ValueError):
    """splat-transform ran and failed (its last message is in the text)."""


def splat_format(path: str | Path, formats=tuple(WRITE_FORMATS)) -> str:
    """The format of ``path`` by its name (``.compressed.ply`` before ``.ply``); ``ValueError`` if none fits."""
    name = Path(path).name.lower()
    for fmt in sorted(formats, key=len, reverse=True):
        if name.endswith(fmt) and len(name) > len(fmt):
            return fmt
    raise ValueError(f"{path}: unknown splat format; use a name ending in {', '.join(formats)}")


def find_splat_transform() -> list[str] | None:
    """The command that runs splat-transform here, or ``None`` (see the module docstring)."""
    env = os.environ.get(SPLAT_TRANSFORM_ENV, "").strip()
    if env:
        return shlex.split(env)
    for candidate in (shutil.which("splat-transform"), PROJECT_TOOLS / "bin" / "splat-transform",
                      Path.home() / ".local" / "bin" / "splat-transform"):
        if candidate and os.access(candidate, os.X_OK) and Path(candidate).is_file():
            return [str(candidate)]
    return None


def require_splat_transform(what: str) -> list[str]:
    command = find_splat_transform()
    if command is None:
        raise FileNotFoundError(f"{what} needs splat-transform, which is not installed; {SPLAT_TRANSFORM_INSTALL}")
    return command


def splat_transform_timeout(gaussians: int = 0, nbytes: int = 0) -> float:
    """Seconds splat-transform may take to write ``gaussians`` Gaussians or read a file of ``nbytes``:
    ``$CYLINDERSPLAT_SPLAT_TRANSFORM_TIMEOUT`` if set, else :data:`MIN_TIMEOUT_S` plus the work's share."""
    given = os.environ.get(TIMEOUT_ENV, "").strip()
    if given:
        try:
            seconds = float(given)
        except ValueError:
            seconds = math.nan
        if not math.isfinite(seconds) or seconds <= 0:
            raise ValueError(f"{TIMEOUT_ENV}={given!r}: give splat-transform's timeout in seconds, e.g. 600")
        return seconds
    return MIN_TIMEOUT_S + gaussians * SECONDS_PER_GAUSSIAN + nbytes * SECONDS_PER_BYTE


def _run(tool: list[str], arguments: list[str], timeout: float, what: str) -> None:
    """Run splat-transform (``tool``, :func:`find_splat_transform`) with ``arguments`` for ``what`` (e.g.
    "writing 1,000 Gaussians to x.spz") within ``timeout`` seconds."""
    command = [*tool, *arguments]
    try:
        # its own session: a timeout ends everything it started (npx runs node as a child, which holds the pipes)
        proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                                text=True, start_new_session=True)
    except FileNotFoundError:
        raise FileNotFoundError(f"cannot run {command[0]!r}; {SPLAT_TRANSFORM_INSTALL}") from None
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        _kill_group(proc)
        raise SplatTransformError(
            f"splat-transform did not finish {what} within {timeout:.0f} s and was stopped; if it is merely slow, "
            f"allow more time ({TIMEOUT_ENV}=SECONDS), else check that `{shlex.join(tool)} --help` answers") from None
    except BaseException:  # Ctrl-C: no converter left running behind us
        _kill_group(proc)
        raise
    if proc.returncode != 0:
        lines = [line.strip() for line in (stderr + stdout).splitlines() if line.strip()]
        detail = next((line for line in reversed(lines) if "error" in line.lower()),
                      lines[-1] if lines else "no output")
        raise SplatTransformError(f"splat-transform failed (exit {proc.returncode}): {detail[:300]}")


def _kill_group(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except OSError:  # already gone
        pass
    proc.communicate()


def save_gaussians(gaussians: Gaussians, path: str | Path, spz_version: int | None = None) -> Path:
    """Write unbatched ``gaussians`` in the format named by ``path`` (:data:`WRITE_FORMATS`); atomic.

    ``spz_version`` (3 or 4, default: splat-transform's, 4) picks the SPZ version; 3 is the older
    gzip container, for readers that predate version 4.
    """
    path = Path(path)
    fmt = splat_format(path)
    if fmt == ".ply":
        return save_ply(gaussians, path)
    if fmt == ".splat":
        return save_splat(gaussians, path)
    command = require_splat_transform(f"writing {fmt}")
    if gaussians.batch_shape:
        raise ValueError(f"save_gaussians takes unbatched Gaussians, got batch shape {tuple(gaussians.batch_shape)}")
    options = ["--quiet", "--overwrite"]
    if spz_version is not None:
        if spz_version not in (3, 4):
            raise ValueError(f"spz_version must be 3 or 4, got {spz_version}")
        options += ["--spz-version", str(spz_version)]
    if fmt == ".sog":
        # SOG's k-means runs on a WebGPU adapter by default and fails without one; the CPU path works everywhere.
        options += ["--gpu", "cpu"]
    with atomic_path(path) as tmp, tempfile.TemporaryDirectory(prefix=f".{path.name}.", dir=path.parent) as work:
        # splat-transform picks the format by the output's name, so it writes `<work>/<name>`, which then
        # takes the place of atomic_path's temporary file (same folder: plain renames throughout).
        source, target = Path(work) / "in.ply", Path(work) / path.name
        with written_at_once():  # the converter's input, read at once: not held back with a command's output set
            save_ply(gaussians, source)
        _run(command, [*options, str(source), str(target)], splat_transform_timeout(gaussians=len(gaussians)),
             f"writing {len(gaussians):,} Gaussians to {path.name}")
        if not target.is_file():
            raise SplatTransformError(f"splat-transform reported success but wrote no {target.name}")
        os.replace(target, tmp)
    return path


def _looks_compressed_ply(path: Path) -> bool:
    with open(path, "rb") as f:
        header = f.read(4096)
    return b"element chunk" in header and b"packed_position" in header


def load_gaussians(path: str | Path, device=None, dtype=torch.float32) -> Gaussians:
    """Read any of :data:`READ_FORMATS` (a compressed PLY is recognised by its header too)."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path} is a folder, not a splat file ({', '.join(READ_FORMATS)})")
    if not path.is_file():
        raise FileNotFoundError(f"splat file not found: {path}")
    fmt = splat_format(path, READ_FORMATS)
    if fmt == ".ply" and not _looks_compressed_ply(path):
        return load_ply(path, device=device, dtype=dtype)
    if fmt == ".splat":
        return load_splat(path, device=device, dtype=dtype)
    command = require_splat_transform(f"reading {path.name}")
    with tempfile.TemporaryDirectory(prefix="cylindersplat-") as work:
        source = Path(work) / ("in" + (".compressed.ply" if fmt == ".ply" else fmt))
        try:
            os.symlink(path.resolve(), source)
        except OSError:
            shutil.copyfile(path, source)
        target = Path(work) / "out.ply"
        _run(command, ["--quiet", str(source), str(target)], splat_transform_timeout(nbytes=path.stat().st_size),
             f"reading {path.name}")
        return load_ply(_saturated_to_finite(target), device=device, dtype=dtype)


def _saturated_to_finite(path: Path) -> Path:
    """Quantised formats store opacity 1 (and 0) exactly, which splat-transform writes as an infinite
    logit (and a zero scale as ``-inf`` log); :func:`load_ply` refuses non-finite values, so these
    become logits/logs of +-30 (opacity 1 - 1e-13, scale 1e-13 m). NaN stays NaN (and is refused)."""
    import numpy as np
    from plyfile import PlyData

    ply = PlyData.read(str(path))
    data = ply["vertex"].data
    names = set(data.dtype.names or ())
    changed = False
    for name in ("opacity", "scale_0", "scale_1", "scale_2"):
        if name in names:
            column = data[name]
            infinite = np.isinf(column) if name == "opacity" else np.isneginf(column)
            if infinite.any():
                column[infinite] = np.sign(column[infinite]) * 30.0
                changed = True
    if not changed:
        return path
    finite = path.with_name(path.stem + ".finite.ply")  # not over the memory-mapped original
    ply.write(str(finite))
    return finite
