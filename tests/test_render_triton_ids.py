"""Pairs that carry only their Gaussian (``triton_backend.PAIR_FIELD = "ids"``, issue 35): the binning writes one
int32 row per (Gaussian, tile) pair and the compositing kernels compute the pair's pixel rectangle from the
Gaussian's centre and extents, instead of reading one the binning wrote (56 bytes a pair with the default forward).

The reference for the bins is :func:`.rasterize.bin_to_tiles` (pairs, order and tile starts); for the images and
gradients, the same render with ``"rects"``: bit for bit in Triton's interpreter, since each pixel gets the same
fragments in the same order (compiled for a GPU, to float32 rounding: :func:`assert_same_image`).
The hard case is a footprint across the panorama's seam whose two column intervals meet one tile: two pairs of one
Gaussian there, told apart by their order. Without a GPU the kernels run in Triton's interpreter (conftest.py).
"""

import pytest
import torch

pytest.importorskip("triton")

from cylindersplat.benchmarks.launches import count_render_launches  # noqa: E402
from cylindersplat.gaussians import Gaussians  # noqa: E402
from cylindersplat.render import Equirect, Pinhole, RasterSettings, render, triton_backend, triton_binning  # noqa: E402
from cylindersplat.render.projection import flatten_cameras, project_gaussians  # noqa: E402
from cylindersplat.render.rasterize import bin_to_tiles  # noqa: E402
from cylindersplat.render.triton_projection import project_dense_triton  # noqa: E402
from render_scenes import shell_scene, yaw_pose  # noqa: E402
from tensor_waits import waits_during  # noqa: E402

DEVICE = "cuda" if torch.cuda.is_available() else "cpu"
F32 = torch.float32
K = torch.tensor([[14.0, 0.0, 12.3], [0.0, 15.0, 9.6], [0.0, 0.0, 1.0]])


def _two_poses():
    return torch.stack([yaw_pose(0.3, dtype=F32), yaw_pose(2.0, (0.1, -0.2, 0.1), dtype=F32)])


def _fused_projection(g, poses, camera):
    """The Triton projection's pairs (every pair kept, the backend's default): the rows the "ids" pairs need."""
    return project_gaussians(*flatten_cameras(g.to(DEVICE), poses.to(DEVICE))[:2], camera, RasterSettings(),
                             project_dense_triton, every_pair=True)


def _tiles_met_twice(bins) -> int:
    """Tiles in which one Gaussian has two pairs (a footprint's two intervals across the seam)."""
    same = (bins.gaussian[1:] == bins.gaussian[:-1]) & (bins.tile[1:] == bins.tile[:-1])
    return int(same.sum())


@pytest.mark.parametrize("tile_size", [4, 8])
def test_id_bins_are_the_reference_pairs_in_the_reference_order(tile_size):
    g = shell_scene(12, seed=36, scale=(0.3, 0.8), radius=(0.4, 1.0), dtype=F32)
    for camera in (Equirect(16, 32), Pinhole(K, 20, 24)):
        proj = _fused_projection(g, _two_poses(), camera)
        ref = bin_to_tiles(proj, tile_size)
        bins = triton_binning.bin_ids(proj, tile_size)
        assert bins.rows is None and bins.cols is None and bins.gaussian.dtype == torch.int32
        assert int(bins.total) == len(ref.gaussian) == bins.capacity
        assert torch.equal(bins.gaussian.long(), ref.gaussian)
        num_tiles = proj.num_cameras * ref.tiles_x * ref.tiles_y
        starts = torch.searchsorted(ref.tile, torch.arange(num_tiles + 1, device=ref.tile.device))
        assert torch.equal(bins.tile_start, starts)
        if camera.wrap_u and tile_size == 8:
            assert _tiles_met_twice(ref) > 0  # the seam's hard case is in the scene


def test_id_bins_of_an_empty_scene():
    proj = _fused_projection(Gaussians.empty(), torch.eye(4)[None], Equirect(8, 16))
    bins = triton_binning.bin_ids(proj, 4)
    assert len(bins.gaussian) == 0 and int(bins.total) == 0
    assert torch.equal(bins.tile_start, torch.zeros(1 * 2 * 4 + 1, dtype=torch.int64, device=DEVICE))


