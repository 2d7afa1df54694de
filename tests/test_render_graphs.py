"""Renders replayed as CUDA graphs (``render.graphs.RenderGraph``, issue 35) against :func:`render` itself.

On a machine without a GPU the Triton backend runs in Triton's interpreter (conftest.py), which has no graphs: there
the graph engine's captures are replaced by reruns of the captured work (``graph_standin.py``), which checks what
``RenderGraph`` and the engine do around a capture - the recorded read (no wait for the device inside what is
captured), copies into and out of the graph's tensors, the backward replay and its gradients, the buffers' growth,
the fallback to :func:`render` for its errors and warnings, the refusals. With CUDA the same tests replay real
graphs. The reference is :func:`render` with the backend's default forward: images, depths
and alphas bit for bit, gradients too on the CPU (to float32 rounding on a GPU, where atomics add in any order).
"""

import warnings

import pytest
import torch

pytest.importorskip("triton")

from cylindersplat.gaussians import Gaussians  # noqa: E402
from cylindersplat.render import Equirect, Pinhole, graphs, render, triton_backend, triton_binning  # noqa: E402
from cylindersplat.render.projection import recording_reads  # noqa: E402
from graph_standin import RerunGraphReplay  # noqa: E402
from render_scenes import shell_scene, yaw_pose  # noqa: E402
from tensor_waits import waits_during  # noqa: E402

CUDA = torch.cuda.is_available()
DEVICE = "cuda" if CUDA else "cpu"
F32 = torch.float32
CAMERAS = {"equirect": Equirect(8, 16),
           "pinhole": Pinhole(torch.tensor([[9.0, 0.0, 8.0], [0.0, 9.0, 6.0], [0.0, 0.0, 1.0]]), 12, 16)}


@pytest.fixture(autouse=True)
def _replay_where_no_graphs(monkeypatch):
    if not CUDA:
        monkeypatch.setitem(graphs._ENGINES, "cpu", RerunGraphReplay)
    monkeypatch.setattr(triton_binning, "_CAPACITY", {})


def _scene(seed=1, n=30, scale=(0.1, 0.3)):
    g = shell_scene(n, seed=seed, scale=scale, dtype=F32)
    return Gaussians(**{k: v.to(DEVICE) for k, v in g.tensors().items()})


def _pose(angle):
    return yaw_pose(angle, dtype=F32).to(DEVICE)


def _same(a, b):
    if CUDA:  # atomics add in any order on a GPU: gradients to float32 rounding of their sums
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-6 + 1e-5 * float(b.abs().max()))
    else:
        assert torch.equal(a, b)


def _assert_same_render(out, ref):
    for name in ("rgb", "depth", "alpha"):
        assert torch.equal(getattr(out, name), getattr(ref, name)), name


@pytest.mark.parametrize("camera", list(CAMERAS))
def test_replays_equal_render_for_new_poses_and_values(camera):
    g, cam = _scene(), CAMERAS[camera]
    graph = graphs.RenderGraph(g, _pose(0.0), cam)
    for angle, scene in ((0.0, g), (0.7, g), (-1.9, _scene(seed=2))):
        out = graph(scene, _pose(angle))
        _assert_same_render(out, render(scene, _pose(angle), cam, backend="triton"))
    assert graph.captures == 1 and graph.renders == 3
    assert out.alpha.max() > 0


def test_outputs_are_the_callers_own():
    g = _scene()
    graph = graphs.RenderGraph(g, _pose(0.0), CAMERAS["equirect"])
    first = graph(g, _pose(0.0))
    kept = first.rgb.clone()
    graph(g, _pose(2.0))  # the graph's buffers now hold another image
    assert torch.equal(first.rgb, kept) and not torch.equal(first.rgb, graph(g, _pose(2.0)).rgb)


def test_a_background_is_fixed_at_capture_and_kept_by_the_graph():
    from cylindersplat.render import api

    g = _scene()
    graph = graphs.RenderGraph(g, _pose(0.0), CAMERAS["pinhole"], background=[0.2, 0.3, 0.4])
    ref = render(g, _pose(0.5), CAMERAS["pinhole"], background=(0.2, 0.3, 0.4), backend="triton")
    _assert_same_render(graph(g, _pose(0.5)), ref)
    api._BACKGROUNDS.clear()  # render()'s cache of backgrounds made on the device drops them when full
    for value in range(api._MAX_BACKGROUNDS + 2):
        render(g, _pose(0.5), CAMERAS["pinhole"], background=(value / 20, 0.0, 1.0), backend="triton")
    _assert_same_render(graph(g, _pose(0.5)), ref)
    assert graph.captures == 1
    with pytest.raises(ValueError, match="background must be finite"):
        graphs.RenderGraph(g, _pose(0.0), CAMERAS["pinhole"], background=(0.0, float("nan"), 0.0))(g, _pose(0.0))


