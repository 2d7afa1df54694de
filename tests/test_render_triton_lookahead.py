"""The compositing kernels' lookahead (``triton_backend.LOOKAHEAD``, issue 35): with ``"row"`` each pair's whole row
is loaded while the pair before it is composited (its Gaussian's id two pairs ahead) instead of when its own turn
comes. Only the loads move: the images and gradients are those of ``"id"`` bit for bit in Triton's interpreter - with
pixel rectangles read or computed (``PAIR_FIELD``), both forwards, across the seam and on pinhole views, tiles with
one pair or none, and float64 Gaussians (the packed rows). Compiled for a GPU, to float32 rounding (pinhole views
with computed rectangles differed by up to 2.4e-7 on an H100, 2026-11-27). Without a GPU the kernels run in Triton's
interpreter (conftest.py)."""

import pytest
import torch

pytest.importorskip("triton")

from cylindersplat.gaussians import Gaussians  # noqa: E402
from cylindersplat.render import Equirect, Pinhole, RasterSettings, render, triton_backend, triton_binning  # noqa: E402
from render_scenes import shell_scene, yaw_pose  # noqa: E402
from test_render_triton_ids import assert_same_gradient, assert_same_image  # noqa: E402

DEVICE = "cuda" if torch.cuda.is_available() else "cpu"
F32 = torch.float32
K = torch.tensor([[14.0, 0.0, 12.3], [0.0, 15.0, 9.6], [0.0, 0.0, 1.0]])


def _outputs_and_gradients(monkeypatch, g, poses, camera, lookahead, **switches):
    monkeypatch.setattr(triton_backend, "LOOKAHEAD", lookahead)
    for name, value in switches.items():
        monkeypatch.setattr(triton_backend, name, value)
    monkeypatch.setattr(triton_binning, "_CAPACITY", {})
    params = {k: v.detach().to(DEVICE).clone().requires_grad_() for k, v in g.tensors().items()}
    out = render(Gaussians(**params), poses.to(DEVICE), camera, background=(0.2, 0.3, 0.4), backend="triton",
                 settings=RasterSettings(tile_size=8))
    gen = torch.Generator().manual_seed(7)
    weights = [torch.randn(t.shape, generator=gen).to(DEVICE) for t in (out.rgb, out.depth, out.alpha)]
    loss = sum((w * t).sum() for w, t in zip(weights, (out.rgb, out.depth, out.alpha)))
    grads = torch.autograd.grad(loss, list(params.values()), allow_unused=True)
    return [out.rgb, out.depth, out.alpha, *(x for x in grads if x is not None)]


def _assert_same(monkeypatch, g, poses, camera, **switches):
    by_id, by_row = (_outputs_and_gradients(monkeypatch, g, poses, camera, look, **switches) for look in ("id", "row"))
    assert len(by_id) == len(by_row) > 3
    for name, a, b in zip(("rgb", "depth", "alpha"), by_id[:3], by_row[:3]):
        assert_same_image(b, a, name)
    for a, b in zip(by_id[3:], by_row[3:]):  # the gradients: bit for bit where the atomics' order is fixed
        assert_same_gradient(b, a, "gradient")
    return by_id


@pytest.mark.parametrize("forward, pair_field", [("default", "rects"), ("default", "ids"), ("lean", "ids")])
def test_loading_the_next_row_ahead_changes_no_bit_across_the_seam(monkeypatch, forward, pair_field):
    # Close, wide footprints across the seam (some meet a tile twice), two cameras; some tiles hold a single pair.
    g = shell_scene(12, seed=36, scale=(0.3, 0.8), radius=(0.4, 1.0), dtype=F32)
    poses = torch.stack([yaw_pose(0.3, dtype=F32), yaw_pose(2.0, (0.1, -0.2, 0.1), dtype=F32)])
    rgb = _assert_same(monkeypatch, g, poses, Equirect(16, 32), FORWARD=forward, PAIR_FIELD=pair_field)[0]
    assert rgb.std() > 0.05


def test_loading_the_next_row_ahead_changes_no_bit_on_pinhole_views_with_empty_tiles(monkeypatch):
    g = shell_scene(6, seed=5, scale=(0.05, 0.2), dtype=F32)  # small footprints: most tiles empty or with one pair
    out = _assert_same(monkeypatch, g, yaw_pose(0.7, dtype=F32), Pinhole(K, 20, 24), PAIR_FIELD="ids")
    alpha = out[2]
    assert (alpha == 0).float().mean() > 0.3 and alpha.max() > 0


def test_loading_the_next_row_ahead_of_packed_rows_and_an_empty_scene(monkeypatch):
    g = shell_scene(10, seed=39, scale=(0.1, 0.5), dtype=torch.float64)  # pack_projected's rows
    _assert_same(monkeypatch, g, yaw_pose(0.4, dtype=torch.float64), Equirect(8, 16))
    monkeypatch.setattr(triton_backend, "LOOKAHEAD", "row")
    out = render(Gaussians.empty().to(DEVICE), torch.eye(4, device=DEVICE), Equirect(8, 16), backend="triton")
    assert torch.equal(out.alpha, torch.zeros_like(out.alpha))


def test_an_unknown_lookahead_is_refused_by_name(monkeypatch):
    monkeypatch.setattr(triton_backend, "LOOKAHEAD", "far")
    with pytest.raises(ValueError, match="unknown Triton lookahead 'far': choose one of row, id"):
        render(shell_scene(4, seed=1, dtype=F32).to(DEVICE), torch.eye(4, device=DEVICE), Equirect(8, 16),
               backend="triton")