def _render(g, poses, camera, forward, pair_field, monkeypatch, background=None, settings=None):
    """Outputs, then the gradients of a fixed random loss of all three, with the given variant."""
    monkeypatch.setattr(triton_backend, "FORWARD", forward)
    monkeypatch.setattr(triton_backend, "PAIR_FIELD", pair_field)
    monkeypatch.setattr(triton_binning, "_CAPACITY", {})
    params = {k: v.detach().to(DEVICE).clone().requires_grad_() for k, v in g.tensors().items()}
    out = render(Gaussians(**params), poses.to(DEVICE), camera, background=background, backend="triton",
                 settings=settings)
    gen = torch.Generator().manual_seed(5)
    weights = [torch.randn(t.shape, generator=gen).to(DEVICE) for t in (out.rgb, out.depth, out.alpha)]
    loss = sum((w * t).sum() for w, t in zip(weights, (out.rgb, out.depth, out.alpha)))
    grads = torch.autograd.grad(loss, list(params.values()), allow_unused=True)
    return [out.rgb, out.depth, out.alpha], dict(zip(params, grads))


def assert_same_gradient(got, expected, name):
    """Bit for bit in Triton's interpreter, which runs the tiles one after another; to float32 rounding on a GPU,
    whose tiles add their atomics in any order (two runs of one variant differ there too)."""
    if DEVICE == "cpu":
        assert torch.equal(got, expected), name
    else:
        torch.testing.assert_close(got, expected, atol=1e-6, rtol=1e-4, msg=name)


def assert_same_image(got, expected, name):
    """Bit for bit in Triton's interpreter; to float32 rounding on a GPU, where two kernels that do the same arithmetic
    may be compiled to another order of it (``LOOKAHEAD`` "row" against "id" with computed rectangles, on pinhole
    views: up to 2.4e-7 on an H100, 2026-11-27)."""
    if DEVICE == "cpu":
        assert torch.equal(got, expected), name
    else:
        torch.testing.assert_close(got, expected, rtol=0, atol=1e-6, msg=name)


def _assert_ids_equal_rects(monkeypatch, g, poses, camera, forward, **kwargs):
    (out_r, grad_r), (out_i, grad_i) = (_render(g, poses, camera, forward, p, monkeypatch, **kwargs)
                                        for p in ("rects", "ids"))
    for name, a, b in zip(("rgb", "depth", "alpha"), out_r, out_i):
        assert_same_image(b, a, name)  # each pixel by one program, its pairs in one order
    for name, expected in grad_r.items():
        assert (expected is None) == (grad_i[name] is None), name
        if expected is not None:
            assert_same_gradient(grad_i[name], expected, name)
    return out_r


@pytest.mark.parametrize("forward", ["default", "lean"])
def test_ids_give_the_rects_images_and_gradients_bit_for_bit_across_the_seam(monkeypatch, forward):
    # Close, wide footprints across the seam (some meet one tile twice), two cameras, a background.
    g = shell_scene(12, seed=36, scale=(0.3, 0.8), radius=(0.4, 1.0), dtype=F32)
    proj = _fused_projection(g, _two_poses(), Equirect(16, 32))
    assert _tiles_met_twice(bin_to_tiles(proj, 8)) > 0
    out = _assert_ids_equal_rects(monkeypatch, g, _two_poses(), Equirect(16, 32), forward,
                                  background=(0.2, 0.3, 0.4), settings=RasterSettings(tile_size=8))
    assert out[2].max() > 0.5  # the scene covers the panorama


@pytest.mark.parametrize("forward", ["default", "lean"])
def test_ids_give_the_rects_images_and_gradients_on_pinhole_views_and_small_tiles(monkeypatch, forward):
    g = shell_scene(30, seed=33, scale=(0.05, 0.4), dtype=F32)
    _assert_ids_equal_rects(monkeypatch, g, _two_poses(), Pinhole(K, 20, 24), forward)
    _assert_ids_equal_rects(monkeypatch, g, yaw_pose(1.0, dtype=F32), Equirect(16, 32), forward,
                            settings=RasterSettings(tile_size=4))


