"""Depth networks as depth priors: exported models, UniK3D, Depth Anything V2.

Every adapter is a :class:`NetworkDepthPrior`: ``prior(query)`` gives one view's radial depth in
metres, ``prior.predict_batch(images)`` several at once (``cylindersplat data priors`` runs a
network once over a dataset this way and stores the result as files), and ``prior.describe()``
says which network and which weights made the depth (recorded next to the files).

* :class:`ExportedDepthPrior` runs *any* depth network exported once with ``torch.export.save``
  (``.pt2``) or TorchScript (``.pt``) — the route for Depth Anywhere, UniFuse or your own model:
  export where the model's code lives, then only that file is needed here.
* :class:`UniK3DAdapter` calls the ``unik3d`` package (``UniK3D.from_pretrained`` on a local
  checkpoint folder or a hub id, a full-sphere ``Spherical`` camera, the ``distance`` output =
  radial depth).
* :class:`DepthAnythingV2Adapter` calls Depth Anything V2 through ``transformers``
  (``AutoModelForDepthEstimation`` on a local model folder or a hub id). Metric checkpoints give
  metres; relative ones give disparity up to scale and shift, turned into depth ``1 / disparity``
  scaled so that its median is ``median_depth`` metres (no metric scale: a weak prior).

A missing package or missing weights is an error saying what to install or where the weights should
be (``ModuleNotFoundError`` / ``FileNotFoundError``, one line on the command line). A local folder
never touches the network; a hub id (``org/name``) is fetched by the package's own
``from_pretrained`` when it is not cached.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib
import importlib.metadata
import importlib.util
import logging
import math
import re
import warnings
import zipfile
from pathlib import Path
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor

from ..io import resize_depth
from .base import DepthPrior, PriorQuery
from .hub import check_hub_id

__all__ = ["NetworkDepthPrior", "FoundationDepthAdapter", "UniK3DAdapter", "DepthAnythingV2Adapter",
           "ExportedDepthPrior", "file_sha256"]

_HUB_ID = re.compile(r"[A-Za-z0-9][\w.-]*/[\w.-]+")


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file, or of a folder's files (relative names and contents, in name order)."""
    path = Path(path)
    digest = hashlib.sha256()
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    for file in files:
        if file != path:
            digest.update(file.relative_to(path).as_posix().encode() + b"\0")
        with open(file, "rb") as handle:
            for block in iter(lambda: handle.read(1 << 20), b""):
                digest.update(block)
    return digest.hexdigest()


def _package_version(distribution: str) -> str | None:
    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return None


def _clean_depth(depth: Tensor, size: tuple[int, int], where: str) -> Tensor:
    """Network output -> ``(H, W)`` float metres at ``size``; non-finite / non-positive -> 0 (unknown)."""
    depth = depth.detach().float().cpu()
    while depth.ndim > 2 and depth.shape[0] == 1:
        depth = depth[0]
    if depth.ndim != 2:
        raise ValueError(f"{where}: expected a single depth map (1, 1, H, W), (1, H, W) or (H, W), "
                         f"got {tuple(depth.shape)}")
    depth = torch.nan_to_num(depth, nan=0.0, posinf=0.0, neginf=0.0).clamp_min(0)
    if tuple(depth.shape) != tuple(size):
        if depth.shape[1] != 2 * depth.shape[0]:
            raise ValueError(f"{where}: output {tuple(depth.shape)} is not a 2:1 panorama")
        depth = resize_depth(depth, size, mode="nearest")
    return depth


def _per_image(out: Tensor, count: int, where: str) -> list[Tensor]:
    """Split a batched network output ``(B, 1, h, w)`` / ``(B, h, w)`` (or one map for ``B = 1``) per image."""
    if out.ndim == 4 and out.shape[0] == count and out.shape[1] == 1:
        return list(out[:, 0])
    if out.ndim == 3 and out.shape[0] == count:
        return list(out)
    if count == 1:
        return [out]
    raise ValueError(f"{where}: expected depth maps (B, 1, H, W) or (B, H, W) for a batch of {count}, "
                     f"got {tuple(out.shape)}")


