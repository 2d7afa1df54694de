"""Depth colouring (utils.colormap) against its definition: Turbo's keys interpolated linearly, in inverse depth
between ``near`` (first key) and ``far`` (last key), invalid pixels in their own colour."""

import numpy as np
import pytest
import torch

from cylindersplat.utils.colormap import TURBO_KEYS, apply_colormap, colorize_depth


def turbo(t):
    """The keys interpolated channel by channel (numpy's interp): the independent reference."""
    at = np.linspace(0.0, 1.0, len(TURBO_KEYS))
    return np.stack([np.interp(np.clip(t, 0, 1), at, TURBO_KEYS[:, c]) for c in range(3)], -1)


def test_apply_colormap_interpolates_the_keys():
    t = np.concatenate((np.linspace(0, 1, 1001), [-0.5, 1.5, np.nan]))
    expected = turbo(np.nan_to_num(t, nan=0.0))
    np.testing.assert_allclose(apply_colormap(t), expected, atol=1e-12)
    np.testing.assert_allclose(apply_colormap(np.linspace(0, 1, 9)), TURBO_KEYS, atol=1e-12)


def test_colorize_depth_is_turbo_of_inverse_depth_between_near_and_far():
    near, far = 0.5, 8.0
    depth = np.array([[0.5, 0.7, 1.0, 2.0], [3.0, 5.0, 8.0, 20.0], [0.1, 0.0, -1.0, np.nan], [np.inf, 4.0, 6.0, 7.9]])
    got = colorize_depth(depth, near, far, invalid_color=(0.2, 0.4, 0.6))
    assert isinstance(got, torch.Tensor) and got.shape == (3, 4, 4) and got.dtype == torch.float32
    valid = np.isfinite(depth) & (depth > 0)
    t = (1 / near - 1 / np.clip(np.where(valid, depth, far), near, far)) / (1 / near - 1 / far)
    expected = np.where(valid[..., None], turbo(t), [0.2, 0.4, 0.6])
    np.testing.assert_allclose(got.permute(1, 2, 0).numpy(), expected, atol=5e-4)  # (a 4096-step table)
    np.testing.assert_allclose(got[:, 0, 0].numpy(), TURBO_KEYS[0], atol=1e-6)  # near: the first key, exactly
    np.testing.assert_allclose(got[:, 1, 2].numpy(), TURBO_KEYS[-1], atol=1e-6)  # far: the last
    as_uint8 = colorize_depth(depth, near, far, invalid_color=(0.2, 0.4, 0.6), as_uint8=True)
    assert as_uint8.dtype == np.uint8 and as_uint8.shape == (4, 4, 3)
    assert np.abs(as_uint8.astype(int) - np.round(expected * 255)).max() <= 1


def test_colorize_depth_defaults_to_the_2nd_and_98th_percentiles():
    depth = np.random.default_rng(0).uniform(0.5, 10.0, (64, 128))
    depth[::5, ::3] = 0.0  # invalid pixels do not count
    low, high = np.percentile(depth[depth > 0], [2, 98])
    np.testing.assert_array_equal(colorize_depth(depth, as_uint8=True), colorize_depth(depth, low, high, as_uint8=True))
    assert np.array_equal(colorize_depth(np.zeros((2, 3)), as_uint8=True), np.zeros((2, 3, 3), np.uint8))  # none valid
    with pytest.raises(ValueError, match=r"\(H, W\)"):
        colorize_depth(np.ones((1, 2, 3)))
