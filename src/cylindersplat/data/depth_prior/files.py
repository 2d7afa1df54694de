"""Precomputed depth priors stored next to the panoramas.

For a panorama ``.../<frame>/rgb.png`` the prior is looked up, in this order, as
``.../<frame>/<name>.png`` (16-bit, ``scale`` units per metre, 0 = unknown) then
``.../<frame>/<name>.npy`` (float metres), with ``name`` defaulting to ``depth_prior``.
Alternatively, ``root`` mirrors the dataset: the file is ``root/<relative frame folder>/<name>.*``
where the relative folder is taken w.r.t. ``dataset_root``.
"""

from __future__ import annotations

from pathlib import Path

from torch import Tensor

from ..io import DEPTH_PNG_SCALE, read_depth_npy, read_depth_png
from .base import DepthPrior, PriorQuery

__all__ = ["FilePrior"]


class FilePrior(DepthPrior):
    name = "file"

    def __init__(
        self,
        name: str = "depth_prior",
        root: str | Path | None = None,
        dataset_root: str | Path | None = None,
        scale: float = DEPTH_PNG_SCALE,
    ) -> None:
        if (root is None) != (dataset_root is None):
            raise ValueError("FilePrior: give both root and dataset_root, or neither")
        self.stem, self.scale = name, scale
        self.root = Path(root) if root is not None else None
        self.dataset_root = Path(dataset_root) if dataset_root is not None else None

    def folder_for(self, rgb_path: Path) -> Path:
        if self.root is None:
            return rgb_path.parent
        try:
            return self.root / rgb_path.parent.relative_to(self.dataset_root)
        except ValueError as exc:
            raise ValueError(f"{rgb_path} is not inside dataset_root {self.dataset_root}") from exc

    def __call__(self, query: PriorQuery) -> Tensor:
        if query.rgb_path is None:
            raise ValueError(f"{query.key}: FilePrior needs the panorama's path")
        folder = self.folder_for(Path(query.rgb_path))
        png, npy = folder / f"{self.stem}.png", folder / f"{self.stem}.npy"
        if png.is_file():
            return read_depth_png(png, size=query.size, scale=self.scale)
        if npy.is_file():
            return read_depth_npy(npy, size=query.size)
        raise FileNotFoundError(f"missing depth prior for {query.key}: neither {png} nor {npy} exists")