class NetworkDepthPrior(DepthPrior):
    """A depth network: one view per call, or a batch with :meth:`predict_batch`."""

    name = "network"

    def predict_batch(self, images: Tensor) -> Tensor:
        """``(B, 3, H, W)`` panoramas in ``[0, 1]`` -> ``(B, H, W)`` radial depth in metres (0 = unknown)."""
        return torch.stack([self(PriorQuery(image, None, None, f"batch/{i}")) for i, image in enumerate(images)])

    def describe(self) -> dict:
        """Which network and weights (with a version or checksum) produce this depth; JSON-ready."""
        return {"network": self.name}


class ExportedDepthPrior(NetworkDepthPrior):
    """Any exported depth network: ``(B, 3, h, w)`` image in ``[0, 1]`` -> depth map(s).

    Args:
        weights: a ``.pt2`` file from ``torch.export.save`` or a ``.pt`` file from ``torch.jit.save``.
        input_size: ``(h, w)`` the network runs at (the panorama is resized bilinearly; output resized
            back with nearest); ``None`` keeps the query size.
        output: ``"depth"`` (radial metres), ``"inverse_depth"`` (1/metres) or ``"log_depth"``.
        scale: multiplies the (converted) depth, e.g. for networks trained in other units.
        mean, std: per-channel input normalisation applied before the call (e.g. ImageNet's).

    A batch is passed to the network in one call; a network exported for batch size 1 is called once
    per image instead.
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
                f"depth prior 'exported': no exported model at {path} "
                "(write one with torch.export.save or torch.jit.save)"
            )
        if output not in ("depth", "inverse_depth", "log_depth"):
            raise ValueError(
                f"depth prior 'exported': output must be depth, inverse_depth or log_depth, got {output!r}"
            )
        if not math.isfinite(scale) or scale <= 0:
            raise ValueError(f"depth prior 'exported': scale must be positive, got {scale}")
        kind = "torch.export (.pt2)" if path.suffix == ".pt2" else "TorchScript"
        if not zipfile.is_zipfile(path):  # both formats are zip archives; say so before torch logs a traceback
            raise ValueError(f"{path}: not a {kind} file (not a zip archive; corrupt or a plain state_dict?)")
        try:
            if path.suffix == ".pt2":
                with _quiet_logger("torch.export"):  # it logs a traceback before raising; our one line says it all
                    self.module = torch.export.load(str(path)).module().to(device)
            else:
                # TorchScript still loads fine; its deprecation is not the user's problem
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", DeprecationWarning)
                    self.module = torch.jit.load(str(path), map_location=device).eval()
        except Exception as exc:  # noqa: BLE001 - torch raises many types for foreign files
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise ValueError(f"{path}: not a {kind} file ({first})") from exc
        self.path, self.device, self.input_size, self.output, self.scale = path, device, input_size, output, scale
        self.mean = torch.tensor(mean).view(1, 3, 1, 1) if mean is not None else None
        self.std = torch.tensor(std).view(1, 3, 1, 1) if std is not None else None
        self._batched = True  # False once the network refused a batch (exported for batch size 1)
        self._sha256: str | None = None

    def _run(self, x: Tensor) -> list[Tensor]:
        try:
            out = self.module(x.to(self.device))
        except torch.OutOfMemoryError:
            raise
        except Exception as exc:  # noqa: BLE001 - a shape guard, a wrong dtype, ...: the user's network and input
            if len(x) > 1:
                raise
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise ValueError(f"{self.path}: the network failed on a {tuple(x.shape)} input ({first}); a network "
                             "exported with fixed shapes needs its own input size (input_size=(h, w); "
                             "`data priors --net-size HxW`)") from exc
        if isinstance(out, (tuple, list)):
            out = out[0]
        if isinstance(out, dict):
            out = out.get("depth", out.get("distance", next(iter(out.values()))))
        out = out.float()
        if self.output == "inverse_depth":
            out = torch.where(out > 0, 1.0 / out.clamp_min(1e-8), torch.zeros_like(out))
        elif self.output == "log_depth":
            out = out.exp()
        return _per_image(out * self.scale, x.shape[0], f"depth prior 'exported' ({self.path})")

    @torch.no_grad()
    def predict_batch(self, images: Tensor) -> Tensor:
        size = tuple(images.shape[-2:])
        x = images.float()
        if self.input_size is not None and tuple(self.input_size) != size:
            x = F.interpolate(x, size=tuple(self.input_size), mode="bilinear", align_corners=False, antialias=True)
        if self.mean is not None:
            x = x - self.mean
        if self.std is not None:
            x = x / self.std
        outputs = None
        if self._batched or len(x) == 1:
            try:
                outputs = self._run(x)
            except Exception:  # noqa: BLE001 - a network exported with batch size 1 refuses more (many error types)
                if len(x) == 1:
                    raise
                self._batched = False
        if outputs is None:
            outputs = [o for i in range(len(x)) for o in self._run(x[i : i + 1])]
        return torch.stack([_clean_depth(o, size, f"depth prior 'exported' ({self.path})") for o in outputs])

    def __call__(self, query: PriorQuery) -> Tensor:
        return self.predict_batch(query.image[None])[0]

    def describe(self) -> dict:
        if self._sha256 is None:
            self._sha256 = file_sha256(self.path)
        return {"network": self.name, "weights": str(self.path.resolve()), "sha256": self._sha256,
                "torch": torch.__version__, "output": self.output, "scale": self.scale,
                "input_size": list(self.input_size) if self.input_size is not None else None,
                "mean": self.mean.flatten().tolist() if self.mean is not None else None,
                "std": self.std.flatten().tolist() if self.std is not None else None}


class FoundationDepthAdapter(NetworkDepthPrior):
    """Base: checks ``package`` is importable and ``weights`` is a local path or a hub id, loads lazily."""

    name = "foundation"
    package = ""  # importable module name
    distribution = ""  # pip distribution name (for its version), default: package
    install_hint = ""  # how to install the package
    weights_hint = ""  # which checkpoint to give and where it comes from

    def __init__(self, weights: str | Path | None = None, device: str = "cpu") -> None:
        if importlib.util.find_spec(self.package) is None:
            raise ModuleNotFoundError(
                f"depth prior {self.name!r} needs the Python package '{self.package}', which is not installed: "
                f"{self.install_hint}", name=self.package,
            )
        if weights is None or str(weights) == "":
            raise FileNotFoundError(
                f"depth prior {self.name!r} needs weights: give {self.name}:PATH_OR_HUB_ID ({self.weights_hint})"
            )
        path = Path(weights).expanduser()
        text = str(weights)
        if path.exists():
            self.source, self.weights = str(path.resolve()), path
        elif _HUB_ID.fullmatch(text) and not text.startswith((".", "/", "~")):
            check_hub_id(text, self.name)  # offline and not cached: say so now, not after the package's retries
            self.source, self.weights = text, None  # a hub id, fetched (or read from the cache) by the package
        else:
            raise FileNotFoundError(f"depth prior {self.name!r}: weights not found at {path} ({self.weights_hint})")
        self.device, self._model = device, None
        self._sha256: str | None = None

    def load(self):
        """Build the network from ``self.source`` (subclass)."""
        raise NotImplementedError

    def _loaded(self):
        if self._model is None:
            try:
                self._model = self.load()
            except (ModuleNotFoundError, FileNotFoundError, ValueError):
                raise
            except Exception as exc:  # noqa: BLE001 - the packages raise OSError, HTTP errors, ...
                first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                where = "a local folder" if self.weights is not None else "a hub id (needs network access or the cache)"
                raise ValueError(
                    f"depth prior {self.name!r}: could not load {self.source!r}, {where} ({first})"
                ) from exc
        return self._model

    def predict(self, image: Tensor) -> Tensor:
        """Radial depth ``(H, W)`` in metres for one panorama ``(3, H, W)`` (subclass)."""
        raise NotImplementedError

    def __call__(self, query: PriorQuery) -> Tensor:
        self._loaded()
        return self.predict(query.image)

    def describe(self) -> dict:
        if self.weights is not None and self._sha256 is None:
            self._sha256 = file_sha256(self.weights)
        return {"network": self.name, "weights": self.source, "sha256": self._sha256,
                "package": self.package, "package_version": _package_version(self.distribution or self.package)}


class UniK3DAdapter(FoundationDepthAdapter):
    """UniK3D metric distance for full equirect panoramas (``weights``: a ``from_pretrained`` folder or hub id)."""

    name = "unik3d"
    package = "unik3d"
    install_hint = "pip install git+https://github.com/lpiccinelli-eth/UniK3D (and its requirements)"
    weights_hint = ("a UniK3D checkpoint folder (config.json + model.safetensors, e.g. a local copy of "
                    "lpiccinelli/unik3d-vitl) or that hub id")

    def load(self):
        models = importlib.import_module("unik3d.models")
        model = models.UniK3D.from_pretrained(self.source)
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


class DepthAnythingV2Adapter(FoundationDepthAdapter):
    """Depth Anything V2 through ``transformers`` (``weights``: a model folder or hub id).

    ``model.config.depth_estimation_type`` decides the output: ``"metric"`` checkpoints
    (``...-Metric-Indoor-...``, ``...-Metric-Outdoor-...``) predict metres, used as they are;
    ``"relative"`` ones (the default checkpoints) predict disparity without scale or shift, turned
    into ``1 / disparity`` and scaled so that the median is ``median_depth`` metres. The network is
    a perspective model applied to the whole equirect image (no seam or pole handling): a rough prior.
    """

    name = "depth_anything_v2"
    package = "transformers"
    install_hint = "pip install transformers"
    weights_hint = ("a Depth Anything V2 model folder in the transformers format (config.json, model.safetensors, "
                    "preprocessor_config.json; e.g. a local copy of depth-anything/Depth-Anything-V2-Small-hf) "
                    "or that hub id")

    def __init__(self, weights: str | Path | None = None, device: str = "cpu", median_depth: float = 2.0) -> None:
        super().__init__(weights, device)
        if not (math.isfinite(median_depth) and median_depth > 0):
            raise ValueError(f"depth prior {self.name!r}: median_depth must be positive, got {median_depth}")
        self.median_depth = float(median_depth)

    def load(self):
        transformers = importlib.import_module("transformers")
        self.processor = transformers.AutoImageProcessor.from_pretrained(self.source)
        model = transformers.AutoModelForDepthEstimation.from_pretrained(self.source)
        self.kind = getattr(model.config, "depth_estimation_type", None) or "relative"
        return model.to(self.device).eval()

    @torch.no_grad()
    def predict_batch(self, images: Tensor) -> Tensor:
        model = self._loaded()
        h, w = images.shape[-2:]
        arrays = [(image.clamp(0, 1) * 255 + 0.5).to(torch.uint8).permute(1, 2, 0).cpu().numpy() for image in images]
        pixels = self.processor(images=arrays, return_tensors="pt")["pixel_values"].to(self.device)
        out = model(pixel_values=pixels).predicted_depth.float()  # (B, h', w')
        out = F.interpolate(out[:, None], size=(h, w), mode="bilinear", align_corners=False)[:, 0].cpu()
        if self.kind != "metric":
            disparity = out
            out = torch.where(disparity > 0, 1.0 / disparity.clamp_min(1e-8), torch.zeros_like(disparity))
            for i in range(len(out)):
                valid = out[i] > 0
                if valid.any():
                    out[i] = out[i] * (self.median_depth / out[i][valid].median())
        return torch.stack([_clean_depth(o, (h, w), "depth prior 'depth_anything_v2'") for o in out])

    def predict(self, image: Tensor) -> Tensor:
        return self.predict_batch(image[None])[0]

    def describe(self) -> dict:
        self._loaded()
        return {**super().describe(), "output": self.kind,
                "median_depth": self.median_depth if self.kind != "metric" else None}


@contextlib.contextmanager
def _quiet_logger(name: str):
    """Silence the ``logging`` logger ``name`` (and its children) within the block."""
    logger = logging.getLogger(name)
    level = logger.level
    logger.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        logger.setLevel(level)
