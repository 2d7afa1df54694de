"""Precomputed depth priors stored as files (what ``cylindersplat data priors`` writes).

``FilePrior(name)`` (spec ``file:NAME``) looks for a panorama ``<dataset root>/<rel>/<file>.<ext>``:

1. in the prior tree ``<dataset root>/priors/NAME/<rel>/<file>.png`` (16-bit, ``scale`` units per
   metre, 0 = unknown) or ``.npy`` (float metres) -- the panorama's path relative to the dataset
   root with its suffix replaced; ``cylindersplat data priors --name NAME`` writes exactly these,
   with ``prior.json`` (network, version, resolution, date) at the top of the tree;
2. next to the panorama: ``<rel>/NAME.png`` / ``NAME.npy`` (``name`` defaults to ``depth_prior``).

``FilePrior(tree=DIR)`` (spec ``file:DIR``, any value with a ``/``) reads a tree written elsewhere
(``data priors --out DIR``, e.g. for a read-only dataset). The older mirror mode ``root`` +
``dataset_root`` reads ``root/<relative frame folder>/NAME.*``.
"""

from __future__ import annotations

import json
from pathlib import Path

from torch import Tensor

from ..io import DEPTH_PNG_SCALE, read_depth_npy, read_depth_png
from .base import DepthPrior, PriorQuery

__all__ = ["FilePrior", "PRIORS_DIR", "SIDECAR", "prior_tree", "check_prior_name", "tree_file", "read_sidecar"]

PRIORS_DIR = "priors"  # <dataset root>/priors/<name>/...
SIDECAR = "prior.json"  # at the top of a prior tree


def prior_tree(dataset_root: str | Path, name: str) -> Path:
    """The folder ``cylindersplat data priors --name NAME`` writes for a dataset (and ``file:NAME`` reads)."""
    return Path(dataset_root) / PRIORS_DIR / check_prior_name(name)


def check_prior_name(name: str) -> str:
    """``name`` if it is one plain folder name; else :class:`~cylindersplat.errors.InputError` (a name with
    ``/``, ``..`` or an absolute path would write outside ``DATA/priors/``)."""
    from ...errors import InputError

    if not isinstance(name, str) or not name.strip():
        raise InputError(f"--name {name!r}: a prior needs a non-empty name (files go to DATA/priors/NAME)")
    if "/" in name or "\\" in name or name in (".", "..") or Path(name).is_absolute():
        raise InputError(f"--name {name}: a prior name is one folder name (no '/', '..' or absolute path), e.g. "
                         "depth_anything; use --out DIR to write the files elsewhere")
    return name


def tree_file(tree: str | Path, rgb_path: str | Path, dataset_root: str | Path, suffix: str = ".png") -> Path:
    """The prior file of one panorama inside ``tree``: its path relative to the dataset root, ``suffix`` swapped."""
    try:
        rel = Path(rgb_path).relative_to(dataset_root)
    except ValueError:
        raise ValueError(f"{rgb_path} is not inside the dataset folder {dataset_root}") from None
    return Path(tree) / rel.with_suffix(suffix)


def read_sidecar(tree: str | Path) -> dict | None:
    """The ``prior.json`` of a prior tree (``None`` when absent)."""
    path = Path(tree) / SIDECAR
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path}: invalid JSON ({exc})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a JSON object")
    return data


class FilePrior(DepthPrior):
    name = "file"

    def __init__(
        self,
        name: str = "depth_prior",
        root: str | Path | None = None,
        dataset_root: str | Path | None = None,
        scale: float = DEPTH_PNG_SCALE,
        tree: str | Path | None = None,
    ) -> None:
        if (root is None) != (dataset_root is None):
            raise ValueError("FilePrior: give both root and dataset_root, or neither")
        if "/" in name or "\\" in name:  # file:/path/to/tree
            tree, name = Path(name).expanduser(), Path(name).name
        if not name:
            raise ValueError("FilePrior: the prior needs a name (file:NAME) or a folder (file:DIR)")
        self.stem, self.scale = name, scale
        self.root = Path(root) if root is not None else None
        self.dataset_root = Path(dataset_root) if dataset_root is not None else None
        self.tree = Path(tree) if tree is not None else None

    @property
    def spec(self) -> str:
        return f"file:{self.tree if self.tree is not None else self.stem}"

    def folder_for(self, rgb_path: Path) -> Path:
        if self.root is None:
            return rgb_path.parent
        try:
            return self.root / rgb_path.parent.relative_to(self.dataset_root)
        except ValueError as exc:
            raise ValueError(f"{rgb_path} is not inside dataset_root {self.dataset_root}") from exc

    def tree_for(self, dataset_root: str | Path | None) -> Path | None:
        """The prior tree read for a dataset opened at ``dataset_root``."""
        if self.tree is not None:
            return self.tree
        return prior_tree(dataset_root, self.stem) if dataset_root is not None and self.root is None else None

    def candidates(self, rgb_path: str | Path, dataset_root: str | Path | None = None) -> list[Path]:
        """Where the prior of one panorama may be, in lookup order."""
        rgb_path = Path(rgb_path)
        tree = self.tree_for(dataset_root)
        found = []
        if tree is not None:
            if dataset_root is None:
                raise ValueError(f"{self.spec}: reading a prior tree needs the dataset folder of {rgb_path}")
            found += [tree_file(tree, rgb_path, dataset_root, ".png"), tree_file(tree, rgb_path, dataset_root, ".npy")]
        if self.tree is None:
            folder = self.folder_for(rgb_path)
            found += [folder / f"{self.stem}.png", folder / f"{self.stem}.npy"]
        return found

    def find(self, rgb_path: str | Path, dataset_root: str | Path | None = None) -> Path | None:
        """The prior file of one panorama, or ``None``."""
        return next((p for p in self.candidates(rgb_path, dataset_root) if p.is_file()), None)

    def missing_help(self, rgb_path: str | Path, dataset_root: str | Path | None) -> str:
        looked = self.candidates(rgb_path, dataset_root)
        tree = self.tree_for(dataset_root)
        where = f"--out {tree}" if self.tree is not None else f"--name {self.stem}"
        data = dataset_root if dataset_root is not None else Path(rgb_path).parent
        return (f"missing depth prior {self.spec} for {rgb_path} (looked for {looked[0]}"
                f"{' and ' + str(len(looked) - 1) + ' more' if len(looked) > 1 else ''}); write the files with "
                f"`cylindersplat data priors --data {data} --net NET {where}` (NET: exported:NET.pt2, "
                f"unik3d:WEIGHTS, depth_anything_v2:MODEL; see docs/data.md)")

    def __call__(self, query: PriorQuery) -> Tensor:
        if query.rgb_path is None:
            raise ValueError(f"{query.key}: FilePrior needs the panorama's path")
        path = self.find(query.rgb_path, query.dataset_root)
        if path is None:
            raise FileNotFoundError(self.missing_help(query.rgb_path, query.dataset_root))
        if path.suffix == ".png":
            return read_depth_png(path, size=query.size, scale=self.scale)
        return read_depth_npy(path, size=query.size)
