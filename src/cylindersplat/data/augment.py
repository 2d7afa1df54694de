"""Training samples that look like captures (``data.augment=captures``): what procedural data lacks.

Procedural rooms give every view the same exposure and white balance, exact poses and clean pixels; real captures do
not. :func:`augment_captures` changes the **context** views of a :class:`~cylindersplat.data.sample.Sample` as a
capture would (the targets stay clean: they are what the model must reproduce, and a target's own exposure is
something the model cannot know). Per context view, in this order:

* exposure: one gain, log-uniform in :attr:`CaptureAugment.exposure` (``[0.8, 1.25]``), times a white balance of
  one gain per channel, uniform in ``1 +- white_balance`` (5 %), on the stored (sRGB) values;
* sensor noise: Gaussian of std-dev :attr:`CaptureAugment.noise_sigma` (0.01) per pixel and channel;
* JPEG: the panorama re-encoded with Pillow at a quality drawn in :attr:`CaptureAugment.jpeg_quality` (75-95);
* pose error: the camera rotated in its own frame by an angle uniform in ``[0, rotation_deg]`` (0.5 degree) about a
  random axis, and its centre moved by a distance uniform in ``[0, translation_m]`` (1 cm) in a random direction.

Images are clipped to ``[0, 1]`` after each step. Depth priors and ground truth are left alone (the prior's own
errors are ``data.depth_prior=degraded:KIND`` or ``mixed:A+B``). Every draw comes from a generator keyed by
``(seed, sample key, view, effect)``, so a sample is the same in every run and epoch, and switching one effect off
leaves the others' draws as they were.
"""

from __future__ import annotations

import hashlib
import io
import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import torch
from PIL import Image
from torch import Tensor
from torch.utils.data import Dataset

from ..geometry.rotations import axis_angle_to_matrix
from .sample import Sample

__all__ = ["AUGMENTS", "CaptureAugment", "augment_captures", "CaptureAugmentedDataset", "sample_key"]

AUGMENTS = ("none", "captures")


@dataclass
class CaptureAugment:
    """Magnitudes of ``data.augment=captures`` (``data.captures.*``); each effect is off at its neutral value."""

    exposure: tuple[float, float] = (0.8, 1.25)  # per-view gain, log-uniform in [low, high]; [1, 1] = off
    white_balance: float = 0.05  # per-channel gain uniform in 1 +- this; 0 = off
    noise_sigma: float = 0.01  # Gaussian sensor noise (std-dev, image units); 0 = off
    jpeg: bool = True  # re-encode each context panorama as JPEG
    jpeg_quality: tuple[int, int] = (75, 95)  # quality drawn uniformly in [low, high] (integers)
    rotation_deg: float = 0.5  # pose error: rotation angle uniform in [0, this] degrees, random axis; 0 = off
    translation_m: float = 0.01  # pose error: centre moved by a distance uniform in [0, this] metres; 0 = off
    seed: int = 0  # one seed for every draw (with the sample's key)

    def validate(self, where: str = "data.captures") -> None:
        """One-line ``ValueError`` naming the setting when a magnitude is out of range."""
        if len(self.exposure) != 2 or not 0 < float(self.exposure[0]) <= float(self.exposure[1]):
            raise ValueError(f"{where}.exposure must be [low, high] with 0 < low <= high, e.g. [0.8, 1.25]; "
                             f"got {list(self.exposure)}")
        if not 0 <= self.white_balance < 1:
            raise ValueError(f"{where}.white_balance must be in [0, 1) (a share, 0.05 = 5 %), got {self.white_balance}")
        if self.noise_sigma < 0:
            raise ValueError(f"{where}.noise_sigma must be >= 0, got {self.noise_sigma}")
        q = self.jpeg_quality
        if len(q) != 2 or not 1 <= q[0] <= q[1] <= 100 or any(int(x) != x for x in q):
            raise ValueError(f"{where}.jpeg_quality must be [low, high] whole numbers with 1 <= low <= high <= 100, "
                             f"e.g. [75, 95]; got {list(q)}")
        if not 0 <= self.rotation_deg <= 180:
            raise ValueError(f"{where}.rotation_deg must be in [0, 180], got {self.rotation_deg}")
        if self.translation_m < 0:
            raise ValueError(f"{where}.translation_m must be >= 0, got {self.translation_m}")


def _generator(seed: int, key: str, view: int, effect: str) -> torch.Generator:
    digest = hashlib.sha256(f"captures:{seed}:{key}:{view}:{effect}".encode()).digest()
    return torch.Generator().manual_seed(int.from_bytes(digest[:8], "little") & (2**63 - 1))


