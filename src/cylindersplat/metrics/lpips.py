"""LPIPS (VGG16 variant, Zhang et al. 2018) in plain torch, with weights from a local file.

Network: scaling layer ``(x - shift) / scale`` on inputs in ``[-1, 1]``; torchvision's VGG16
``features`` up to relu5_3, tapped after relu1_2, relu2_2, relu3_3, relu4_3, relu5_3; each tap is
unit-normalised over channels, the squared difference goes through a 1x1 linear head (no bias),
is averaged over space and summed over the five taps.

Weights (no downloads, ever) come in two parts, each read with ``torch.load(weights_only=True)``
(or safetensors):

* the **VGG16 trunk**: convolutions under torchvision keys ``features.{i}.weight/bias`` (the
  ``lpips`` package's ``net.slice{k}.{i}.weight`` naming is accepted too);
* the **linear heads**: ``lin{k}.model.1.weight`` (the ``lpips`` package's ``vgg.pth`` naming) or
  ``lin{k}.weight``, each of shape ``(1, C_k, 1, 1)``.

Lookup (:func:`load_lpips`), each part from the first place that has it:

1. the file given by path (``--lpips-weights``, ``loss.lpips_weights``), else the one named by
   ``$CYLINDERSPLAT_LPIPS_WEIGHTS``: a merged file with both parts, or a file with one of them
   (torchvision's ``vgg16-397923af.pth``: trunk only; the ``lpips`` package's ``vgg.pth``: heads only).
   A part the file has only some entries of is an error, never completed from elsewhere;
2. the heads missing so far: the ``lpips`` package's bundled ``lpips/weights/v0.1/vgg.pth`` (checked
   in the ``lpips-0.1.4`` wheel: keys ``lin0..lin4.model.1.weight``, shapes ``(1, 64|128|256|512|512,
   1, 1)``), found with ``importlib.util.find_spec`` -- the package is located, not imported (it
   imports torchvision);
3. the trunk missing so far: torchvision's download cache,
   ``torch.hub.get_dir()/checkpoints/vgg16-397923af.pth`` (``$TORCH_HOME/hub``, default
   ``~/.cache/torch/hub``), where ``torchvision.models.vgg16(weights="IMAGENET1K_V1")`` stores it.

Nothing found: ``FileNotFoundError`` naming all three. :attr:`LPIPS.sources` records where each
part came from. To build a merged file: save torchvision's ``vgg16(weights="IMAGENET1K_V1").features``
state dict (prefix ``features.``) together with the ``lpips`` package's ``weights/v0.1/vgg.pth``.
"""

from __future__ import annotations

import importlib.util
import os
import pickle
import re
import warnings
from pathlib import Path

import torch
from jaxtyping import Float
from torch import Tensor, nn

from .image import check_image_pair

__all__ = ["LPIPS", "LPIPS_WEIGHTS_ENV", "VGG16_CONV_LAYERS", "LPIPS_TAPS", "lpips", "load_lpips",
           "lpips_package_weights", "torchvision_vgg16_weights", "lpips_weights_available"]

LPIPS_WEIGHTS_ENV = "CYLINDERSPLAT_LPIPS_WEIGHTS"
LPIPS_PACKAGE_FILE = ("weights", "v0.1", "vgg.pth")  # inside the lpips package folder
TORCHVISION_VGG16_FILE = "vgg16-397923af.pth"  # torchvision's VGG16_Weights.IMAGENET1K_V1 file name
# (index in torchvision's vgg16.features, in channels, out channels); "M" = max-pool.
VGG16_CONV_LAYERS: list = [
    (0, 3, 64), (2, 64, 64), "M",
    (5, 64, 128), (7, 128, 128), "M",
    (10, 128, 256), (12, 256, 256), (14, 256, 256), "M",
    (17, 256, 512), (19, 512, 512), (21, 512, 512), "M",
    (24, 512, 512), (26, 512, 512), (28, 512, 512),
]
LPIPS_TAPS = (2, 7, 14, 21, 28)  # conv whose ReLU output is a tap: relu1_2 ... relu5_3
TAP_CHANNELS = (64, 128, 256, 512, 512)
SHIFT = (-0.030, -0.088, -0.188)
SCALE = (0.458, 0.448, 0.450)


