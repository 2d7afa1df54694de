"""Image and depth metrics against skimage and straightforward numpy references."""

import math

import numpy as np
import pytest
import torch
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from cylindersplat.metrics import (
    DepthRange,
    abs_rel,
    delta1,
    depth_metrics,
    lrce,
    pcc,
    psnr,
    rmse,
    ssim,
    ws_psnr,
)


def _pair(seed, shape=(2, 3, 16, 32)):
    g = torch.Generator().manual_seed(seed)
    a = torch.rand(shape, generator=g, dtype=torch.float64)
    b = (a + 0.1 * torch.randn(shape, generator=g, dtype=torch.float64)).clamp(0, 1)
    return a, b


def _structured(h=24, w=48):
    y, x = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    img = np.stack([np.sin(8 * x) * 0.5 + 0.5, (x + y) / 2, ((x * 6).astype(int) % 2) * 0.8 + 0.1])
    other = np.clip(img + 0.05 * np.cos(20 * y)[None], 0, 1)
    return torch.from_numpy(img)[None], torch.from_numpy(other)[None]


def _ws_psnr_numpy(a, b):
    h = a.shape[-2]
    w = np.sin(np.pi * (np.arange(h) + 0.5) / h)[:, None]
    err = (np.clip(a, 0, 1) - np.clip(b, 0, 1)) ** 2  # (3, H, W)
    wmse = (err * w).sum() / (w.sum() * a.shape[-1] * 3)
    return 10 * np.log10(1.0 / wmse)


@pytest.mark.parametrize("make", [lambda: _pair(0), _structured])
@pytest.mark.parametrize("sample_cov", [False, True])
def test_ssim_matches_skimage(make, sample_cov):
    a, b = make()
    ours = ssim(a, b, use_sample_covariance=sample_cov)
    for k in range(a.shape[0]):
        ref = structural_similarity(
            a[k].numpy(), b[k].numpy(), gaussian_weights=True, sigma=1.5,
            use_sample_covariance=sample_cov, data_range=1.0, channel_axis=0,
        )
        assert abs(float(ours[k]) - ref) < 1e-5


def test_ssim_float32_and_batch_dims():
    a, b = _pair(1, (2, 2, 3, 16, 32))
    ours = ssim(a.float(), b.float())
    assert ours.shape == (2, 2) and ours.dtype == torch.float32
    ref = structural_similarity(a[1, 0].numpy(), b[1, 0].numpy(), gaussian_weights=True, sigma=1.5,
                                data_range=1.0, channel_axis=0)  # skimage's defaults otherwise, as PanSplat
    assert abs(float(ours[1, 0]) - ref) < 1e-5
    assert torch.allclose(ssim(a, a), torch.ones(2, 2, dtype=torch.float64))


def test_psnr_matches_skimage_and_clips():
    a, b = _pair(2)
    ours = psnr(a, b)
    for k in range(2):
        assert abs(float(ours[k]) - peak_signal_noise_ratio(a[k].numpy(), b[k].numpy(), data_range=1.0)) < 1e-6
    # Clipping: values outside [0, 1] count as the nearest bound.
    assert torch.allclose(psnr(a * 0 + 1.5, a * 0 + 0.9), psnr(a * 0 + 1.0, a * 0 + 0.9))


def test_ws_psnr_reference_and_constant_error():
    a, b = _pair(3)
    ours = ws_psnr(a, b)
    for k in range(2):
        assert abs(float(ours[k]) - _ws_psnr_numpy(a[k].numpy(), b[k].numpy())) < 1e-6
    # A spatially constant error makes the weights irrelevant: WS-PSNR == PSNR == -10 log10(e^2).
    base = torch.full((1, 3, 8, 16), 0.5, dtype=torch.float64)
    assert abs(float(ws_psnr(base + 0.1, base)) - float(psnr(base + 0.1, base))) < 1e-9
    assert abs(float(ws_psnr(base + 0.1, base)) - 20.0) < 1e-9


def test_ws_psnr_weights_rows_not_channels():
    # Error only at the poles weighs little; the same error on the equator weighs a lot.
    base = torch.zeros(1, 3, 16, 32)
    polar, equator = base.clone(), base.clone()
    polar[..., 0, :] = 1.0
    equator[..., 8, :] = 1.0
    assert ws_psnr(polar, base) > ws_psnr(equator, base) + 10