@pytest.mark.parametrize("camera", list(CAMERAS))
def test_backward_graph_gives_renders_gradients(camera):
    cam = CAMERAS[camera]
    params = {k: v.detach().requires_grad_() for k, v in _scene().tensors().items()}
    ref_params = {k: v.detach().clone().requires_grad_() for k, v in params.items()}
    graph = graphs.RenderGraph(Gaussians(**params), _pose(0.0), cam, backward=True)
    for angle in (0.3, 1.1):
        out = graph(Gaussians(**params), _pose(angle))
        ref = render(Gaussians(**ref_params), _pose(angle), cam, backend="triton")
        _assert_same_render(out, ref)
        (out.rgb.square().sum() + out.depth.sum() + 0.5 * out.alpha.sum()).backward()
        (ref.rgb.square().sum() + ref.depth.sum() + 0.5 * ref.alpha.sum()).backward()
        for name in params:
            assert params[name].grad.abs().max() > 0, name
            _same(params[name].grad, ref_params[name].grad)
            params[name].grad = ref_params[name].grad = None


def test_gradients_accumulate_as_renders_do():
    # The graph's gradient buffers are overwritten by its next backward: what reaches .grad must be a copy, or a
    # second backward would add a buffer to itself.
    params = {k: v.detach().requires_grad_() for k, v in _scene().tensors().items()}
    ref_params = {k: v.detach().clone().requires_grad_() for k, v in params.items()}
    graph = graphs.RenderGraph(Gaussians(**params), _pose(0.0), CAMERAS["pinhole"], backward=True)
    for angle in (0.2, 0.9, 1.6):
        graph(Gaussians(**params), _pose(angle)).rgb.sum().backward()
        render(Gaussians(**ref_params), _pose(angle), CAMERAS["pinhole"], backend="triton").rgb.sum().backward()
    kept = params["means"].grad.clone()
    graph(Gaussians(**params), _pose(-0.5)).depth.sum().backward()
    render(Gaussians(**ref_params), _pose(-0.5), CAMERAS["pinhole"], backend="triton").depth.sum().backward()
    for name in params:
        _same(params[name].grad, ref_params[name].grad)
    assert not torch.equal(params["means"].grad, kept)


def test_a_training_loop_renders_its_parameters_as_they_are_updated_in_place():
    # The graph reads a leaf tensor where it is: a step's in-place update is what the next replay renders.
    params = {k: v.detach().requires_grad_() for k, v in _scene().tensors().items()}
    graph = graphs.RenderGraph(Gaussians(**params), _pose(0.0), CAMERAS["equirect"], backward=True)
    optimiser = torch.optim.SGD(params.values(), lr=0.05)
    for step in range(3):
        optimiser.zero_grad()
        out = graph(Gaussians(**params), _pose(0.3 * step))
        with torch.no_grad():
            _assert_same_render(out, render(Gaussians(**params), _pose(0.3 * step), CAMERAS["equirect"],
                                            backend="triton"))
        (out.rgb - 0.5).square().mean().backward()
        optimiser.step()
    assert graph.captures == 1
    # a network's output (not a leaf) is copied in: its graph still reaches the network's parameters
    scale = torch.ones(1, device=DEVICE, requires_grad=True)
    moved = Gaussians(**{**params, "means": params["means"] * scale})
    graphs.RenderGraph(moved, _pose(0.0), CAMERAS["equirect"], backward=True)(moved, _pose(0.0)).rgb.sum().backward()
    assert scale.grad is not None and scale.grad.abs().item() > 0


def test_a_graph_made_under_autocast_renders_as_render_does():
    # (a training step's bf16 autocast: the capture turns it off; the render is float32 either way)
    g = _scene()
    with torch.autocast(device_type=DEVICE, dtype=torch.bfloat16):
        graph = graphs.RenderGraph(g, _pose(0.0), CAMERAS["pinhole"])
        out = graph(g, _pose(0.4))
        ref = render(g, _pose(0.4), CAMERAS["pinhole"], backend="triton")
    assert out.rgb.dtype == torch.float32
    _assert_same_render(out, ref)


def test_a_backward_after_the_next_render_is_refused():
    params = {k: v.detach().requires_grad_() for k, v in _scene().tensors().items()}
    graph = graphs.RenderGraph(Gaussians(**params), _pose(0.0), CAMERAS["equirect"], backward=True)
    first = graph(Gaussians(**params), _pose(0.0))
    second = graph(Gaussians(**params), _pose(1.0))
    with pytest.raises(RuntimeError, match="call backward before the next render"):
        first.rgb.sum().backward()
    second.rgb.sum().backward()  # the latest render's backward is fine
    assert params["means"].grad.abs().max() > 0


