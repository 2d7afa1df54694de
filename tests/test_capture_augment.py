"""Issue 34: ``data.augment=captures``, training samples that look like captures (cylindersplat.data.augment).

Each check is against an independent reference: the unaugmented dataset, a flat colour divided before/after, the
rotation angle from the trace, Pillow's own JPEG round trip."""

from __future__ import annotations

import io
import math
from dataclasses import fields

import numpy as np
import pytest
import torch
from PIL import Image

from cylindersplat.data.augment import CaptureAugment, CaptureAugmentedDataset, augment_captures
from cylindersplat.data.datasets import make_dataset
from cylindersplat.data.sample import Sample
from cylindersplat.geometry.rotations import axis_angle_to_matrix
from cylindersplat.training.config import load_config
from cylindersplat.training.data import build_dataset

OFF = dict(exposure=(1.0, 1.0), white_balance=0.0, noise_sigma=0.0, jpeg=False, rotation_deg=0.0, translation_m=0.0)


def _pose(seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    pose = torch.eye(4)
    pose[:3, :3] = axis_angle_to_matrix(torch.randn(3, generator=g, dtype=torch.float64).tolist()).float()
    pose[:3, 3] = torch.randn(3, generator=g)
    return pose


def _sample(image: torch.Tensor | None = None, views: int = 2, h: int = 16, w: int = 32) -> Sample:
    g = torch.Generator().manual_seed(1)
    ctx = image.expand(views, 3, h, w).clone() if image is not None else torch.rand(views, 3, h, w, generator=g)
    return Sample(context_images=ctx, context_priors=torch.full((views, h, w), 2.0),
                  context_poses=torch.stack([_pose(i) for i in range(views)]),
                  target_images=torch.rand(1, 3, h, w, generator=g), target_depths=torch.full((1, h, w), 2.0),
                  target_poses=_pose(9)[None], metadata={"scene": "s"})


def _config(*overrides: str):
    return load_config("tiny", list(overrides)).data


def _assert_same(a: Sample, b: Sample, skip: tuple[str, ...] = ()) -> None:
    for f in fields(Sample):
        if f.name in skip:
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, torch.Tensor):
            assert x.dtype == y.dtype and torch.equal(x, y), f.name
        else:
            assert x == y, f.name


def test_none_is_todays_dataset_byte_for_byte(synth_dataset):
    root = synth_dataset(2, 0)
    cfg = _config(f"data.root={root}")
    assert cfg.augment == "none"
    dataset, today = build_dataset(cfg), make_dataset("synthetic", root, split="train", resolution=cfg.resolution)
    assert type(dataset) is type(today)
    for i in range(len(today)):
        _assert_same(dataset[i], today[i])


def test_captures_changes_only_context_images_and_poses(synth_dataset):
    root = synth_dataset(2, 0)
    cfg = _config(f"data.root={root}", "data.augment=captures")
    dataset, today = build_dataset(cfg), make_dataset("synthetic", root, split="train", resolution=cfg.resolution)
    assert isinstance(dataset, CaptureAugmentedDataset) and len(dataset) == len(today)
    assert dataset.depth_prior.spec == today.depth_prior.spec  # the wrapped dataset's attributes
    for i in range(len(today)):
        new, old = dataset[i], today[i]
        _assert_same(new, old, skip=("context_images", "context_poses", "metadata"))
        assert new.metadata == {**old.metadata, "augment": "captures"}
        assert not torch.equal(new.context_images, old.context_images)
        assert not torch.equal(new.context_poses, old.context_poses)
        assert new.context_images.dtype == old.context_images.dtype
        assert 0 <= float(new.context_images.min()) and float(new.context_images.max()) <= 1
        # a mild change: within the exposure, noise and JPEG budget on average
        assert float((new.context_images - old.context_images).abs().mean()) < 0.15
    again = build_dataset(_config(f"data.root={root}", "data.augment=captures"))  # a second run
    _assert_same(again[1], dataset[1])


def test_the_draws_are_keyed_by_seed_and_sample():
    sample, cfg = _sample(), CaptureAugment()
    a, b = augment_captures(sample, cfg, "k1"), augment_captures(sample, cfg, "k1")
    _assert_same(a, b)
    for other in (augment_captures(sample, cfg, "k2"), augment_captures(sample, CaptureAugment(seed=1), "k1")):
        assert not torch.equal(other.context_images, a.context_images)
        assert not torch.equal(other.context_poses, a.context_poses)
    assert not torch.equal(a.context_images[0] - sample.context_images[0],
                           a.context_images[1] - sample.context_images[1])  # each view its own draw
    # switching one effect off keeps the other effects' draws
    no_noise = augment_captures(sample, CaptureAugment(noise_sigma=0.0), "k1")
    assert torch.equal(no_noise.context_poses, a.context_poses)


def test_images_stay_in_unit_range_at_the_extremes():
    extremes = torch.tensor([0.0, 1.0, 0.999]).repeat(16 * 32)[: 3 * 16 * 32].reshape(3, 16, 32)
    cfg = CaptureAugment(exposure=(0.5, 2.0), white_balance=0.3, noise_sigma=0.2)
    for key in range(10):
        out = augment_captures(_sample(extremes), cfg, str(key)).context_images
        assert torch.isfinite(out).all() and 0 <= float(out.min()) and float(out.max()) <= 1


