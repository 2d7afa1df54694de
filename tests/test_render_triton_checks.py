"""The Triton backend's input checks in one kernel launch (issue 35, :mod:`cylindersplat.render.triton_checks`).

The reference is the PyTorch checks they replace (``api._queue_checks_torch``: ``isfinite``, comparisons and norms,
each check its own operations): on clean input and on each kind of bad value, in every float type, batched, not
contiguous, empty, past one program's share of the Gaussians and past one step of the cameras' loop, the kernel's
two flags (an input problem, a camera too far) are raised exactly where those are. The render then launches some
seventy fewer kernels per forward (counted by :func:`cylindersplat.benchmarks.launches.count_launches`).

Without a GPU the kernel runs in Triton's interpreter (conftest.py)."""

import pytest
import torch

pytest.importorskip("triton")

from cylindersplat.benchmarks.launches import count_render_launches  # noqa: E402
from cylindersplat.gaussians import Gaussians  # noqa: E402
from cylindersplat.render import api, render_equirect, triton_backend  # noqa: E402
from cylindersplat.render.triton_checks import queue_input_checks  # noqa: E402
from render_scenes import shell_scene, yaw_pose  # noqa: E402

DEVICE = "cuda" if torch.cuda.is_available() else "cpu"


def _flags(checks) -> list[bool]:
    return [bool(f) for f in checks]


def _agree(g: Gaussians, c2w: torch.Tensor) -> list[bool]:
    fused, reference = _flags(queue_input_checks(g, c2w)), _flags(api._queue_checks_torch(g, c2w))
    assert fused == reference
    return fused


def _scene(n=9, dtype=torch.float32, sh_degree=0, seed=4) -> Gaussians:
    g = shell_scene(n, seed=seed, sh_degree=sh_degree, dtype=dtype)
    return Gaussians(**{k: v.to(DEVICE) for k, v in g.tensors().items()})


def _poses(num=2, dtype=torch.float32) -> torch.Tensor:
    return torch.stack([yaw_pose(0.3 * i, (0.1 * i, 0.0, -0.2)) for i in range(num)]).to(DEVICE, dtype)


def _set(name, index, value):
    def change(g, c2w):
        getattr(g, name).view(-1)[index] = value
        return g, c2w
    change.__name__ = f"{name}[{index}]={value}"
    return change


def _pose(index, value):
    def change(g, c2w):
        c2w.view(-1)[index] = value
        return g, c2w
    change.__name__ = f"c2w[{index}]={value}"
    return change


def _zero_quaternion(g, c2w):
    g.rotations[3] = 0.0
    return g, c2w


def _reflection(g, c2w):
    c2w[1, :3, 0] *= -1
    return g, c2w


def _far(g, c2w):
    c2w[1, 0, 3] = 12_000.0
    return g, c2w


def _far_and_nan_scale(g, c2w):
    c2w[0, 2, 3] = -10_001.0
    g.scales[0, 0] = float("nan")
    return g, c2w


CHANGES = [
    _set("means", 7, float("nan")), _set("means", 26, float("inf")), _set("scales", 0, float("-inf")),
    _set("scales", 13, -1e-6), _set("rotations", 35, float("nan")), _set("opacities", 8, 1.001),
    _set("opacities", 0, -0.5), _set("opacities", 4, float("nan")), _set("sh", 20, float("inf")),
    _zero_quaternion, _pose(5, float("nan")), _pose(16 + 0, 1.01), _pose(12, 0.5), _pose(15, 0.99),
    _reflection, _far, _far_and_nan_scale,
]


@pytest.mark.parametrize("change", CHANGES, ids=lambda c: c.__name__)
def test_each_bad_value_raises_the_flag_the_torch_checks_raise(change):
    g, c2w = change(_scene(), _poses())
    flags = _agree(g, c2w)
    assert any(flags)  # the change is bad input indeed


def test_clean_input_and_edge_values_raise_nothing():
    g, c2w = _scene(), _poses()
    g.opacities[0], g.opacities[1], g.scales[2] = 0.0, 1.0, torch.tensor([0.0, 0.0, 0.0])  # the ranges' ends
    g.rotations[5] = torch.tensor([0.0, 0.0, 0.0, 1e-3])  # small, not zero
    c2w[0, 0, 0] += 4e-4  # within the pose tolerance (|R R^T - I| about 8e-4)
    c2w[1, :3, 3] = torch.tensor([6000.0, 0.0, 8000.0])  # exactly the plausible distance
    assert _agree(g, c2w) == [False, False]


