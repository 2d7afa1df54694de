"""Adapters for panoramic depth foundation models (UniK3D, Depth Anywhere, UniFuse).

Nothing is ever downloaded. An adapter is usable only when its Python package is importable
*and* its weights exist at a local path the user gives; otherwise constructing it raises a clear
error saying what to install and where to put the weights. Subclasses implement
:meth:`FoundationDepthAdapter.load` and :meth:`FoundationDepthAdapter.predict`.

* :class:`ExportedDepthPrior` runs *any* depth network exported once with ``torch.export.save``
  (``.pt2``) or TorchScript (``.pt``) — the route for Depth Anywhere, UniFuse or your own model:
  export where the model's code lives, then only that file is needed here.
* :class:`UniK3DAdapter` calls the ``unik3d`` package directly (``UniK3D.from_pretrained`` on a
  local checkpoint folder, a full-sphere ``Spherical`` camera, the ``distance`` output = radial depth).
* :class:`DepthAnywhereAdapter`, :class:`UniFuseAdapter`: availability checks only; their research
  code has no stable inference API, so ``load`` explains the TorchScript export route instead.

Alternatively run any model offline and store its output next to the panoramas for
:class:`~cylindersplat.data.depth_prior.files.FilePrior`.
"""

from __future__ import annotations

import importlib
import importlib.util
import math
import warnings
import zipfile
from pathlib import Path
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor

from ..io import resize_depth
from .base import DepthPrior, PriorQuery

__all__ = ["FoundationDepthAdapter", "UniK3DAdapter", "DepthAnywhereAdapter", "UniFuseAdapter", "ExportedDepthPrior"]


def _clean_depth(depth: Tensor, size: tuple[int, int], where: str) -> Tensor:
    """Network output -> ``(H, W)`` float metres at ``size``; non-finite / non-positive -> 0 (unknown)."""
    depth = depth.detach().float().cpu()
    while depth.ndim > 2 and depth.shape[0] == 1:
        depth = depth[0]
    if depth.ndim != 2:
        raise ValueError(f"{where}: expected a single depth map (1, 1, H, W), (1, H, W) or (H, W), got {tuple(depth.shape)}")
    depth = torch.nan_to_num(depth, nan=0.0, posinf=0.0, neginf=0.0).clamp_min(0)
    if tuple(depth.shape) != tuple(size):
        if depth.shape[1] != 2 * depth.shape[0]:
            raise ValueError(f"{where}: output {tuple(depth.shape)} is not a 2:1 panorama")
        depth = resize_depth(depth, size, mode="nearest")
    return depth


