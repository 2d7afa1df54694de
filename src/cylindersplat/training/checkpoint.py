"""Training checkpoints: inference weights (safetensors) + full resume state.

Layout under ``<output_dir>/checkpoints/``::

    step_0001500/model.safetensors   # cylindersplat.model.save_model: weights + model config
    step_0001500/state.pt            # optimizer, scheduler, curriculum position, RNG states, config
    latest                           # text file: name of the newest complete checkpoint folder

The ``latest`` pointer is written last, so a crash while saving leaves the previous one valid.
"""

from __future__ import annotations

import io
import random
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ..model import CylinderSplat, save_model
from ..utils.atomic import atomic_write_bytes, atomic_write_text

__all__ = ["capture_rng", "restore_rng", "save_checkpoint", "resolve_checkpoint", "read_state", "prune_checkpoints"]

MODEL_FILE = "model.safetensors"
STATE_FILE = "state.pt"
STATE_KEYS = ("stages", "global_step", "stage_index", "stage_step", "optimizer", "scheduler", "rng")


def capture_rng() -> dict[str, Any]:
    np_state = np.random.get_state()
    return {
        "torch": torch.get_rng_state(),
        "cuda": torch.cuda.get_rng_state_all() if torch.cuda.is_available() else [],
        # numpy's state as plain types so the file loads with torch.load(weights_only=True)
        "numpy": [np_state[0], torch.from_numpy(np_state[1].copy()), int(np_state[2]), int(np_state[3]),
                  float(np_state[4])],
        "python": random.getstate(),
    }


def restore_rng(state: dict[str, Any]) -> None:
    torch.set_rng_state(state["torch"])
    if state.get("cuda") and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(state["cuda"])
    name, keys, pos, has_gauss, cached = state["numpy"]
    np.random.set_state((name, keys.numpy().astype(np.uint32), pos, has_gauss, cached))
    version, internal, gauss = state["python"]
    random.setstate((version, tuple(internal), gauss))


def save_checkpoint(folder: str | Path, model: CylinderSplat, state: dict[str, Any]) -> Path:
    """Write ``folder/step_<global_step>/`` and point ``folder/latest`` at it."""
    root = Path(folder)
    target = root / f"step_{state['global_step']:07d}"
    new = not target.exists()
    target.mkdir(parents=True, exist_ok=True)
    try:
        save_model(model, target / MODEL_FILE)
        buffer = io.BytesIO()  # in memory first: a full disk is then an OSError naming the file, nothing half-written
        torch.save(state, buffer)
        atomic_write_bytes(target / STATE_FILE, buffer.getbuffer())
        atomic_write_text(root / "latest", target.name + "\n")
    except BaseException:
        if new:  # no half checkpoint beside the earlier ones; `latest` still names the last complete one
            shutil.rmtree(target, ignore_errors=True)
        raise
    return target


def resolve_checkpoint(path: str | Path) -> Path:
    """A checkpoint folder, its ``state.pt``, or a run/checkpoints folder (-> its latest)."""
    path = Path(path)
    if path.is_file() and path.name == STATE_FILE:
        path = path.parent
    for pointer in (path / "latest", path / "checkpoints" / "latest"):
        if pointer.is_file():
            path = pointer.parent / pointer.read_text().strip()
            break
    if not (path / STATE_FILE).is_file() or not (path / MODEL_FILE).is_file():
        raise FileNotFoundError(f"no training checkpoint at {path} (expected {STATE_FILE} and {MODEL_FILE})")
    return path


def read_state(folder: Path, map_location: str | torch.device = "cpu") -> dict[str, Any]:
    """The resume state saved by :func:`save_checkpoint`; a truncated, foreign or incomplete file raises
    ``ValueError`` naming it (and what to do)."""
    path = Path(folder) / STATE_FILE
    advice = "resume from an earlier step_* folder of the run (its checkpoints/) or start anew with --overwrite"
    try:
        state = torch.load(path, map_location=map_location, weights_only=True)
    except OSError:
        raise
    except Exception as exc:  # noqa: BLE001 - truncated, foreign, random bytes: the unpickler fails in any way
        raise ValueError(f"{path}: cannot read this training state "
                         f"({' '.join(str(exc).split())[:200]}); {advice}") from None
    missing = [key for key in STATE_KEYS if key not in state] if isinstance(state, dict) else list(STATE_KEYS)
    if missing:
        raise ValueError(f"{path} is not a training state written by cylindersplat (no {', '.join(missing)}); {advice}")
    return state


def prune_checkpoints(folder: str | Path, keep: int) -> None:
    """Delete all but the newest ``keep`` step folders (never the one ``latest`` names)."""
    root = Path(folder)
    if keep <= 0 or not root.is_dir():
        return
    latest = (root / "latest").read_text().strip() if (root / "latest").is_file() else None
    steps = sorted(p for p in root.glob("step_*") if p.is_dir())
    for old in steps[:-keep]:
        if old.name != latest:
            shutil.rmtree(old, ignore_errors=True)