def test_the_capture_reads_the_device_nowhere():
    # A CUDA graph cannot wait for the device while it is captured: the captured function records its one read.
    g = _scene()
    graph = graphs.RenderGraph(g, _pose(0.0), CAMERAS["equirect"])
    inputs = graph._checked_inputs(g, _pose(0.3))
    graph(g, _pose(0.3))  # sizes the buffers
    outputs = []
    assert waits_during(lambda: outputs.append(graph._render_recorded(*inputs))) == []
    count, problem, far, visible = outputs[0][3].tolist()
    ref = render(g, _pose(0.3), CAMERAS["equirect"], backend="torch")
    assert (problem, far) == (0, 0) and visible == 30 and 0 < count <= graph.capacity
    assert torch.equal(outputs[0][0], graph(g, _pose(0.3)).rgb)
    torch.testing.assert_close(outputs[0][0], ref.rgb, rtol=1e-4, atol=2e-4)  # test_render_triton's tolerance


# What a CUDA graph cannot hold: a value read from the device (a wait), a size that depends on one, a tensor made from
# host data (a host-to-device copy, replayed from the same host memory each time).
_NOT_CAPTURABLE = {"_local_scalar_dense", "nonzero", "masked_select", "unique", "_unique2", "lift_fresh",
                   "lift_fresh_copy", "repeat_interleave"}


def _operations(fn) -> list[str]:
    """The PyTorch operations ``fn`` dispatches outside Triton's kernels (the interpreter's own copies excluded)."""
    from torch.utils._python_dispatch import TorchDispatchMode

    from cylindersplat.benchmarks.launches import LaunchCount, _triton_launches

    names, inside = [], [False]

    class Watch(TorchDispatchMode):
        def __torch_dispatch__(self, func, types, args=(), kwargs=None):
            if not inside[0]:
                names.append(func.overloadpacket.__name__)
            return func(*args, **(kwargs or {}))

    with _triton_launches(LaunchCount(), inside), Watch():
        fn()
    return names


@pytest.mark.parametrize("camera", list(CAMERAS))
def test_the_captured_forward_and_backward_hold_nothing_a_graph_cannot(camera):
    params = {k: v.detach().requires_grad_() for k, v in _scene().tensors().items()}
    graph = graphs.RenderGraph(Gaussians(**params), _pose(0.0), CAMERAS[camera], background=(0.1, 0.2, 0.3),
                               backward=True)
    graph(Gaussians(**params), _pose(0.3))  # sizes the buffers, warms the caches (as the capture's warm-up does)
    inputs = graph._checked_inputs(Gaussians(**params), _pose(0.3))
    outputs = []
    forward = _operations(lambda: outputs.append(graph._render_recorded(*inputs)))
    rgb, depth, alpha, _ = outputs[0]
    backward = _operations(lambda: torch.autograd.grad([rgb, depth, alpha], inputs[:-1],
                                                       [torch.ones_like(rgb), torch.ones_like(depth),
                                                        torch.ones_like(alpha)]))
    assert "sort" in forward and len(backward) > 0  # the watch saw the work
    assert [name for name in forward + backward if name in _NOT_CAPTURABLE] == []


def test_the_pair_count_is_the_reference_binnings():
    from cylindersplat.render import RasterSettings
    from cylindersplat.render.projection import flatten_cameras, project_gaussians
    from cylindersplat.render.rasterize import bin_to_tiles
    from cylindersplat.render.triton_projection import project_dense_triton

    g, pose = _scene(), _pose(0.4)
    with graphs._capturable_forward():
        render(g, pose, CAMERAS["pinhole"], backend="triton")  # sizes the buffers
        with recording_reads() as record:
            render(g, pose, CAMERAS["pinhole"], backend="triton")
    proj = project_gaussians(*flatten_cameras(g, pose[None])[:2], CAMERAS["pinhole"], RasterSettings(),
                             project_dense_triton, every_pair=True)
    assert int(record.values[0]) == len(bin_to_tiles(proj, 16).gaussian)


def test_recording_the_default_forward_is_refused():
    with recording_reads(), pytest.raises(RuntimeError, match="lean forward"):
        render(_scene(), _pose(0.0), CAMERAS["equirect"], backend="triton")
    assert triton_backend.FORWARD == "default"