def _uniform(generator: torch.Generator, low: float, high: float, size: tuple[int, ...] = ()) -> Tensor:
    return low + (high - low) * torch.rand(size, generator=generator, dtype=torch.float64)


def _unit_vector(generator: torch.Generator) -> Tensor:
    v = torch.randn(3, generator=generator, dtype=torch.float64)
    return v / v.norm().clamp_min(1e-12)


def _jpeg(image: Tensor, quality: int) -> Tensor:
    """``(3, H, W)`` in [0, 1] -> the same after an 8-bit JPEG round trip at ``quality``."""
    array = (image.permute(1, 2, 0).clamp(0, 1).numpy() * 255.0).round().astype(np.uint8)
    buffer = io.BytesIO()
    Image.fromarray(array, mode="RGB").save(buffer, format="JPEG", quality=int(quality))
    buffer.seek(0)
    with Image.open(buffer) as decoded:
        out = np.asarray(decoded.convert("RGB"), dtype=np.float32) / 255.0
    return torch.from_numpy(out.copy()).permute(2, 0, 1).to(image.dtype)


def _perturb_pose(c2w: Tensor, cfg: CaptureAugment, generator: torch.Generator) -> Tensor:
    """``c2w`` (4x4) with its camera rotated in its own frame and its centre moved (float64 maths, rigid)."""
    angle = math.radians(cfg.rotation_deg) * float(torch.rand((), generator=generator, dtype=torch.float64))
    axis = _unit_vector(generator)
    distance = cfg.translation_m * float(torch.rand((), generator=generator, dtype=torch.float64))
    direction = _unit_vector(generator)
    pose = c2w.double().clone()
    pose[:3, :3] = pose[:3, :3] @ axis_angle_to_matrix((axis * angle).tolist())
    pose[:3, 3] = pose[:3, 3] + distance * direction
    return pose.to(c2w.dtype)


def augment_captures(sample: Sample, cfg: CaptureAugment, key: str) -> Sample:
    """``sample`` with its context images and poses changed as a capture's would be (module docstring); ``key``
    names the sample (the same key and ``cfg.seed`` give the same draws). Targets, depths and priors are kept."""
    images, poses = [], []
    low, high = (math.log(float(x)) for x in cfg.exposure)
    for view, (image, pose) in enumerate(zip(sample.context_images, sample.context_poses)):
        out = image.float()
        g = _generator(cfg.seed, key, view, "exposure")
        gain = math.exp(float(_uniform(g, low, high)))
        balance = _uniform(g, 1 - cfg.white_balance, 1 + cfg.white_balance, (3,))
        out = (out * (gain * balance).float()[:, None, None]).clamp(0, 1)
        if cfg.noise_sigma > 0:
            g = _generator(cfg.seed, key, view, "noise")
            out = (out + cfg.noise_sigma * torch.randn(out.shape, generator=g)).clamp(0, 1)
        if cfg.jpeg:
            g = _generator(cfg.seed, key, view, "jpeg")
            quality = int(torch.randint(int(cfg.jpeg_quality[0]), int(cfg.jpeg_quality[1]) + 1, (), generator=g))
            out = _jpeg(out, quality)
        images.append(out.to(image.dtype))
        if cfg.rotation_deg > 0 or cfg.translation_m > 0:
            pose = _perturb_pose(pose, cfg, _generator(cfg.seed, key, view, "pose"))
        poses.append(pose)
    metadata = {**sample.metadata, "augment": "captures"}
    return replace(sample, context_images=torch.stack(images), context_poses=torch.stack(poses), metadata=metadata)


def sample_key(index: int, metadata: dict[str, Any]) -> str:
    """The key of a dataset's sample ``index``: its position, dataset, scene and context frames."""
    return (f"{index}:{metadata.get('dataset')}/{metadata.get('scene')}:"
            f"{','.join(map(str, metadata.get('context_indices', ())))}")


class CaptureAugmentedDataset(Dataset):
    """``dataset`` whose samples go through :func:`augment_captures` (for training only: evaluation reads the
    dataset itself). Attributes other than ``__getitem__`` / ``__len__`` are the wrapped dataset's."""

    def __init__(self, dataset: Dataset, cfg: CaptureAugment | None = None) -> None:
        self.dataset = dataset
        self.augment = cfg or CaptureAugment()
        self.augment.validate()

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, index: int) -> Sample:
        sample = self.dataset[index]
        return augment_captures(sample, self.augment, sample_key(index, sample.metadata))

    def __getattr__(self, name: str):
        if name == "dataset":  # not yet set (unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.dataset, name)
