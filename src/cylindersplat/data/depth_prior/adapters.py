"""Adapters for panoramic depth foundation models (UniK3D, Depth Anywhere, UniFuse).

Nothing is ever downloaded. An adapter is usable only when its Python package is importable
*and* its weights exist at a local path the user gives; otherwise constructing it raises a clear
error saying what to install and where to put the weights. Subclasses implement
:meth:`FoundationDepthAdapter.load` and :meth:`FoundationDepthAdapter.predict`.

Status: the availability checks are complete; the inference glue of each model is not wired yet
(it needs the package and weights to be verified against), so ``load`` raises
``NotImplementedError`` after the checks pass. Until then, run the model offline and store its
output next to the panoramas for :class:`~cylindersplat.data.depth_prior.files.FilePrior`.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from torch import Tensor

from .base import DepthPrior, PriorQuery

__all__ = ["FoundationDepthAdapter", "UniK3DAdapter", "DepthAnywhereAdapter", "UniFuseAdapter"]


class FoundationDepthAdapter(DepthPrior):
    """Base: checks ``package`` is importable and ``weights`` exists, then lazily loads the model."""

    name = "foundation"
    package = ""  # importable module name
    install_hint = ""  # how to install the package
    weights_hint = ""  # which checkpoint file to fetch (by the user) and where it comes from

    def __init__(self, weights: str | Path | None = None, device: str = "cpu") -> None:
        if importlib.util.find_spec(self.package) is None:
            raise ImportError(
                f"depth prior {self.name!r} needs the Python package '{self.package}', which is not installed: "
                f"{self.install_hint}"
            )
        if weights is None:
            raise FileNotFoundError(
                f"depth prior {self.name!r} needs local weights: pass weights=/path/to/checkpoint ({self.weights_hint})"
            )
        path = Path(weights)
        if not path.exists():
            raise FileNotFoundError(f"depth prior {self.name!r}: weights not found at {path} ({self.weights_hint})")
        self.weights, self.device, self._model = path, device, None

    def load(self):
        """Build the network from ``self.weights`` (subclass)."""
        raise NotImplementedError(
            f"depth prior {self.name!r}: inference glue is not wired yet; precompute its depth into "
            "<frame>/depth_prior.png (16-bit mm) or .npy and use the 'file' prior"
        )

    def predict(self, image: Tensor) -> Tensor:
        """Radial depth ``(H, W)`` in metres for one panorama ``(3, H, W)`` (subclass)."""
        raise NotImplementedError

    def __call__(self, query: PriorQuery) -> Tensor:
        if self._model is None:
            self._model = self.load()
        return self.predict(query.image)


class UniK3DAdapter(FoundationDepthAdapter):
    name = "unik3d"
    package = "unik3d"
    install_hint = "pip install git+https://github.com/lpiccinelli-eth/UniK3D (and its requirements)"
    weights_hint = "a UniK3D checkpoint (e.g. unik3d-vitl) saved locally; it is not fetched from the hub"


class DepthAnywhereAdapter(FoundationDepthAdapter):
    name = "depth_anywhere"
    package = "depth_anywhere"
    install_hint = "install the Depth Anywhere code (github.com/albert100121/Depth-Anywhere) so it imports as 'depth_anywhere'"
    weights_hint = "a Depth Anywhere student checkpoint (.pth) downloaded by hand"


class UniFuseAdapter(FoundationDepthAdapter):
    name = "unifuse"
    package = "unifuse"
    install_hint = "install UniFuse (github.com/alibaba/UniFuse-Unidirectional-Fusion) so it imports as 'unifuse'"
    weights_hint = "a UniFuse Matterport3D checkpoint directory (model.pth) downloaded by hand"