def test_pairs_that_outgrow_the_graph_are_captured_again(monkeypatch):
    from cylindersplat.render import RasterSettings

    monkeypatch.setattr(graphs, "CAPACITY_HEADROOM", 1.0)  # buffers of exactly the first inputs' pairs
    monkeypatch.setattr(graphs, "CAPACITY_EXTRA", 0)
    small, large = _scene(scale=(0.01, 0.02)), _scene(scale=(0.3, 0.6))
    camera, settings = Equirect(32, 64), RasterSettings(tile_size=8)
    graph = graphs.RenderGraph(small, _pose(0.0), camera, settings=settings)
    _assert_same_render(graph(small, _pose(0.0)), render(small, _pose(0.0), camera, backend="triton",
                                                         settings=settings))
    pairs = graph.capacity
    assert 30 <= pairs < 100  # the small scene's own pairs, not the lean binning's first guess (4 per Gaussian + 1024)
    out = graph(large, _pose(0.0))  # more pairs than the first capture's buffers hold
    assert graph.captures == 2 and graph.capacity > pairs
    _assert_same_render(out, render(large, _pose(0.0), camera, backend="triton", settings=settings))
    assert graph(small, _pose(0.0)).alpha.max() > 0 and graph.captures == 2  # fewer pairs fit: no capture


def test_the_buffers_hold_the_first_inputs_pairs_with_headroom():
    g = _scene()
    graph = graphs.RenderGraph(g, _pose(0.0), CAMERAS["pinhole"])
    graph(g, _pose(0.0))
    with graphs._capturable_forward(), recording_reads() as record:
        render(g, _pose(0.0), CAMERAS["pinhole"], backend="triton")
    assert graph.capacity == int(int(record.values[0]) * graphs.CAPACITY_HEADROOM) + graphs.CAPACITY_EXTRA


def test_bad_values_raise_what_render_raises():
    g = _scene()
    graph = graphs.RenderGraph(g, _pose(0.0), CAMERAS["equirect"])
    means = g.means.clone()
    means[3, 1] = float("nan")
    bad = Gaussians(means, g.scales, g.rotations, g.opacities, g.sh)
    with pytest.raises(ValueError) as from_render:
        render(bad, _pose(0.0), CAMERAS["equirect"], backend="triton")
    with pytest.raises(ValueError) as from_graph:
        graph(bad, _pose(0.0))
    assert str(from_graph.value) == str(from_render.value) and "means" in str(from_graph.value)
    first_bad = graphs.RenderGraph(bad, _pose(0.0), CAMERAS["equirect"])
    with pytest.raises(ValueError, match="means"):
        first_bad(bad, _pose(0.0))  # refused before any capture
    assert first_bad.captures == 0
    pose = _pose(0.0)
    pose[0, 0] = float("inf")
    with pytest.raises(ValueError, match="c2w"):
        graph(g, pose)
    _assert_same_render(graph(g, _pose(0.0)), render(g, _pose(0.0), CAMERAS["equirect"], backend="triton"))


def test_a_far_camera_warns_as_render_does():
    g = _scene()
    graph = graphs.RenderGraph(g, _pose(0.0), CAMERAS["equirect"])
    far = yaw_pose(0.0, translation=(5e4, 0.0, 0.0), dtype=F32).to(DEVICE)
    with pytest.warns(RuntimeWarning, match="from the origin"):
        out = graph(g, far)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _assert_same_render(out, render(g, far, CAMERAS["equirect"], backend="triton"))


def test_other_sizes_and_gradients_without_backward_are_refused():
    g = _scene()
    graph = graphs.RenderGraph(g, _pose(0.0), CAMERAS["equirect"])
    with pytest.raises(ValueError, match=r"captured for means of shape \(30, 3\)"):
        graph(_scene(n=31), _pose(0.0))
    with pytest.raises(ValueError, match="c2w"):
        graph(g, torch.stack([_pose(0.0), _pose(1.0)]))
    with pytest.raises(ValueError, match="float32"):
        graph(g.to(torch.float64), _pose(0.0))
    wanting = Gaussians(**{k: v.detach().requires_grad_() for k, v in g.tensors().items()})
    with pytest.raises(ValueError, match="backward=True"):
        graph(wanting, _pose(0.0))
    with torch.no_grad():
        _assert_same_render(graph(wanting, _pose(0.0)), render(g, _pose(0.0), CAMERAS["equirect"], backend="triton"))
    with pytest.raises(TypeError, match="Gaussians"):
        graph(g.means, _pose(0.0))


def test_a_device_without_graphs_is_refused(monkeypatch):
    monkeypatch.delitem(graphs._ENGINES, "cpu", raising=False)
    with pytest.raises(ValueError, match="needs the Gaussians on a CUDA device"):
        graphs.RenderGraph(_scene().to("cpu"), _pose(0.0).cpu(), CAMERAS["equirect"])


def test_deferred_values_read_alone_are_recorded_with_no_count():
    from cylindersplat.render.projection import DeferredValues

    values = DeferredValues([torch.tensor(False), torch.tensor(3)])
    with recording_reads() as record:
        assert values.read() is None and values.read() is None  # recorded once, read by nobody
    assert record.values.tolist() == [0, 0, 3] and record.capacity is None
    assert DeferredValues([torch.tensor(False), torch.tensor(3)]).read() == [0, 3]  # outside: read now