def test_rows_the_compositing_cannot_read_extents_from_keep_their_rectangles(monkeypatch):
    # float64 Gaussians: the reference projects (pack_projected's rows, no extents): the pairs carry rectangles.
    g = shell_scene(15, seed=39, scale=(0.1, 0.5), dtype=torch.float64)
    camera = Equirect(8, 16)
    proj = camera.project(g, yaw_pose(0.4, dtype=torch.float64)[None], RasterSettings())
    monkeypatch.setattr(triton_backend, "PAIR_FIELD", "ids")
    assert triton_backend.pairs_carry_rects(proj)
    assert not triton_backend.pairs_carry_rects(_fused_projection(g.to(F32), yaw_pose(0.4, dtype=F32)[None], camera))
    _assert_ids_equal_rects(monkeypatch, g, yaw_pose(0.4, dtype=torch.float64), camera, "default")


def test_an_unknown_pair_field_is_refused_by_name(monkeypatch):
    monkeypatch.setattr(triton_backend, "PAIR_FIELD", "boxes")
    g = shell_scene(5, seed=1, dtype=F32).to(DEVICE)
    with pytest.raises(ValueError, match="unknown Triton pair field 'boxes': choose one of ids, rects"):
        render(g, torch.eye(4, device=DEVICE), Equirect(8, 16), backend="triton")


def test_the_id_forward_reads_the_device_once_and_launches_fewer_kernels(monkeypatch):
    g = shell_scene(20, seed=1, dtype=F32)
    c2w = torch.eye(4, device=DEVICE)
    counts = {}
    for pair_field in ("rects", "ids"):
        monkeypatch.setattr(triton_backend, "PAIR_FIELD", pair_field)
        params = {k: v.detach().to(DEVICE).clone().requires_grad_() for k, v in g.tensors().items()}  # no grads yet

        def forward():
            return render(Gaussians(**params), c2w, Equirect(8, 16), backend="triton")

        counts[pair_field] = count_render_launches(forward)
        outputs = []
        assert waits_during(lambda: outputs.append(forward())) == [("tolist", "render/projection.py", "read_with")]
        assert waits_during(lambda: (outputs[0].rgb.sum() + outputs[0].depth.sum()).backward()) == []
    (rects, rects_bwd), (ids, ids_bwd) = counts["rects"], counts["ids"]
    # The pairs' writing, the tile ids' range and their binary search become one kernel (which also writes the tiles'
    # first places); the backward is unchanged.
    assert ids.kernels == rects.kernels - 2 and ids_bwd.kernels == rects_bwd.kernels
    assert "write_fused_pairs_kernel" not in ids.triton and ids.triton["write_lean_pairs_kernel"] == 1


def test_a_lean_capacity_too_small_for_the_id_pairs_drops_none(monkeypatch):
    g = shell_scene(20, seed=34, scale=(0.2, 0.6), dtype=F32)
    camera, settings = Equirect(16, 32), RasterSettings(tile_size=4)
    expected, _ = _render(g, torch.eye(4), camera, "default", "rects", monkeypatch, settings=settings)
    proj = _fused_projection(g, torch.eye(4)[None], camera)
    key, _ = triton_binning.lean_capacity(proj, 4)
    calls = []
    original = triton_binning.bin_lean
    monkeypatch.setattr(triton_binning, "bin_lean", lambda *a: calls.append(a[2:]) or original(*a))
    monkeypatch.setattr(triton_backend, "FORWARD", "lean")
    monkeypatch.setattr(triton_backend, "PAIR_FIELD", "ids")
    monkeypatch.setattr(triton_binning, "_CAPACITY", {key: 3})  # far too small: the first binning misses most pairs
    out = render(g.to(DEVICE), torch.eye(4, device=DEVICE), camera, backend="triton", settings=settings)
    assert [rects for _, rects in calls] == [False, False] and calls[0][0] == 3 < calls[1][0]  # one rerun
    for name, a, b in zip(("rgb", "depth", "alpha"), expected, (out.rgb, out.depth, out.alpha)):
        assert torch.equal(a.detach(), b), name
