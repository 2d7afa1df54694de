"""The Triton backend's "lean" forward (issue 35): the same bins, images and gradients as the default path, and
no pair dropped when the cached pair capacity is too small (the binning and compositing rerun with more).

Without a GPU the kernels run in Triton's interpreter (conftest.py)."""

import math

import pytest
import torch

pytest.importorskip("triton")

from cylindersplat.gaussians import Gaussians  # noqa: E402
from cylindersplat.render import Equirect, Pinhole, RasterSettings, render, triton_backend, triton_binning  # noqa: E402
from cylindersplat.render.projection import recording_reads  # noqa: E402
from cylindersplat.render.rasterize import bin_to_tiles  # noqa: E402
from render_scenes import shell_scene, yaw_pose  # noqa: E402

DEVICE = "cuda" if torch.cuda.is_available() else "cpu"
F32 = torch.float32
K = torch.tensor([[14.0, 0.0, 12.3], [0.0, 15.0, 9.6], [0.0, 0.0, 1.0]])


def _assert_lean_bins_match_the_reference(proj, tile_size, capacity):
    ref = bin_to_tiles(proj, tile_size)
    bins = triton_binning.bin_lean(proj, tile_size, capacity)
    total = len(ref.gaussian)
    assert int(bins.total) == total  # the device-side count: every pair, fitting or not
    num_tiles = proj.num_cameras * bins.tiles_x * bins.tiles_y
    assert (bins.tiles_x, bins.tiles_y) == (ref.tiles_x, ref.tiles_y)
    assert bins.gaussian.shape == (capacity,) and bins.rows.shape == (capacity, 2)  # nothing written past it
    if total > capacity:
        return bins
    assert torch.equal(bins.gaussian[:total].long(), ref.gaussian)
    assert torch.equal(bins.rows[:total].long(), ref.rows)
    assert torch.equal(bins.cols[:total].long(), ref.cols)
    starts = torch.searchsorted(ref.tile, torch.arange(num_tiles + 1, device=ref.tile.device))
    assert torch.equal(bins.tile_start, starts)
    return bins


@pytest.mark.parametrize("tile_size", [4, 8])
def test_lean_bins_equal_the_reference_with_room_to_spare_and_exactly_full(tile_size):
    g = shell_scene(40, seed=31, scale=(0.05, 0.6), dtype=F32).to(DEVICE)
    poses = torch.stack((yaw_pose(0.0, dtype=F32), yaw_pose(1.1, (0.2, -0.1, 0.3), dtype=F32))).to(DEVICE)
    proj = Equirect(16, 32).project(g, poses, RasterSettings())
    ref = bin_to_tiles(proj, tile_size)
    assert (ref.col_shift != 0).any()  # some footprints cross the seam
    for capacity in (len(ref.gaussian) + 300, len(ref.gaussian)):
        _assert_lean_bins_match_the_reference(proj, tile_size, capacity)
    pin = Pinhole(K, 20, 24).project(g, poses, RasterSettings())
    _assert_lean_bins_match_the_reference(pin, tile_size, len(bin_to_tiles(pin, tile_size).gaussian) + 7)


def test_lean_bins_of_an_empty_scene_and_a_too_small_capacity():
    empty = Equirect(8, 16).project(Gaussians.empty().to(DEVICE), torch.eye(4, device=DEVICE), RasterSettings())
    bins = _assert_lean_bins_match_the_reference(empty, 4, 16)
    assert int(bins.total) == 0
    g = shell_scene(20, seed=3, scale=(0.2, 0.5), dtype=F32).to(DEVICE)
    proj = Equirect(16, 32).project(g, torch.eye(4, device=DEVICE), RasterSettings())
    total = len(bin_to_tiles(proj, 4).gaussian)
    bins = _assert_lean_bins_match_the_reference(proj, 4, 5)
    assert total > 5 and int(bins.tile_start[-1]) == 5  # the places used: the capacity, no more


def _render(g, poses, camera, forward, background=None, settings=None):
    """Render with the given forward variant; outputs and the gradients of a fixed random loss."""
    params = {k: v.detach().to(DEVICE).clone().requires_grad_() for k, v in g.tensors().items()}
    saved = triton_backend.FORWARD
    triton_backend.FORWARD = forward
    try:
        out = render(Gaussians(**params), poses.to(DEVICE), camera, background=background, backend="triton",
                     settings=settings)
    finally:
        triton_backend.FORWARD = saved
    gen = torch.Generator().manual_seed(5)
    weights = [torch.randn(t.shape, generator=gen).to(DEVICE) for t in (out.rgb, out.depth, out.alpha)]
    loss = sum((wt * t).sum() for wt, t in zip(weights, (out.rgb, out.depth, out.alpha)))
    grads = torch.autograd.grad(loss, list(params.values()), allow_unused=True)
    return out, dict(zip(params, grads))


