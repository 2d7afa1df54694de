"""LPIPS (VGG16 variant, Zhang et al. 2018) in plain torch, with weights from a local file.

Network: scaling layer ``(x - shift) / scale`` on inputs in ``[-1, 1]``; torchvision's VGG16
``features`` up to relu5_3, tapped after relu1_2, relu2_2, relu3_3, relu4_3, relu5_3; each tap is
unit-normalised over channels, the squared difference goes through a 1x1 linear head (no bias),
is averaged over space and summed over the five taps.

Weights (no downloads, ever): a ``.safetensors`` or ``.pth`` file given by path or by the
environment variable ``CYLINDERSPLAT_LPIPS_WEIGHTS`` holding

* VGG16 convolutions under torchvision keys ``features.{i}.weight/bias``
  (the ``lpips`` package's ``net.slice{k}.{i}.weight`` naming is accepted too), and
* the linear heads under ``lin{k}.model.1.weight`` (the ``lpips`` package's ``vgg.pth`` naming) or
  ``lin{k}.weight``, each of shape ``(1, C_k, 1, 1)``.

To build such a file: save torchvision's ``vgg16(weights="IMAGENET1K_V1").features`` state dict
(prefix ``features.``) together with the ``lpips`` package's ``weights/v0.1/vgg.pth``.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import torch
from jaxtyping import Float
from torch import Tensor, nn

from .image import check_image_pair

__all__ = ["LPIPS", "LPIPS_WEIGHTS_ENV", "VGG16_CONV_LAYERS", "LPIPS_TAPS", "lpips", "load_lpips"]

LPIPS_WEIGHTS_ENV = "CYLINDERSPLAT_LPIPS_WEIGHTS"
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

    def forward(self, pred: Float[Tensor, "B 3 H W"], target: Float[Tensor, "B 3 H W"]) -> Float[Tensor, "B"]:
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
        features: dict[str, Tensor] = {}
        lins: dict[int, Tensor] = {}
        for key, value in state.items():
            if m := re.fullmatch(r"(?:.*\.)?features\.(\d+)\.(weight|bias)", key):
                features[f"{m[1]}.{m[2]}"] = value
            elif m := re.fullmatch(r"(?:.*\.)?slice\d\.(\d+)\.(weight|bias)", key):
                features[f"{m[1]}.{m[2]}"] = value
            elif m := re.fullmatch(r"(?:.*\.)?lin(\d)(?:\.model\.1)?\.weight", key):
                lins[int(m[1])] = value
        expected = [f"{k}.{p}" for k in self.features for p in ("weight", "bias")]
        missing = [k for k in expected if k not in features] + [f"lin{k}" for k in range(5) if k not in lins]
        if missing:
            raise ValueError(f"LPIPS {source}: missing entries {missing[:6]}{'...' if len(missing) > 6 else ''}")
        for name in expected:
            index, param = name.split(".")
            getattr(self.features[index], param).data.copy_(features[name])
        for k, lin in enumerate(self.lins):
            lin.weight.data.copy_(lins[k].reshape(lin.weight.shape))


def _read_weight_file(path: Path) -> dict[str, Tensor]:
    if path.suffix == ".safetensors":
        from safetensors.torch import load_file

        return load_file(str(path))
    state = torch.load(path, map_location="cpu", weights_only=True)
    if isinstance(state, dict) and "state_dict" in state:
        state = state["state_dict"]
    return state


def load_lpips(path: str | os.PathLike | None = None, device=None) -> LPIPS:
    """Build :class:`LPIPS` with weights from ``path`` or ``$CYLINDERSPLAT_LPIPS_WEIGHTS``."""
    raw = path if path is not None else os.environ.get(LPIPS_WEIGHTS_ENV)
    if not raw:
        raise FileNotFoundError(
            "LPIPS needs local weights: pass a path or set "
            f"{LPIPS_WEIGHTS_ENV}=/path/to/lpips_vgg.safetensors (torchvision vgg16 'features.*' keys + "
            "lpips 'lin{k}.model.1.weight' keys; see cylindersplat.metrics.lpips)"
        )
    file = Path(raw)
    if not file.is_file():
        raise FileNotFoundError(f"LPIPS weights file not found: {file}")
    model = LPIPS()
    model.load_external(_read_weight_file(file), source=str(file))
    return model.to(device) if device is not None else model


_CACHE: dict[tuple[str, str], LPIPS] = {}


@torch.no_grad()
def lpips(pred: Float[Tensor, "*b 3 H W"], target: Float[Tensor, "*b 3 H W"], weights: str | None = None) -> Tensor:
    """LPIPS-VGG per image with a cached network (weights from ``weights`` or the env variable)."""
    key = (str(weights or os.environ.get(LPIPS_WEIGHTS_ENV, "")), str(pred.device))
    if key not in _CACHE:
        _CACHE[key] = load_lpips(weights, device=pred.device)
    return _CACHE[key](pred.float(), target.float()).to(pred.dtype)
