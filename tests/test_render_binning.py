"""Tile binning: the fast path's variants (per-Gaussian counts, prefix sum, Triton key emission, one sort:
of ``tile << 32 | depth bits``, or of narrow tile ids after a depth sort of the Gaussians) against the
reference :func:`bin_to_tiles`, field by field, and all against a brute-force list of the tiles each
Gaussian's bounding box touches. Without CUDA the kernels run in Triton's interpreter.
"""

import math

import pytest
import torch

pytest.importorskip("triton")

from cylindersplat.gaussians import Gaussians  # noqa: E402
from cylindersplat.geometry.cubemap import cubemap_face_c2w  # noqa: E402
from cylindersplat.render import Equirect, Pinhole, RasterSettings, cubemap_face, triton_binning  # noqa: E402
from cylindersplat.render.rasterize import bin_to_tiles  # noqa: E402
from cylindersplat.render.triton_binning import bin_to_tiles_by_key, tile_key_dtype  # noqa: E402
from render_scenes import shell_scene, yaw_pose  # noqa: E402

F32 = torch.float32
DEVICE = "cuda" if torch.cuda.is_available() else "cpu"  # the kernel needs CUDA tensors unless interpreted
FIELDS = ("gaussian", "tile", "rows", "cols", "col_shift")


def _brute_force_pairs(proj, tile_size):
    """{(gaussian row, tile id)} from every pixel of every bounding box, columns wrapped for panoramas."""
    h, w = proj.height, proj.width
    tiles_x, tiles_y = math.ceil(w / tile_size), math.ceil(h / tile_size)
    pairs = set()
    for m in range(len(proj.depth)):
        (u, v), (eu, ev) = proj.uv[m].tolist(), proj.extent[m].tolist()
        rows = [i for i in range(h) if abs(i + 0.5 - v) <= ev]
        if proj.wrap_u:
            lo = math.ceil(u - eu - 0.5)
            cols = {j % w for j in range(lo, min(math.floor(u + eu - 0.5), lo + w - 1) + 1)}
        else:
            cols = [j for j in range(w) if abs(j + 0.5 - u) <= eu]
        for i in rows:
            for j in cols:
                pairs.add((m, int(proj.camera[m]) * tiles_x * tiles_y + (i // tile_size) * tiles_x + j // tile_size))
    return pairs


def _project(camera, g, poses):
    return camera.project(g.to(DEVICE), poses.to(DEVICE), RasterSettings())


def _assert_same(proj, tile_size):
    """The Triton binning gives the reference's bins, field by field (values, dtypes, shapes)."""
    ref = bin_to_tiles(proj, tile_size)
    fast = bin_to_tiles_by_key(proj, tile_size)
    for name in FIELDS:
        assert torch.equal(getattr(fast, name), getattr(ref, name)), name
    assert (fast.tiles_x, fast.tiles_y) == (ref.tiles_x, ref.tiles_y)
    # Both are the bounding boxes' tiles, in (tile, depth) order.
    assert set(zip(ref.gaussian.tolist(), ref.tile.tolist())) == _brute_force_pairs(proj, tile_size)
    key = ref.tile.double() * 1e6 + proj.depth[ref.gaussian].double()
    assert (key[1:] >= key[:-1]).all()
    return ref


@pytest.mark.parametrize("tile_size", [4, 8, 16, 7])
def test_equirect_bins_match_the_reference(tile_size):
    g = shell_scene(80, seed=31, scale=(0.05, 0.5), dtype=F32)
    poses = torch.stack((yaw_pose(0.0, dtype=F32), yaw_pose(1.1, (0.2, -0.1, 0.3), dtype=F32)))
    proj = _project(Equirect(16, 32), g, poses)
    bins = _assert_same(proj, tile_size)
    assert (bins.col_shift != 0).any()  # some footprints cross the seam


def test_wide_footprints_that_meet_a_tile_twice_across_the_seam():
    # Close, big Gaussians: bounding boxes up to the whole width; a wrapped range can touch one tile
    # with both of its column intervals.
    g = shell_scene(30, seed=32, scale=(0.3, 0.8), radius=(0.4, 1.0), dtype=F32)
    proj = _project(Equirect(16, 32), g, yaw_pose(0.3, dtype=F32))
    bins = _assert_same(proj, 8)
    pair_keys = bins.gaussian * 10_000 + bins.tile
    assert len(pair_keys.unique()) < len(pair_keys)


def test_pinhole_and_cubemap_bins_match_the_reference():
    g = shell_scene(80, seed=33, scale=(0.05, 0.4), dtype=F32)
    k = torch.tensor([[14.0, 0.0, 12.3], [0.0, 15.0, 9.6], [0.0, 0.0, 1.0]])
    poses = torch.stack((yaw_pose(0.2, dtype=F32), yaw_pose(-1.9, (0.1, 0.1, 0.2), dtype=F32)))
    _assert_same(_project(Pinhole(k, 20, 24), g, poses), 8)
    faces = cubemap_face_c2w(yaw_pose(0.4, dtype=F32))
    _assert_same(_project(cubemap_face(12, dtype=F32), g, faces), 4)


def test_equal_depths_keep_the_gaussian_order():
    # Eight Gaussians at exactly the same distance, overlapping: ties are broken by Gaussian row.
    angles = torch.linspace(-0.2, 0.2, 8)
    means = torch.stack((torch.sin(angles), torch.zeros(8), torch.cos(angles)), -1) * 2.0
    g = Gaussians.from_rgb(means, torch.full((8, 3), 0.2), torch.tensor([[1.0, 0, 0, 0]]).expand(8, 4),
                           torch.full((8,), 0.5), torch.rand(8, 3))
    g = Gaussians(g.means.flip(0), g.scales, g.rotations, g.opacities, g.sh)
    proj = _project(Equirect(16, 32), g, torch.eye(4))
    assert len(proj.depth.unique()) == 1
    bins = _assert_same(proj, 8)
    for tile in bins.tile.unique():
        rows = bins.gaussian[bins.tile == tile]
        assert (rows[1:] > rows[:-1]).all()


def test_batched_cameras_and_empty_input():
    a, b = shell_scene(25, seed=34, dtype=F32), shell_scene(25, seed=35, dtype=F32)
    batched = Gaussians(**{k: torch.stack((getattr(a, k), getattr(b, k))) for k in a.tensors()})
    poses = torch.stack([torch.stack((yaw_pose(0.3 * i, dtype=F32), yaw_pose(2.0, (0.1, 0, 0), dtype=F32)))
                         for i in range(2)])
    _assert_same(_project(Equirect(8, 16), batched, poses), 4)
    empty = _project(Equirect(8, 16), Gaussians.empty(), torch.eye(4))
    ref = bin_to_tiles(empty, 4)
    bins = bin_to_tiles_by_key(empty, 4)
    for name in FIELDS:
        assert getattr(bins, name).shape == getattr(ref, name).shape and getattr(bins, name).numel() == 0, name
        assert getattr(bins, name).dtype == getattr(ref, name).dtype, name


def test_tile_keys_are_the_narrowest_type_that_holds_every_tile_id():
    assert tile_key_dtype(2**15) == torch.int16  # ids 0 .. 32767
    assert tile_key_dtype(2**15 + 1) == torch.int32
    assert torch.iinfo(torch.int16).max == 2**15 - 1


def test_int32_tile_keys_give_the_same_bins(monkeypatch):
    # The int32 keys of >= 32768 tiles (e.g. 4 cameras of 2048 x 4096 in 16-pixel tiles), on a small scene.
    monkeypatch.setattr(triton_binning, "tile_key_dtype", lambda num_tiles: torch.int32)
    g = shell_scene(60, seed=36, scale=(0.05, 0.6), dtype=F32)
    poses = torch.stack((yaw_pose(0.0, dtype=F32), yaw_pose(2.5, (0.1, 0.2, 0.0), dtype=F32)))
    _assert_same(_project(Equirect(16, 32), g, poses), 4)


def test_float64_projections_give_the_same_bins():
    # The fused variant recomputes the spans from uv and extent in their own float type, as tile_spans does.
    g = shell_scene(60, seed=38, scale=(0.05, 0.5), dtype=torch.float64)
    k = torch.tensor([[14.0, 0.0, 12.3], [0.0, 15.0, 9.6], [0.0, 0.0, 1.0]], dtype=torch.float64)
    for camera in (Equirect(16, 32), Pinhole(k, 20, 24)):
        proj = _project(camera, g, yaw_pose(0.4, dtype=torch.float64))
        assert proj.uv.dtype == torch.float64
        _assert_same(proj, 4)