class ExportedDepthPrior(DepthPrior):
    """Any exported depth network: ``(1, 3, h, w)`` image in ``[0, 1]`` -> depth map.

    Args:
        weights: a ``.pt2`` file from ``torch.export.save`` or a ``.pt`` file from ``torch.jit.save``.
        input_size: ``(h, w)`` the network runs at (the panorama is resized bilinearly; output resized
            back with nearest); ``None`` keeps the query size.
        output: ``"depth"`` (radial metres), ``"inverse_depth"`` (1/metres) or ``"log_depth"``.
        scale: multiplies the (converted) depth, e.g. for networks trained in other units.
        mean, std: per-channel input normalisation applied before the call (e.g. ImageNet's).
    """

    name = "exported"

    def __init__(
        self,
        weights: str | Path,
        device: str = "cpu",
        input_size: tuple[int, int] | None = None,
        output: Literal["depth", "inverse_depth", "log_depth"] = "depth",
        scale: float = 1.0,
        mean: tuple[float, float, float] | None = None,
        std: tuple[float, float, float] | None = None,
    ) -> None:
        path = Path(weights)
        if not path.is_file():
            raise FileNotFoundError(
                f"depth prior 'exported': no exported model at {path} (write one with torch.export.save or torch.jit.save)"
            )
        if output not in ("depth", "inverse_depth", "log_depth"):
            raise ValueError(f"depth prior 'exported': output must be depth, inverse_depth or log_depth, got {output!r}")
        if not math.isfinite(scale) or scale <= 0:
            raise ValueError(f"depth prior 'exported': scale must be positive, got {scale}")
        kind = "torch.export (.pt2)" if path.suffix == ".pt2" else "TorchScript"
        if not zipfile.is_zipfile(path):  # both formats are zip archives; say so before torch logs a traceback
            raise ValueError(f"{path}: not a {kind} file (not a zip archive; corrupt or a plain state_dict?)")
        try:
            if path.suffix == ".pt2":
                self.module = torch.export.load(str(path)).module().to(device)
            else:
                with warnings.catch_warnings():  # TorchScript still loads fine; its deprecation is not the user's problem
                    warnings.simplefilter("ignore", DeprecationWarning)
                    self.module = torch.jit.load(str(path), map_location=device).eval()
        except Exception as exc:  # noqa: BLE001 - torch raises many types for foreign files
            raise ValueError(f"{path}: not a {kind} file ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from exc
        self.path, self.device, self.input_size, self.output, self.scale = path, device, input_size, output, scale
        self.mean = torch.tensor(mean).view(1, 3, 1, 1) if mean is not None else None
        self.std = torch.tensor(std).view(1, 3, 1, 1) if std is not None else None

    @torch.no_grad()
    def __call__(self, query: PriorQuery) -> Tensor:
        x = query.image[None].float()
        if self.input_size is not None and tuple(self.input_size) != query.size:
            x = F.interpolate(x, size=tuple(self.input_size), mode="bilinear", align_corners=False, antialias=True)
        if self.mean is not None:
            x = x - self.mean
        if self.std is not None:
            x = x / self.std
        out = self.module(x.to(self.device))
        if isinstance(out, (tuple, list)):
            out = out[0]
        if isinstance(out, dict):
            out = out.get("depth", out.get("distance", next(iter(out.values()))))
        out = out.float()
        if self.output == "inverse_depth":
            out = torch.where(out > 0, 1.0 / out.clamp_min(1e-8), torch.zeros_like(out))
        elif self.output == "log_depth":
            out = out.exp()
        return _clean_depth(out * self.scale, query.size, f"depth prior 'exported' ({self.path})")


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
            f"depth prior {self.name!r} has no stable inference API to call: export the network once with "
            "torch.export.save (or torch.jit.trace) where its code lives and use the 'exported' prior, or precompute its depth "
            "into <frame>/depth_prior.png (16-bit mm) / .npy and use the 'file' prior"
        )

    def predict(self, image: Tensor) -> Tensor:
        """Radial depth ``(H, W)`` in metres for one panorama ``(3, H, W)`` (subclass)."""
        raise NotImplementedError

    def __call__(self, query: PriorQuery) -> Tensor:
        if self._model is None:
            self._model = self.load()
        return self.predict(query.image)


class UniK3DAdapter(FoundationDepthAdapter):
    """UniK3D metric distance for full equirect panoramas (``weights``: a local ``from_pretrained`` folder)."""

    name = "unik3d"
    package = "unik3d"
    install_hint = "pip install git+https://github.com/lpiccinelli-eth/UniK3D (and its requirements)"
    weights_hint = (
        "a UniK3D checkpoint folder (config.json + model.safetensors, e.g. a local copy of unik3d-vitl); "
        "it is not fetched from the hub"
    )

    def load(self):
        models = importlib.import_module("unik3d.models")
        model = models.UniK3D.from_pretrained(str(self.weights))
        return model.to(self.device).eval()

    @torch.no_grad()
    def predict(self, image: Tensor) -> Tensor:
        camera_module = importlib.import_module("unik3d.utils.camera")
        h, w = image.shape[-2:]
        rgb = (image.clamp(0, 1) * 255 + 0.5).to(torch.uint8).to(self.device)
        # A fresh full-sphere camera per call: [fx, fy, cx, cy, W, H, half HFoV, half VFoV] (the
        # first four are unused by the spherical model; infer() may rescale the camera in place).
        params = torch.tensor([1.0, 1.0, 1.0, 1.0, float(w), float(h), math.pi, math.pi / 2])
        out = self._model.infer(rgb=rgb, camera=camera_module.Spherical(params=params), normalize=True)
        return _clean_depth(out["distance"], (h, w), "depth prior 'unik3d'")


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