def test_layout_checks():
    a = torch.rand(1, 16, 32, 3)
    with pytest.raises(ValueError, match="channel-last"):
        ws_psnr(a, a)
    with pytest.raises(ValueError, match="W == 2H"):
        ws_psnr(torch.rand(1, 3, 16, 16), torch.rand(1, 3, 16, 16))
    with pytest.raises(ValueError, match="differ in shape"):
        psnr(torch.rand(1, 3, 8, 16), torch.rand(2, 3, 8, 16))


def test_depth_metrics_against_numpy():
    g = torch.Generator().manual_seed(4)
    gt = torch.rand(2, 8, 16, generator=g, dtype=torch.float64) * 12
    pred = gt * (1 + 0.3 * torch.randn(2, 8, 16, generator=g, dtype=torch.float64))
    gt[0, 0, :4] = 0.0  # holes
    out = depth_metrics(pred, gt)
    for k in range(2):
        p, t = pred[k].numpy(), gt[k].numpy()
        m = (t > 0.45) & (t < 10)
        p, t = p[m], t[m]
        assert abs(float(out["abs_rel"][k]) - np.mean(np.abs(p - t) / t)) < 1e-9
        assert abs(float(out["rmse"][k]) - np.sqrt(np.mean((p - t) ** 2))) < 1e-9
        ratio = np.maximum(np.clip(p, 1e-12, None) / t, t / np.clip(p, 1e-12, None))
        assert abs(float(out["delta1"][k]) - np.mean((ratio < 1.25) & (p > 0))) < 1e-9
        assert abs(float(out["pcc"][k]) - np.corrcoef(p, t)[0, 1]) < 1e-9


def test_depth_metrics_known_values_and_range():
    gt = torch.full((1, 4, 8), 2.0)
    assert float(abs_rel(gt * 1.1, gt)) == pytest.approx(0.1, abs=1e-6)
    assert float(rmse(gt + 0.5, gt)) == pytest.approx(0.5, abs=1e-6)
    assert float(delta1(gt * 1.3, gt)) == 0.0 and float(delta1(gt * 1.2, gt)) == 1.0
    # Nothing valid in a custom range -> NaN, not 0.
    assert math.isnan(float(rmse(gt, gt, depth_range=DepthRange(3.0, 5.0))))
    ramp = torch.linspace(1, 5, 32).view(1, 4, 8)
    assert float(pcc(3 * ramp + 1, ramp)) == pytest.approx(1.0, abs=1e-6)
    assert float(pcc(-ramp, ramp)) == pytest.approx(-1.0, abs=1e-6)


def test_lrce_is_the_seam_error_relative_to_the_reference():
    # The released evaluation's formula written out: mean over rows of |(p0 - pW) - (t0 - tW)|.
    h, w = 4, 8
    target = torch.full((2, h, w), 3.0)
    target[..., 0] = torch.tensor([2.0, 3.0, 4.0, 5.0])  # the truth itself has a step at the seam
    pred = target.clone()
    assert torch.equal(lrce(pred, target), torch.zeros(2))  # matching the truth's seam: no error
    pred[0, :, -1] += torch.tensor([0.4, -0.4, 0.0, 0.8])
    assert float(lrce(pred, target)[0]) == pytest.approx((0.4 + 0.4 + 0.0 + 0.8) / 4)
    # A blurred render that is seamless where the truth is not is penalised (the old reference-free LRCE gave it 0).
    flat = torch.full((1, h, w), 3.0)
    assert float(lrce(flat, target[:1])) == pytest.approx((1 + 0 + 1 + 2) / 4)
    # Rows whose reference end pixels are not valid depths do not count; none valid: NaN.
    holes = target[:1].clone()
    holes[0, 0, 0] = 0.0
    assert float(lrce(flat, holes)) == pytest.approx((0 + 1 + 2) / 3)
    assert math.isnan(float(lrce(flat, torch.zeros_like(flat))))
    # RGB variant, relative too: channels and rows averaged.
    img, ref = torch.zeros(1, 3, h, w), torch.zeros(1, 3, h, w)
    img[..., -1] = 0.5
    assert float(lrce(img, ref, channel_dim=True, depth_range=None)) == pytest.approx(0.5)
    with pytest.raises(ValueError, match="differ in shape"):
        lrce(flat, target)