@pytest.mark.parametrize("dtype", [torch.float64, torch.float16, torch.bfloat16])
def test_every_float_type(dtype):
    g, c2w = _scene(dtype=dtype), _poses(dtype=torch.float64)
    assert _agree(g, c2w) == [False, False]
    g.sh[2, 0, 1] = float("nan")
    assert _agree(g, c2w) == [True, False]
    if dtype == torch.float64:  # beyond float32's range, yet finite: no flag (the kernel compares in the input's type)
        g.sh[2, 0, 1] = 1e300
        g.opacities[1] = 1.0 + 2**-40  # above 1 only in float64
        assert _agree(g, c2w) == [True, False]


def test_batched_non_contiguous_and_higher_degree_inputs():
    base = _scene(n=11, sh_degree=2)
    batched = Gaussians(**{k: torch.stack([v, v.flip(0)]) for k, v in base.tensors().items()})
    strided = Gaussians(**{k: v.transpose(0, 1).contiguous().transpose(0, 1) for k, v in batched.tensors().items()})
    assert not strided.means.is_contiguous()
    c2w = torch.stack([_poses(3), _poses(3)])
    assert _agree(strided, c2w) == [False, False]
    strided.sh[1, 10, 8, 2] = float("nan")  # the last value of the last Gaussian's highest coefficient
    assert _agree(strided, c2w) == [True, False]


def test_past_one_program_and_one_camera_step():
    # 700 Gaussians: 2800 quaternion values, three programs of 1024; 40 cameras: two steps of 32.
    g, c2w = _scene(n=700), _poses(40)
    assert _agree(g, c2w) == [False, False]
    g.rotations[699] = 0.0
    assert _agree(g, c2w) == [True, False]
    g.rotations[699] = 1.0
    c2w[39, 0, 3] = 20_000.0
    assert _agree(g, c2w) == [False, True]


def test_no_gaussians_and_no_cameras():
    empty = Gaussians.empty(device=DEVICE)
    assert _agree(empty, _poses()) == [False, False]
    assert _agree(empty, _poses()[:0]) == [False, False]
    c2w = _poses()
    c2w[0, 3, 3] = float("nan")
    assert _agree(empty, c2w) == [True, False]


def test_bad_structure_raises_now_as_the_torch_checks():
    g, c2w = _scene(), _poses()
    for bad in (Gaussians.__new__(Gaussians),):
        object.__setattr__(bad, "means", g.means[:, :2])
        for name in ("scales", "rotations", "opacities", "sh"):
            object.__setattr__(bad, name, getattr(g, name))
        messages = []
        for queue in (queue_input_checks, api._queue_checks_torch):
            with pytest.raises(ValueError) as caught:
                queue(bad, c2w)
            messages.append(str(caught.value))
        assert messages[0] == messages[1] and "means must have shape" in messages[0]
    for poses, error in ((c2w[..., :3], ValueError), (c2w.tolist(), TypeError)):
        for queue in (queue_input_checks, api._queue_checks_torch):
            with pytest.raises(error, match="c2w must"):
                queue(g, poses)


def _launches(monkeypatch, check: str, forward: str, background=None):
    monkeypatch.setattr(triton_backend, "CHECK", check)
    monkeypatch.setattr(triton_backend, "FORWARD", forward)
    g = _scene(n=20)
    params = {k: v.clone().requires_grad_() for k, v in g.tensors().items()}
    c2w = torch.eye(4, device=DEVICE)
    return count_render_launches(lambda: render_equirect(Gaussians(**params), c2w, 8, 16, background=background,
                                                         backend="triton"))


def test_an_rgb_background_costs_only_its_blending(monkeypatch):
    # A training step renders with its config's RGB tuple: made on the device once (4 fills) and checked on the
    # host, it costs each later render only the blend under the image (1 - alpha, its product, the sum: 3).
    plain, _ = _launches(monkeypatch, "fused", "default")
    with_rgb, _ = _launches(monkeypatch, "fused", "default", background=(0.2, 0.3, 0.4))
    assert with_rgb.kernels - plain.kernels <= 3, (plain, with_rgb)


@pytest.mark.parametrize("forward", ["default", "lean"])
def test_the_fused_checks_launch_one_kernel_where_pytorch_launches_dozens(monkeypatch, forward):
    fused, fused_backward = _launches(monkeypatch, "fused", forward)
    torch_checks, torch_backward = _launches(monkeypatch, "torch", forward)
    assert fused.triton["input_checks_kernel"] == 1 and "input_checks_kernel" not in torch_checks.triton
    assert torch_checks.kernels - fused.kernels >= 60  # 98 -> 24 (default), 94 -> 20 (lean) on 2026-11-26
    # The whole forward: checks, projection, binning, compositing (20 default / 18 lean since session 21, which
    # dropped the compositing rows' concatenation; 24 / 20 in session 18, 112 / 105 before). The backward: 14 with
    # the loss's own four and the copies of its two expanded gradients (17 in session 18, 31 / 26 before).
    assert fused.kernels <= (20 if forward == "default" else 18)
    assert fused_backward.kernels == torch_backward.kernels <= 15