class LPIPS(nn.Module):
    """LPIPS-VGG distance. ``forward(pred, target)`` takes images in ``[0, 1]`` ``(B, 3, H, W)``."""

    def __init__(self) -> None:
        super().__init__()
        self.features = nn.ModuleDict()
        for layer in VGG16_CONV_LAYERS:
            if layer != "M":
                index, c_in, c_out = layer
                self.features[str(index)] = nn.Conv2d(c_in, c_out, 3, padding=1)
        self.lins = nn.ModuleList(nn.Conv2d(c, 1, 1, bias=False) for c in TAP_CHANNELS)
        self.register_buffer("shift", torch.tensor(SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(SCALE).view(1, 3, 1, 1), persistent=False)
        self.requires_grad_(False)
        self.eval()
        self.sources: dict[str, str] = {}  # where load_lpips took the trunk and the linear heads from

    def taps(self, x: Float[Tensor, "B 3 H W"]) -> list[Tensor]:
        """VGG activations at the five LPIPS taps for inputs in ``[0, 1]``."""
        x = ((2.0 * x - 1.0) - self.shift) / self.scale
        out = []
        for layer in VGG16_CONV_LAYERS:
            if layer == "M":
                x = nn.functional.max_pool2d(x, 2, 2)
                continue
            x = torch.relu(self.features[str(layer[0])](x))
            if layer[0] in LPIPS_TAPS:
                out.append(x)
        return out

    def forward(self, pred: Float[Tensor, "B 3 H W"], target: Float[Tensor, "B 3 H W"]) -> Float[Tensor, " B"]:
        check_image_pair(pred, target, name="lpips")
        batch = pred.shape[:-3]
        pred = pred.reshape(-1, *pred.shape[-3:])
        target = target.reshape(-1, *target.shape[-3:])
        total = 0.0
        for lin, fa, fb in zip(self.lins, self.taps(pred), self.taps(target)):
            na = fa / (fa.pow(2).sum(dim=1, keepdim=True).sqrt() + 1e-10)
            nb = fb / (fb.pow(2).sum(dim=1, keepdim=True).sqrt() + 1e-10)
            total = total + lin((na - nb) ** 2).mean(dim=(-2, -1))
        return total.view(*batch)

    # ---- weights -----------------------------------------------------------------------------
    def state_dict_external(self) -> dict[str, Tensor]:
        """Weights under the documented file keys (torchvision ``features.*`` + ``lin{k}.model.1.weight``)."""
        out = {f"features.{k}.{p}": v for k, conv in self.features.items() for p, v in conv.state_dict().items()}
        out.update({f"lin{k}.model.1.weight": lin.weight for k, lin in enumerate(self.lins)})
        return {k: v.detach().clone().contiguous() for k, v in out.items()}

    def load_external(self, state: dict[str, Tensor], source: str = "weights") -> None:
        """Load a flat dict in one of the documented key layouts; raise naming missing keys."""
        features, lins = _split_state(state)
        self._load_parts(features, lins, source, source)

    def _load_parts(self, features: dict[str, Tensor], lins: dict[int, Tensor], trunk_source: str,
                    linear_source: str) -> None:
        expected = [f"{k}.{p}" for k in self.features for p in ("weight", "bias")]
        missing = [k for k in expected if k not in features] + [f"lin{k}" for k in range(5) if k not in lins]
        if missing:
            source = trunk_source if trunk_source == linear_source else f"{trunk_source} + {linear_source}"
            raise ValueError(f"LPIPS {source}: missing entries {missing[:6]}{'...' if len(missing) > 6 else ''}")
        for name in expected:
            index, param = name.split(".")
            target = getattr(self.features[index], param)
            if tuple(features[name].shape) != tuple(target.shape):
                raise ValueError(f"LPIPS {trunk_source}: features.{name} has shape {tuple(features[name].shape)}, "
                                 f"VGG16 needs {tuple(target.shape)}")
            target.data.copy_(features[name])
        for k, lin in enumerate(self.lins):
            if lins[k].numel() != lin.weight.numel():
                raise ValueError(f"LPIPS {linear_source}: lin{k} has shape {tuple(lins[k].shape)}, "
                                 f"needs {tuple(lin.weight.shape)}")
            lin.weight.data.copy_(lins[k].reshape(lin.weight.shape))
        self.sources = {"trunk": trunk_source, "linear": linear_source}


def _split_state(state: dict[str, Tensor]) -> tuple[dict[str, Tensor], dict[int, Tensor]]:
    """A flat state dict -> (trunk entries ``"{index}.{weight|bias}"``, heads ``{k: weight}``); other keys are
    ignored."""
    features: dict[str, Tensor] = {}
    lins: dict[int, Tensor] = {}
    for key, value in state.items():
        if m := re.fullmatch(r"(?:.*\.)?features\.(\d+)\.(weight|bias)", key):
            features[f"{m[1]}.{m[2]}"] = value
        elif m := re.fullmatch(r"(?:.*\.)?slice\d\.(\d+)\.(weight|bias)", key):
            features[f"{m[1]}.{m[2]}"] = value
        elif m := re.fullmatch(r"(?:.*\.)?lin(\d)(?:\.model\.1)?\.weight", key):
            lins[int(m[1])] = value
    return features, lins


def _read_weight_file(path: Path) -> dict[str, Tensor]:
    if path.suffix == ".safetensors":
        from safetensors.torch import load_file

        return load_file(str(path))
    try:  # weights_only: a pickle is never executed, it is refused (with torch's many-line advice cut to one)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # torch's note on the pickle protocol
            state = torch.load(path, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, OSError, AttributeError) as exc:
        if isinstance(exc, FileNotFoundError):
            raise
        first = ("a pickle of more than tensors: refused, never run" if isinstance(exc, pickle.UnpicklingError)
                 else str(exc).strip().splitlines()[0][:120] if str(exc).strip() else type(exc).__name__)
        raise ValueError(f"{path}: not a weights file that loads without running code ({first}); give the LPIPS "
                         "weights as a .pth state_dict or .safetensors") from None
    if isinstance(state, dict) and "state_dict" in state:
        state = state["state_dict"]
    if not isinstance(state, dict) or not all(isinstance(v, Tensor) for v in state.values()):
        raise ValueError(f"{path}: expected a state_dict of tensors, got {type(state).__name__}")
    return state


def lpips_package_weights() -> Path | None:
    """The ``lpips`` package's bundled ``weights/v0.1/vgg.pth`` (its linear heads), or None.

    The package is found with ``importlib.util.find_spec`` and not imported: importing it needs
    torchvision, which the heads do not.
    """
    try:
        spec = importlib.util.find_spec("lpips")
    except (ImportError, ValueError):
        return None
    for folder in (spec.submodule_search_locations or []) if spec is not None else []:
        file = Path(folder).joinpath(*LPIPS_PACKAGE_FILE)
        if file.is_file():
            return file
    return None


def torchvision_vgg16_weights() -> Path:
    """Where torchvision caches its ImageNet VGG16 weights: ``torch.hub.get_dir()/checkpoints/vgg16-397923af.pth``."""
    return Path(torch.hub.get_dir()) / "checkpoints" / TORCHVISION_VGG16_FILE


def _explicit_file(path) -> Path | None:
    raw = path if path is not None else os.environ.get(LPIPS_WEIGHTS_ENV)
    return Path(raw) if raw else None


def lpips_weights_available(path: str | os.PathLike | None = None) -> bool:
    """Whether :func:`load_lpips` has something to read: a weights file (``path`` / the environment
    variable) or both the ``lpips`` package's heads and torchvision's cached VGG16 trunk."""
    return _explicit_file(path) is not None or (lpips_package_weights() is not None
                                                and torchvision_vgg16_weights().is_file())


def _no_weights_message(file: Path | None, need: list[str]) -> str:
    package = lpips_package_weights()
    trunk = torchvision_vgg16_weights()
    where = f"{file} has no {' and no '.join(need)}" if file is not None else (
        f"no weights file (pass a path or set {LPIPS_WEIGHTS_ENV}=/path/to/lpips_vgg.safetensors: torchvision vgg16 "
        "'features.*' keys + lpips 'lin{k}.model.1.weight' keys)")
    return (f"LPIPS needs local weights: {where}; the linear heads are also taken from the lpips package (pip install "
            f"lpips; {'found: ' + str(package) if package else 'not installed'}) and the VGG16 trunk from "
            f"torchvision's cache {trunk} ({'found' if trunk.is_file() else 'missing'}); nothing is downloaded "
            "(see cylindersplat.metrics.lpips)")


def load_lpips(path: str | os.PathLike | None = None, device=None) -> LPIPS:
    """Build :class:`LPIPS` from local weights: ``path`` or ``$CYLINDERSPLAT_LPIPS_WEIGHTS``, with the parts that
    file lacks (or everything, without a file) from the ``lpips`` package (heads) and torchvision's cache (trunk)."""
    file = _explicit_file(path)
    features: dict[str, Tensor] = {}
    lins: dict[int, Tensor] = {}
    trunk_source = linear_source = str(file)
    if file is not None:
        if not file.is_file():
            raise FileNotFoundError(f"LPIPS weights file not found: {file}")
        features, lins = _split_state(_read_weight_file(file))
        trunk_keys = [f"{layer[0]}.{p}" for layer in VGG16_CONV_LAYERS if layer != "M" for p in ("weight", "bias")]
        partial = [k for k in trunk_keys if k not in features] if features else []
        partial += [f"lin{k}" for k in range(5) if k not in lins] if lins else []
        if partial:  # a part the file has some of: a broken file, not completed from elsewhere
            raise ValueError(f"LPIPS {file}: missing entries {partial[:6]}{'...' if len(partial) > 6 else ''}")
    if not lins:
        package = lpips_package_weights()
        if package is None:
            need = ["linear heads (lin0..lin4)"] + ([] if features else ["VGG16 trunk"])
            raise FileNotFoundError(_no_weights_message(file, need))
        _, lins = _split_state(_read_weight_file(package))
        linear_source = str(package)
    if not features:
        trunk = torchvision_vgg16_weights()
        if not trunk.is_file():
            raise FileNotFoundError(_no_weights_message(file, ["VGG16 trunk (features.*)"]))
        features, _ = _split_state(_read_weight_file(trunk))
        trunk_source = str(trunk)
    model = LPIPS()
    model._load_parts(features, lins, trunk_source, linear_source)
    return model.to(device) if device is not None else model


_CACHE: dict[tuple[str, str], LPIPS] = {}


@torch.no_grad()
def lpips(pred: Float[Tensor, "*b 3 H W"], target: Float[Tensor, "*b 3 H W"], weights: str | None = None) -> Tensor:
    """LPIPS-VGG per image with a cached network (weights from ``weights`` or the env variable)."""
    key = (str(weights or os.environ.get(LPIPS_WEIGHTS_ENV, "")), str(pred.device))
    if key not in _CACHE:
        _CACHE[key] = load_lpips(weights, device=pred.device)
    return _CACHE[key](pred.float(), target.float()).to(pred.dtype)
