"""Run a depth network once over a dataset and store its depth as prior files (``cylindersplat data priors``).

For a dataset opened at ``ROOT`` and a prior named ``NAME`` the files go to
``ROOT/priors/NAME/<panorama path relative to ROOT, suffix .png or .npy>`` (or to ``--out DIR``),
next to ``prior.json``: the network spec, what identifies it (file SHA-256, package version), the
resolution, the file format and the date. :class:`~.files.FilePrior` (``file:NAME`` / ``file:DIR``)
reads exactly these files. A second run skips every frame whose file exists when ``prior.json``
matches the network and settings, and refuses a tree made by another network unless ``overwrite``.

Nothing the user had is lost: a tree that would hold the dataset (``--out DATA``: the prior files would take the
panoramas' names) is refused, ``--overwrite`` included; a run that replaces existing prior files writes the new
tree beside them and swaps it in only when whole (:func:`~cylindersplat.utils.atomic.output_set`), so a failure
part-way (a full disk, a file-size limit) leaves the earlier tree as it was. A run that only adds files keeps
those it finished (the next run resumes from them).
"""

from __future__ import annotations

import contextlib
import json
import os
import warnings
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import torch
from tqdm.auto import tqdm

from ...dataset_layouts import DATASET_LAYOUTS, dataset_spec, detect_layout, layout_name
from ...utils.atomic import atomic_path, atomic_write_text, output_set
from ..io import DEPTH_PNG_SCALE, read_rgb, write_depth_png
from .files import SIDECAR, check_prior_name, prior_tree, read_sidecar, tree_file
from .registry import parse_network_prior

__all__ = ["LAYOUTS", "detect_layout", "prior_frames", "write_priors", "PriorRun"]

LAYOUTS = DATASET_LAYOUTS  # the registry's names (dataset_layouts.py)
_PNG_MAX_METRES = 65535 / DEPTH_PNG_SCALE


@dataclass
class PriorRun:
    tree: Path  # where the files are
    frames: int  # panoramas of the dataset
    written: int
    skipped: int  # already there (same network and settings)
    seconds: float


def prior_frames(data: str | Path, layout: str = "auto", split: str = "all"
                 ) -> tuple[Path, list[tuple[Path, str]], str]:
    """``(dataset root, [(panorama path, key)], layout)``: every panorama of a dataset, once (its spec's
    ``frames``; ``split`` is ``all`` or a split name of layouts that have splits)."""
    data = Path(data)
    layout = detect_layout(data) if layout == "auto" else layout_name(layout)
    dataset = dataset_spec(layout).frames(data, split)
    return Path(dataset.data_root), [(Path(f.rgb), key) for f, key in dataset.frames()], layout


def _inside(path: Path, folder: Path) -> bool:
    """Whether ``path`` is ``folder`` or lies in it, links followed (``realpath``: a symlink loop does not raise)."""
    path, folder = Path(os.path.realpath(path)), Path(os.path.realpath(folder))
    return path == folder or folder in path.parents


def _check_tree(tree: Path, root: Path, targets: list[tuple[Path, str, Path]]) -> None:
    """Refuse a prior tree whose files would replace the dataset's own (``--out DATA`` or a folder above it, or a
    link that leads there), ``--overwrite`` or not."""
    if _inside(root, tree):
        raise ValueError(f"--out {tree} holds the dataset {root}: prior files named like its panoramas would "
                         "replace them; give a folder outside it (default: DATA/priors/NAME with --name)")
    inputs = {os.path.realpath(rgb) for rgb, _, _ in targets}
    clash = next((path for _, _, path in targets if os.path.realpath(path) in inputs), None)
    if clash is not None:
        raise ValueError(f"the prior file {clash} would replace a panorama of the dataset {root}: give another "
                         "--out or --name")


def _same_network(old: dict, new: dict) -> bool:
    """Same identity (weights' checksum or hub id, package version, options) and same output settings."""
    def identity(record):
        net = dict(record.get("identity") or {})
        if net.get("sha256"):
            net.pop("weights", None)  # the same file moved elsewhere is the same network
        return net, record.get("format"), record.get("resolution"), record.get("scale")

    return identity(old) == identity(new)