def _assert_same_as_default(g, poses, camera, **kwargs):
    (ref, grad_ref), (lean, grad_lean) = (_render(g, poses, camera, f, **kwargs) for f in ("default", "lean"))
    for name in ("rgb", "depth", "alpha"):
        torch.testing.assert_close(getattr(lean, name), getattr(ref, name), atol=1e-6, rtol=1e-5, msg=name)
    for name, expected in grad_ref.items():
        if expected is None:
            assert grad_lean[name] is None, name
        else:
            torch.testing.assert_close(grad_lean[name], expected, atol=1e-6, rtol=1e-4, msg=name)
    return ref


def test_lean_forward_gives_the_default_images_and_gradients_equirect_seam_and_pinhole():
    # Close, wide footprints across the seam, two cameras, a background; then a pinhole camera.
    g = shell_scene(12, seed=32, scale=(0.3, 0.8), radius=(0.4, 1.0), dtype=F32)
    poses = torch.stack([yaw_pose(0.3, dtype=F32), yaw_pose(2.0, (0.1, -0.2, 0.1), dtype=F32)])
    ref = _assert_same_as_default(g, poses, Equirect(16, 32), background=(0.2, 0.3, 0.4),
                                  settings=RasterSettings(tile_size=8))
    assert ref.alpha.max() > 0.5
    _assert_same_as_default(shell_scene(30, seed=33, scale=(0.05, 0.4), dtype=F32), poses, Pinhole(K, 20, 24))


def test_lean_forward_of_float64_gaussians_and_a_cubemap_face():
    # float64 projections: the 11-column layout and float64 centres and extents read in place.
    from cylindersplat.render import cubemap_face

    g = shell_scene(15, seed=39, scale=(0.1, 0.5), dtype=torch.float64)
    _assert_same_as_default(g, yaw_pose(0.4, dtype=torch.float64), Equirect(8, 16), background=(0.1, 0.2, 0.3))
    _assert_same_as_default(shell_scene(15, seed=40, dtype=F32), yaw_pose(0.2, dtype=F32), cubemap_face(12, dtype=F32))


def test_lean_forward_with_footprints_that_meet_a_tile_twice():
    g = shell_scene(12, seed=36, scale=(0.3, 0.8), radius=(0.4, 1.0), dtype=F32)
    _assert_same_as_default(g, yaw_pose(0.3, dtype=F32), Equirect(16, 32), settings=RasterSettings(tile_size=8))


def test_lean_forward_of_an_empty_scene_is_the_background():
    out, _ = _render(Gaussians.empty(), torch.eye(4), Pinhole(K, 20, 24), "lean", background=(0.2, 0.3, 0.4))
    assert torch.equal(out.alpha, torch.zeros_like(out.alpha))
    assert torch.allclose(out.rgb, torch.tensor([0.2, 0.3, 0.4], device=DEVICE).view(3, 1, 1).expand(3, 20, 24))


def _watched_lean_binning(monkeypatch, g):
    """An empty capacity cache, the scene's camera and settings (16x32 panorama, 4 px tiles), its pair count (the
    reference binning's), the cache key and first guess of its kind of render, and the list of capacities that
    each lean binning gets from then on."""
    monkeypatch.setattr(triton_binning, "_CAPACITY", {})
    camera, settings = Equirect(16, 32), RasterSettings(tile_size=4)
    proj = camera.project(g.to(DEVICE), torch.eye(4, device=DEVICE), settings)
    needed = len(bin_to_tiles(proj, 4).gaussian)
    key, first = triton_binning.lean_capacity(proj, 4)
    calls = []
    original = triton_binning.bin_lean
    monkeypatch.setattr(triton_binning, "bin_lean", lambda *a: calls.append(a[2]) or original(*a))
    return camera, settings, needed, key, first, calls


def test_a_capacity_too_small_drops_no_pair_and_grows(monkeypatch):
    g = shell_scene(20, seed=34, scale=(0.2, 0.6), dtype=F32)
    camera, settings, needed, key, first, calls = _watched_lean_binning(monkeypatch, g)
    triton_binning._CAPACITY[key] = 3  # far too small: the first binning misses most pairs
    _assert_same_as_default(g, torch.eye(4), camera, settings=settings)
    assert calls == [3, math.floor(needed * triton_binning.CAPACITY_HEADROOM) + 1024]  # one rerun, all pairs
    assert triton_binning._CAPACITY[key] == calls[-1]
    calls.clear()
    _render(g, torch.eye(4), camera, "lean", settings=settings)
    assert calls == [triton_binning._CAPACITY[key]]  # the next render of this kind fits at once