@pytest.mark.parametrize("rotation_deg,translation_m", [(0.5, 0.01), (30.0, 0.5)])
def test_poses_stay_rigid_within_the_bounds(rotation_deg, translation_m):
    sample = _sample(views=4)
    cfg = CaptureAugment(rotation_deg=rotation_deg, translation_m=translation_m)
    angles, shifts = [], []
    for key in range(25):
        out = augment_captures(sample, cfg, f"pose{key}")
        assert torch.equal(out.target_poses, sample.target_poses)
        for new, old in zip(out.context_poses.double(), sample.context_poses.double()):
            r = new[:3, :3]
            assert torch.allclose(r.T @ r, torch.eye(3, dtype=torch.float64), atol=1e-5)
            assert abs(float(torch.linalg.det(r)) - 1) < 1e-5
            assert torch.equal(new[3], torch.tensor([0.0, 0, 0, 1], dtype=torch.float64))
            relative = old[:3, :3].T @ r  # the perturbation, whichever frame it was applied in
            cosine = (float(torch.trace(relative)) - 1) / 2
            angles.append(math.degrees(math.acos(max(-1.0, min(1.0, cosine)))))
            shifts.append(float((new[:3, 3] - old[:3, 3]).norm()))
    tolerance = 2e-3 if rotation_deg < 1 else 1e-4  # the float32 poses' rounding, seen through acos
    assert max(angles) <= rotation_deg + tolerance and max(shifts) <= translation_m + 1e-6
    assert max(angles) > 0.8 * rotation_deg and min(angles) < 0.3 * rotation_deg  # uniform in [0, bound]
    assert max(shifts) > 0.8 * translation_m and min(shifts) < 0.3 * translation_m


def test_exposure_and_white_balance_gains_fall_in_their_ranges():
    colour = torch.tensor([0.4, 0.5, 0.6])[:, None, None].expand(3, 16, 32)
    sample = _sample(colour, views=3)
    cfg = CaptureAugment(**{**OFF, "exposure": (0.8, 1.25), "white_balance": 0.05})
    gains = []
    for key in range(40):
        out = augment_captures(sample, cfg, str(key))
        assert torch.equal(out.context_poses, sample.context_poses)
        ratio = out.context_images / sample.context_images  # (V, 3, H, W)
        per_view = ratio[..., :1, :1]
        assert torch.allclose(ratio, per_view.expand_as(ratio), atol=1e-6)  # one gain per view and channel
        gains.append(per_view.flatten(1).double())
    gains = torch.cat(gains)  # (views, 3)
    assert 0.8 * 0.95 - 1e-6 <= float(gains.min()) and float(gains.max()) <= 1.25 * 1.05 + 1e-6
    balance = gains[:, :, None] / gains[:, None, :]  # the exposure cancels: channel over channel
    assert float(balance.max()) <= 1.05 / 0.95 + 1e-6
    exposure = gains.mean(1)  # about the exposure gain (the balance's mean is 1 +- 0.05 / sqrt(3))
    assert float(exposure.min()) < 0.87 and float(exposure.max()) > 1.15  # the whole range is drawn
    assert float(balance.max()) > 1.04  # the balance is drawn too (channels up to 10 % apart)


def test_sensor_noise_has_the_configured_sigma():
    sample = _sample(torch.full((3, 1, 1), 0.5), h=64, w=128)
    out = augment_captures(sample, CaptureAugment(**{**OFF, "noise_sigma": 0.01}), "n")
    noise = out.context_images - sample.context_images
    assert abs(float(noise.std()) - 0.01) < 0.0005 and abs(float(noise.mean())) < 0.0005


def test_jpeg_is_pillows_round_trip_at_a_quality_in_range():
    sample = _sample()
    out = augment_captures(sample, CaptureAugment(**{**OFF, "jpeg": True, "jpeg_quality": (75, 95)}), "j")
    for new, old in zip(out.context_images, sample.context_images):
        array = (old.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
        matches = []
        for quality in range(1, 101):
            buffer = io.BytesIO()
            Image.fromarray(array).save(buffer, format="JPEG", quality=quality)
            decoded = np.asarray(Image.open(io.BytesIO(buffer.getvalue())).convert("RGB"), dtype=np.float32) / 255
            if np.array_equal(decoded, new.permute(1, 2, 0).numpy()):
                matches.append(quality)
        assert matches and all(75 <= q <= 95 for q in matches), matches


@pytest.mark.parametrize("override,message", [
    ("data.augment=jpeg", "data.augment must be one of none, captures; got 'jpeg'"),
    ("data.captures.exposure=[1.25, 0.8]", "data.captures.exposure must be [low, high] with 0 < low <= high"),
    ("data.captures.jpeg_quality=[75, 101]", "data.captures.jpeg_quality must be [low, high] whole numbers"),
    ("data.captures.noise_sigma=-0.1", "data.captures.noise_sigma must be >= 0, got -0.1"),
])
def test_bad_settings_name_the_setting(override, message):
    with pytest.raises(ValueError, match=f"^{message.replace('[', '.').replace(']', '.')}"):
        load_config("tiny", [override])