def write_priors(
    data: str | Path,
    net: str,
    name: str | None = None,
    out: str | Path | None = None,
    layout: str = "auto",
    split: str = "all",
    file_format: str = "png",
    resolution: tuple[int, int] | None = None,
    batch_size: int = 4,
    device: str = "cpu",
    overwrite: bool = False,
    progress: bool = True,
    net_size: tuple[int, int] | None = None,
) -> PriorRun:
    """Run the network ``net`` (a spec: ``exported:NET.pt2``, ``unik3d:DIR``, ``depth_anything_v2:MODEL``)
    over every panorama of ``data`` and store its radial depth (see the module docstring).

    ``file_format``: ``png`` (16-bit millimetres, 0 = unknown; depth beyond 65.535 m is stored as 0)
    or ``npy`` (float32 metres). ``resolution`` ``(H, W)``: the size the network sees and the files
    have (default: each panorama's stored size). ``net_size`` ``(h, w)``: the size an ``exported:``
    network runs at (input resized, output resized back), for networks exported with fixed shapes.
    """
    from ... import __version__

    if file_format not in ("png", "npy"):
        raise ValueError(f"prior file format must be png or npy, got {file_format!r}")
    if batch_size < 1:
        raise ValueError(f"--batch-size must be >= 1, got {batch_size}")
    if name is None and out is None:
        raise ValueError("give the prior a --name (files go to DATA/priors/NAME) or an --out folder")
    if name is not None:
        check_prior_name(name)  # before any work: a name must not lead out of DATA/priors/
    root, frames, layout = prior_frames(data, layout, split)
    tree = Path(out) if out is not None else prior_tree(root, name)
    name = name or tree.name
    if not frames:
        raise ValueError(f"{data}: no panoramas found")
    suffix = f".{file_format}"
    targets = [(rgb, key, tree_file(tree, rgb, root, suffix)) for rgb, key in frames]
    if len({t[2] for t in targets}) != len(targets):
        raise ValueError(f"{data}: two panoramas differ only in their suffix and would share a prior file")
    _check_tree(tree, Path(root), targets)
    options = {}
    if net_size is not None:
        if not net.startswith("exported:"):
            raise ValueError("--net-size is for exported networks (UniK3D and Depth Anything V2 resize by themselves)")
        options["input_size"] = tuple(net_size)
    network = parse_network_prior(net, device=device, **options)
    record = {
        "name": name, "network": net, "identity": network.describe(), "format": file_format,
        "scale": DEPTH_PNG_SCALE if file_format == "png" else 1.0,  # file units per metre
        "resolution": list(resolution) if resolution is not None else None,
        "depth": "radial distance along each pixel's ray (metres), 0 = unknown",
        "layout": layout, "dataset": str(Path(root).resolve()), "frames": len(frames),
        "cylindersplat": __version__, "created": datetime.now(timezone.utc).isoformat(timespec="seconds"),
        "complete": False,
    }
    existing = read_sidecar(tree)
    has_files = tree.is_dir() and any(p.suffix in (".png", ".npy") and p.is_file() for p in tree.rglob("*"))
    if not has_files:
        existing = None  # a sidecar alone (a run that failed before its first file) holds nothing to keep
    if existing is not None and not overwrite and not _same_network(existing, record):
        size = existing.get("resolution")
        raise ValueError(f"{tree} holds priors of another network or settings ({existing.get('network')}, "
                         f"{existing.get('format')}, {'x'.join(map(str, size)) if size else 'stored size'}); pass "
                         "--overwrite to replace them or choose another --name")
    if existing is None and not overwrite and has_files:
        raise ValueError(f"{tree} holds prior files without {SIDECAR} (not written by `cylindersplat data priors`); "
                         "pass --overwrite to replace them or choose another --name")
    resume = existing is not None and not overwrite
    pending = [t for t in targets if not (resume and t[2].is_file())]
    if resume:
        record["created"] = existing.get("created", record["created"])
    # Replacing files: the new tree is written beside the earlier one and swapped in whole (a failure keeps it).
    replacing = any(path.exists() for _, _, path in pending)
    with output_set(tree, planned=[path for _, _, path in pending]) if replacing else contextlib.nullcontext():
        run = _write(network, net, name, tree, record, pending, batch_size, resolution, file_format, progress)
    return PriorRun(tree, len(frames), len(pending), len(targets) - len(pending), run)


def _write(network, net: str, name: str, tree: Path, record: dict, pending: list[tuple[Path, str, Path]],
           batch_size: int, resolution: tuple[int, int] | None, file_format: str, progress: bool) -> float:
    """Write the sidecar (``complete: false``), every pending frame's prior file and the finished sidecar;
    returns the seconds taken."""
    import time

    atomic_write_text(tree / SIDECAR, json.dumps(record, indent=1))

    start = time.perf_counter()
    clipped = 0
    bar = tqdm(total=len(pending), desc=f"priors {name}", unit="pano", disable=None if progress else True)
    batch: list[tuple[torch.Tensor, Path, Path]] = []

    def flush():
        nonlocal clipped
        if not batch:
            return
        depths = network.predict_batch(torch.stack([image for image, _, _ in batch]))
        for (image, rgb, path), depth in zip(batch, depths):
            if tuple(depth.shape) != tuple(image.shape[-2:]):
                raise ValueError(f"network {net} returned {tuple(depth.shape)} for {rgb}, "
                                 f"expected {tuple(image.shape[-2:])}")
            if not bool((depth > 0).any()):
                raise ValueError(f"network {net} gave no positive depth for {rgb} (all zeros/negative): check its "
                                 "output convention (depth, inverse_depth, log_depth) and scale")
            if file_format == "png":
                clipped += int((depth >= _PNG_MAX_METRES).sum())
                write_depth_png(path, depth)
            else:
                with atomic_path(path) as tmp:
                    np.save(tmp, depth.numpy().astype(np.float32))
        bar.update(len(batch))
        batch.clear()

    for rgb, _, path in pending:
        image = read_rgb(rgb, size=resolution)
        if batch and batch[0][0].shape != image.shape:
            flush()
        batch.append((image, rgb, path))
        if len(batch) >= batch_size:
            flush()
    flush()
    bar.close()
    if clipped:
        warnings.warn(f"{clipped} pixels lie beyond {_PNG_MAX_METRES:.3f} m, the 16-bit PNG range, and were stored "
                      "as 0 (unknown); use --format npy to keep them", stacklevel=3)
    record.update(complete=True, finished=datetime.now(timezone.utc).isoformat(timespec="seconds"))
    atomic_write_text(tree / SIDECAR, json.dumps(record, indent=1))
    return time.perf_counter() - start