def test_the_first_render_of_a_kind_sizes_its_capacity_by_its_pairs(monkeypatch):
    # (the first guess, 4 per Gaussian, is sorted and written in full at every render where the pairs are fewer)
    g = shell_scene(60, seed=3, scale=(0.02, 0.05), dtype=F32)
    camera, settings, needed, key, first, calls = _watched_lean_binning(monkeypatch, g)
    settled = math.floor(needed * triton_binning.CAPACITY_HEADROOM) + 1024
    assert settled < first
    with recording_reads():  # a recorded render (a graph's capture) reads no count: it settles nothing
        _render(g, torch.eye(4), camera, "lean", settings=settings)
    assert triton_binning._CAPACITY == {}
    calls.clear()
    _assert_same_as_default(g, torch.eye(4), camera, settings=settings)
    _render(g, torch.eye(4), camera, "lean", settings=settings)
    assert calls == [first, settled] and triton_binning._CAPACITY[key] == settled


def test_unknown_forward_is_refused_by_name(monkeypatch):
    monkeypatch.setattr(triton_backend, "FORWARD", "skinny")
    with pytest.raises(ValueError, match="unknown Triton forward 'skinny'.*lean"):
        render(shell_scene(5, seed=9, dtype=F32).to(DEVICE), torch.eye(4, device=DEVICE), Equirect(8, 16),
               backend="triton")


def test_the_compositing_reads_the_projection_rows_in_place_and_falls_back_elsewhere():
    from dataclasses import replace

    from cylindersplat.render.projection import flatten_cameras, project_gaussians
    from cylindersplat.render.rasterize import pack_projected
    from cylindersplat.render.triton_projection import project_dense_triton

    g = shell_scene(10, seed=35, dtype=F32).to(DEVICE)
    camera, settings = Equirect(8, 16), RasterSettings()
    proj = project_gaussians(*flatten_cameras(g, torch.eye(4, device=DEVICE))[:2], camera, settings,
                             project_dense_triton)
    (geo, opacity, colour), layout, dtype = triton_backend._composite_rows(proj)
    reference = pack_projected(proj)
    assert layout.split == 1 and dtype == F32 and geo.shape == (len(proj.depth), 8)
    assert geo.data_ptr() == proj.uv.data_ptr()  # the projection's own rows: no copy, no concatenation
    u_to_c_and_depth = torch.cat((geo[:, :5], opacity[:, None], colour, geo[:, 7:8]), 1)
    assert torch.equal(u_to_c_and_depth, reference[:, :10])  # pack_projected's columns 0-9
    copied = replace(proj, uv=proj.uv.clone())  # not a view of the projection's rows: the 11-column layout
    (packed, none, nothing), layout, dtype = triton_backend._composite_rows(copied)
    assert layout.split == 0 and none is None and nothing is None and torch.equal(packed, reference)
    pointers = layout.pointers(packed, None, None)  # opacity and colour: views of the packed rows
    assert torch.equal(pointers[1], reference[:, 5]) and torch.equal(pointers[2], reference[:, 6:9])


def test_lean_bins_with_int32_tile_keys(monkeypatch):
    # The int32 keys of >= 32768 tiles, on a small scene: padding past every tile id sorts last there too.
    monkeypatch.setattr(triton_binning, "tile_key_dtype", lambda num_tiles: torch.int32)
    g = shell_scene(30, seed=37, scale=(0.05, 0.6), dtype=F32).to(DEVICE)
    proj = Equirect(16, 32).project(g, torch.eye(4, device=DEVICE), RasterSettings())
    _assert_lean_bins_match_the_reference(proj, 4, len(bin_to_tiles(proj, 4).gaussian) + 50)


def test_scenes_of_other_sizes_keep_their_own_capacity(monkeypatch):
    monkeypatch.setattr(triton_binning, "_CAPACITY", {})
    camera, eye = Equirect(16, 32), torch.eye(4, device=DEVICE)
    small, large = (camera.project(shell_scene(n, seed=38, dtype=F32).to(DEVICE), eye, RasterSettings())
                    for n in (6, 60))
    (key_small, first_small), (key_large, first_large) = (triton_binning.lean_capacity(p, 8) for p in (small, large))
    assert key_small != key_large
    assert (first_small, first_large) == (4 * len(small.depth) + 1024, 4 * len(large.depth) + 1024)
    triton_binning.grow_capacity(key_large, 10**6)
    assert triton_binning.lean_capacity(small, 8)[1] == first_small  # the large scene's growth is not the small's
    assert triton_binning.lean_capacity(large, 8)[1] == int(10**6 * triton_binning.CAPACITY_HEADROOM) + 1024
