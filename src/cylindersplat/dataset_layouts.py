"""The names of the dataset layouts and which one a folder holds: one vocabulary for every command.

``train`` (``data.format``), ``eval`` (``--format`` / ``--layout``), ``data priors`` (``--layout``), ``data info``
and ``data preview`` all name a layout with one of :data:`DATASET_LAYOUTS` and detect it with
:func:`detect_layout`; :data:`cylindersplat.data.datasets.DATASETS` maps the same names to their loaders. Light on
imports (no torch), so the command line can offer the names as choices.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["DATASET_LAYOUTS", "LAYOUT_ALIASES", "layout_name", "detect_layout"]

#: synthetic: `cylindersplat data synth` output (meta.json); pano_grf: a png_render_* folder (Matterport3D, Replica,
#: Residential); loc360: a 360Loc root; folder: posed panoramas (poses.json / transforms.json), or a folder of them.
DATASET_LAYOUTS = ("synthetic", "pano_grf", "loc360", "folder")
#: Older spellings still accepted: `data priors --layout input` named a folder of posed panoramas.
LAYOUT_ALIASES = {"input": "folder"}


def layout_name(text: str) -> str:
    """The layout ``text`` names (an alias becomes its name); ``ValueError`` for none."""
    name = LAYOUT_ALIASES.get(text, text)
    if name not in DATASET_LAYOUTS:
        raise ValueError(f"unknown dataset layout {text!r}; expected one of {', '.join(DATASET_LAYOUTS)}")
    return name


def detect_layout(path: str | Path) -> str:
    """The layout of the dataset folder ``path``: ``synthetic`` (``meta.json``), ``pano_grf`` (a ``png_render_*``
    folder), ``folder`` (``poses.json`` or ``transforms.json``, or subfolders with one) or ``loc360``
    (``<location>/mapping|query_360``). ``FileNotFoundError`` for a missing folder, ``ValueError`` for none."""
    from .data.folder import is_input_folder  # (lazy: the names above are read by the command line at start)

    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"missing dataset folder: {path}")
    if (path / "meta.json").is_file():
        return "synthetic"
    if path.name.startswith("png_render_"):
        return "pano_grf"
    if is_input_folder(path):
        return "folder"
    if any((d / "mapping").is_dir() or (d / "query_360").is_dir() for d in path.iterdir() if d.is_dir()):
        return "loc360"
    if any(is_input_folder(d) for d in path.iterdir() if d.is_dir()):
        return "folder"
    raise ValueError(f"{path}: not a dataset folder cylindersplat knows (synthetic meta.json, a png_render_* folder, "
                     "a 360Loc root or a folder of posed panoramas with poses.json); name its layout "
                     f"({', '.join(DATASET_LAYOUTS)})")
