"""``benchmarks.tile_walk``: the pairs the Triton compositing kernels walk before a tile's pixels are all opaque
(issue 35's slower backward at 0.1 M Gaussians). Checked on stacks of layers whose walk is known by hand, and on a
random scene against the reference renderer's alpha (the walked fragments must give the render's own)."""

import numpy as np
import pytest
import torch

from cylindersplat.benchmarks import render as bench_render
from cylindersplat.benchmarks.tile_walk import FORWARD_RUN, tile_walk
from cylindersplat.gaussians import Gaussians
from cylindersplat.render import Equirect, Pinhole, RasterSettings, render
from render_scenes import shell_scene, yaw_pose

F64 = torch.float64
K = torch.tensor([[20.0, 0.0, 32.0], [0.0, 20.0, 16.0], [0.0, 0.0, 1.0]], dtype=F64)


def _layers(count, opacity):
    """``count`` wide flat layers straight ahead at 1, 2, ... m, each covering the whole 32x64 pinhole view with
    alpha just under ``opacity``."""
    z = torch.arange(1, count + 1, dtype=F64)
    means = torch.stack([torch.zeros_like(z), torch.zeros_like(z), z], dim=-1)
    return Gaussians.from_rgb(means, torch.tensor([[200.0, 200.0, 0.01]], dtype=F64).expand(count, 3).clone(),
                              torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=F64).expand(count, 4).clone(),
                              torch.full((count,), opacity, dtype=F64), torch.rand(count, 3, dtype=F64))


def _walk(g, c2w, camera, settings=RasterSettings()):
    return tile_walk(camera.project(g, c2w[None], settings), settings)


def test_opaque_layers_stop_every_tile_after_the_layer_that_makes_it_opaque():
    # alpha 0.8 a layer: transmittance 0.2^5 = 3.2e-4 after five, 6.4e-5 < 1e-4 at the sixth, which is dropped.
    walk = _walk(_layers(20, 0.8), torch.eye(4, dtype=F64), Pinhole(K, 32, 64))
    assert len(walk.pairs) == 2 * 4 and (walk.pairs == 20).all()  # 16-px tiles
    assert (walk.backward == 6).all()  # the backward stops at the pair that left no pixel alive
    assert (walk.forward == FORWARD_RUN).all()  # the forward counts the live pixels after each run of 8
    assert (walk.used == 5 * 16 * 16).all()
    np.testing.assert_allclose(walk.alpha, 1 - 0.2**5, atol=2e-4)  # (each layer's alpha a little under 0.8)


def test_sparse_layers_are_all_walked():
    walk = _walk(_layers(3, 0.5), torch.eye(4, dtype=F64), Pinhole(K, 32, 64))
    assert (walk.pairs == 3).all() and (walk.forward == 3).all() and (walk.backward == 3).all()
    assert (walk.used == 3 * 16 * 16).all()
    np.testing.assert_allclose(walk.alpha, 1 - 0.5**3, atol=1e-2)


@pytest.mark.parametrize("camera", [Equirect(16, 32), Pinhole(K, 32, 64)], ids=["equirect", "pinhole"])
def test_the_walked_fragments_give_the_reference_renders_alpha(camera):
    g = shell_scene(400, seed=4, scale=(0.2, 0.9), radius=(0.5, 2.0))  # overlapping, some across the seam
    g.opacities.fill_(0.95)  # opaque enough that some tiles stop early
    c2w = torch.stack([yaw_pose(0.3), yaw_pose(1.9, (0.1, 0.0, -0.1))])
    settings = RasterSettings(tile_size=8)
    walk = tile_walk(camera.project(g, c2w, settings), settings)
    ref = render(g, c2w, camera, backend="torch", settings=settings).alpha.reshape(walk.alpha.shape)
    np.testing.assert_allclose(walk.alpha, ref.numpy(), atol=1e-6)
    assert (walk.backward <= walk.forward).all() and (walk.forward <= walk.pairs).all()
    assert 0 < walk.backward.sum() < walk.pairs.sum()  # some tiles stop early
    assert ((walk.forward % FORWARD_RUN == 0) | (walk.forward == walk.pairs)).all()


def test_the_forward_run_is_the_kernels():
    triton_kernels = pytest.importorskip("cylindersplat.render.triton_kernels")
    assert triton_kernels._ALIVE_EVERY == FORWARD_RUN


def test_bench_render_prints_the_walk_per_size(capsys):
    bench_render.main(["--num", "300", "2000", "--height", "16", "--device", "cpu", "--backend", "torch",
                       "--repeats", "1", "--tile-walk"])
    lines = [x for x in capsys.readouterr().out.splitlines() if x.startswith("# tile walk")]
    assert [x.split(" Gaussians")[0] for x in lines] == ["# tile walk (300", "# tile walk (2000"]
    assert "16x32, equirect" in lines[0] and "the forward walks" in lines[0] and "the backward" in lines[0]
