"""The dataset registry: one :class:`DatasetSpec` per layout, and the one place every command asks.

``train`` (``data.format``), ``eval`` (``--format`` / ``--layout``), ``data priors`` (``--layout``), ``data info``
and ``data preview`` name a layout with one of :data:`DATASET_LAYOUTS`, detect it with :func:`detect_layout` and
ask its spec (:func:`dataset_spec`) how to open it, which frames it has, its default views, the loader options it
accepts and the depth range it is evaluated over. No command compares layout names itself.

A new dataset is one file (its spec, e.g. ``data/specs/my_data.py``, and, if it needs one, its loader) plus one
line in :data:`DATASET_SPECS` (docs/architecture.md, "Adding a dataset"). Light on imports (no torch): a spec
module is imported when first asked, so the command line can offer the names as choices at start.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

__all__ = ["DatasetSpec", "DATASET_SPECS", "DATASET_LAYOUTS", "LAYOUT_ALIASES", "IS_ONE", "HOLDS_SOME",
           "dataset_spec", "register_dataset", "layout_name", "detect_layout"]

IS_ONE = 2  # detect(): the folder is a dataset of this layout
HOLDS_SOME = 1  # detect(): the folder holds datasets of this layout (a root of locations, a folder of folders)


@dataclass(frozen=True)
class DatasetSpec:
    """What the commands need to know about one dataset layout.

    Args:
        name: the layout's name (``data.format``, ``--layout``).
        what: a noun phrase for help and errors (``"a 360Loc root (<location>/mapping or query_360)"``).
        detect: ``detect(folder) -> int``: :data:`IS_ONE`, :data:`HOLDS_SOME` or 0. Every "is one" answer beats
            every "holds some", then the registry's order decides.
        open: ``open(root, *, views, split, resolution=..., depth_prior=..., **options) -> PanoramaDataset`` for
            training and evaluation (the depth choices are :func:`cylindersplat.data.datasets.make_dataset`'s).
        frames: ``frames(root, split) -> PanoramaDataset`` whose ``frames()`` are every panorama once (``data
            priors``; ``split`` is ``all`` or a split name).
        inspect: ``inspect(root, *, views, resolution, **options) -> PanoramaDataset`` without a depth prior, for
            ``data info`` and ``data preview`` (pictures and occlusion need none).
        views: default views of training and evaluation; ``info_views`` / ``preview_views``: of ``data info`` and
            ``data preview``.
        options: the loader options it accepts besides views, split, resolution and the depth prior (the
            commands pass ``--scenes``, ``--targets``, ``--views``/``--gap`` only to a layout that lists them).
        depth_range: ``(near, far)`` metres of valid reference depth in evaluation (``eval --depth-range``).
    """

    name: str
    what: str
    detect: Callable[[Path], int]
    open: Callable[..., Any]
    frames: Callable[[Path, str], Any]
    inspect: Callable[..., Any]
    views: str = "two_view"
    info_views: str = "two_view"
    preview_views: str = "n_view"
    options: tuple[str, ...] = ()
    depth_range: tuple[float, float] = (0.05, 1000.0)

    def accepts(self, option: str) -> bool:
        return option in self.options


#: layout name -> ``"module:attribute"`` of its :class:`DatasetSpec`, imported when first asked. synthetic:
#: `cylindersplat data synth` output (meta.json); pano_grf: a png_render_* folder (Matterport3D, Replica,
#: Residential); loc360: a 360Loc root; folder: posed panoramas (poses.json / transforms.json), or a folder of them.
DATASET_SPECS: dict[str, str | DatasetSpec] = {
    "synthetic": "cylindersplat.data.specs.synthetic:SPEC",
    "pano_grf": "cylindersplat.data.specs.pano_grf:SPEC",
    "loc360": "cylindersplat.data.specs.loc360:SPEC",
    "folder": "cylindersplat.data.specs.folder:SPEC",
}
DATASET_LAYOUTS = tuple(DATASET_SPECS)  # the names the command line offers
#: Older spellings still accepted: `data priors --layout input` named a folder of posed panoramas.
LAYOUT_ALIASES = {"input": "folder"}


def register_dataset(spec: DatasetSpec | str, name: str | None = None) -> None:
    """Add a layout at run time (a plugin, a test): a :class:`DatasetSpec` or its ``"module:attribute"``."""
    key = name or (spec.name if isinstance(spec, DatasetSpec) else None)
    if not key:
        raise ValueError("register_dataset needs the layout's name for a 'module:attribute' spec")
    DATASET_SPECS[key] = spec


def layout_name(text: str) -> str:
    """The layout ``text`` names (an alias becomes its name); ``ValueError`` for none."""
    name = LAYOUT_ALIASES.get(text, text)
    if name not in DATASET_SPECS:
        raise ValueError(f"unknown dataset layout {text!r}; expected one of {', '.join(DATASET_SPECS)}")
    return name


def dataset_spec(name: str) -> DatasetSpec:
    """The :class:`DatasetSpec` of layout ``name`` (or an alias of it)."""
    name = layout_name(name)
    spec = DATASET_SPECS[name]
    if isinstance(spec, str):
        module, _, attribute = spec.partition(":")
        spec = getattr(importlib.import_module(module), attribute)
        DATASET_SPECS[name] = spec
    if not isinstance(spec, DatasetSpec) or spec.name != name:
        raise TypeError(f"the registry's entry for {name!r} is not a DatasetSpec named {name!r}: {spec!r}")
    return spec


def _listing(phrases: list[str]) -> str:
    return phrases[0] if len(phrases) == 1 else ", ".join(phrases[:-1]) + " or " + phrases[-1]


def detect_layout(path: str | Path) -> str:
    """The layout of the dataset folder ``path``: the first layout whose spec says the folder is one, else the
    first that says it holds some (registry order). ``FileNotFoundError`` for a missing folder, ``ValueError``
    for none."""
    path = Path(path)
    if not path.is_dir():
        raise FileNotFoundError(f"missing dataset folder: {path}")
    specs = [dataset_spec(name) for name in list(DATASET_SPECS)]
    holds_some = []
    for spec in specs:
        answer = spec.detect(path)
        if answer == IS_ONE:
            return spec.name
        if answer == HOLDS_SOME:
            holds_some.append(spec.name)
    if holds_some:
        return holds_some[0]
    raise ValueError(f"{path}: not a dataset folder cylindersplat knows ({_listing([s.what for s in specs])}); "
                     f"name its layout ({', '.join(DATASET_SPECS)})")
