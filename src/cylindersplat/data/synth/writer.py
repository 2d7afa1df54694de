"""Write generated sequences to disk in the synthetic layout (see ``docs/data.md``)::

    DIR/meta.json                      generator settings + list of scene ids
    DIR/<8-digit scene id>/meta.json   layout kind, spacing, frame names, resolution, seed
    DIR/<id>/poses.json                {"00": 4x4 OpenCV c2w, ...}
    DIR/<id>/NN/rgb.png                8-bit RGB panorama
    DIR/<id>/NN/depth.png              16-bit radial depth in millimetres, 0 = sky / none

A scene's ``meta.json`` is written last, so an interrupted run is resumed by running it again:
complete scenes are skipped, an incomplete one is written anew, and the temporary files a killed run leaves
(``kill -9``: no clean-up ran) are removed, so the result is byte for byte that of an uninterrupted run.
"""

from __future__ import annotations

import json
from dataclasses import asdict, fields
from pathlib import Path

from tqdm import tqdm

from ...utils.atomic import atomic_write_text, remove_temporaries
from ..io import DEPTH_PNG_SCALE, write_depth_png, write_rgb
from .sequence import SequenceConfig, generate_sequence, render_sequence, target_offset

__all__ = ["SYNTH_FORMAT", "write_synthetic_dataset", "scene_id", "config_record"]

SYNTH_FORMAT = "cylindersplat-synth-v1"


def scene_id(index: int) -> str:
    return f"{index:08d}"


# Fields added after the first datasets were written: recorded only when set, so a default
# configuration writes the same ``meta.json`` as before (absent = the default).
_LATER_FIELDS = ("target_offset", "occluders", "layout_weights", "through_doorways")


def config_record(cfg: SequenceConfig) -> dict:
    """``cfg`` as JSON-ready dict for ``meta.json`` (later options only where not at their default)."""
    record = asdict(cfg)
    defaults = {f.name: f.default for f in fields(SequenceConfig)}
    for name in _LATER_FIELDS:
        if record[name] == defaults[name] or (isinstance(record[name], tuple)
                                              and record[name] == tuple(defaults[name])):
            del record[name]
    return record


def _check_same_settings(meta_path: Path, settings: dict) -> None:
    """Resuming (or adding scenes to) a dataset is fine; writing scenes of other settings into it is not: one
    dataset of two resolutions, seeds or generator settings would be read as one without a word."""
    if not meta_path.is_file():
        return
    try:
        old = json.loads(meta_path.read_text())
    except (ValueError, UnicodeDecodeError, RecursionError):
        old = None
    if not isinstance(old, dict):
        raise ValueError(f"{meta_path} exists but is not a data synth meta.json; choose another --out")
    settings = json.loads(json.dumps(settings))  # as the file holds them (tuples become lists)
    labels = {"format": "format", "seed": "--seed", "resolution": "--resolution", "config": "generator settings"}
    differ = [label for key, label in labels.items() if old.get(key) != settings[key]]
    if differ:
        shown = {"seed": lambda v: str(v),
                 "resolution": lambda v: "x".join(map(str, v)) if isinstance(v, list) else repr(v)}
        said = "; ".join(f"{label} {shown[key](old.get(key))} there, {shown[key](settings[key])} now" if key in shown
                         else f"other {label}" for key, label in labels.items() if label in differ)
        raise ValueError(f"{meta_path.parent} already holds a synthetic dataset made with other settings ({said}); "
                         "choose another --out, or repeat the original settings to resume or extend it")


def write_synthetic_dataset(
    out: str | Path,
    scenes: int,
    resolution: tuple[int, int] = (256, 512),
    cfg: SequenceConfig = SequenceConfig(),
    seed: int = 0,
    progress: bool = True,
) -> Path:
    """Generate ``scenes`` sequences into ``out``; returns ``out``."""
    height, width = resolution
    if width != 2 * height:
        raise ValueError(f"resolution must be HxW with W == 2H, got {height}x{width}")
    out = Path(out)
    ids = [scene_id(i) for i in range(scenes)]
    settings = {
        "format": SYNTH_FORMAT, "seed": seed, "resolution": [height, width],
        "depth_scale": DEPTH_PNG_SCALE, "config": config_record(cfg), "scenes": ids,
    }
    _check_same_settings(out / "meta.json", settings)
    out.mkdir(parents=True, exist_ok=True)
    remove_temporaries(out)  # left by a killed run
    atomic_write_text(out / "meta.json", json.dumps(settings, indent=1))
    # None: no bar when output is not a terminal
    for index in tqdm(range(scenes), desc="synth scenes", unit="scene", disable=None if progress else True):
        folder = out / ids[index]
        if (folder / "meta.json").is_file():
            continue
        seq = generate_sequence(seed, index, cfg)
        rgb, depth = render_sequence(seq, height, width)
        names = [f"{k:02d}" for k in range(cfg.frames)]
        for k, name in enumerate(names):
            write_rgb(folder / name / "rgb.png", rgb[k])
            write_depth_png(folder / name / "depth.png", depth[k])
        atomic_write_text(folder / "poses.json",
                          json.dumps({n: p.tolist() for n, p in zip(names, seq.poses)}, indent=1))
        meta = {
            "scene": ids[index], "index": index, "seed": seed, "kind": seq.scene.kind,
            "spacing": seq.spacing, "frames": names, "resolution": [height, width],
            "depth_scale": DEPTH_PNG_SCALE, "sky": seq.scene.sky is not None,
        }
        if cfg.target_offset[1] > 0:  # metres the middle frame stands off the first-last line
            meta["target_offset"] = round(target_offset(seq.poses), 4)
        # last, whole or not at all: marks the scene done
        atomic_write_text(folder / "meta.json", json.dumps(meta, indent=1))
    return out
