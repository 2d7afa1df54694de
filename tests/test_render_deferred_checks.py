"""The render's input checks on a path that reads the device once (issue 35): the Triton backend queues them as
device flags that its one host read (the pair count) brings along, and renders every (camera, Gaussian) pair with
the invisible ones inert (``triton_backend.COMPACTION = "none"``) instead of compacting the visible ones. Bad input
still raises or warns with the torch backend's message (checked on the host once a flag is set); the images and
gradients are those of the compacted path and of the reference.

Without a GPU the kernels run in Triton's interpreter (conftest.py)."""

import os
import traceback
import warnings

import pytest
import torch

pytest.importorskip("triton")

from cylindersplat.gaussians import Gaussians  # noqa: E402
from cylindersplat.render import Equirect, Pinhole, RasterSettings, render, triton_backend, triton_binning  # noqa: E402
from render_scenes import shell_scene, yaw_pose  # noqa: E402
from tensor_waits import waits_during  # noqa: E402

DEVICE = "cuda" if torch.cuda.is_available() else "cpu"
F32 = torch.float32
K = torch.tensor([[14.0, 0.0, 12.3], [0.0, 15.0, 9.6], [0.0, 0.0, 1.0]])


def _scene(n=12, seed=3):
    return Gaussians(**{k: v.to(DEVICE) for k, v in shell_scene(n, seed=seed, dtype=F32).tensors().items()})


def _outcome(backend, g, c2w, background=None, camera=None):
    """(error type and message or None, the warnings' (category, message, file)) of one render."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            render(g, c2w.to(DEVICE), camera or Equirect(8, 16), background=background, backend=backend)
            error = None
        except ValueError as exc:
            error = (type(exc), str(exc))
    return error, [(w.category, str(w.message), w.filename) for w in caught]


def _nan_mean(g, c2w):
    g.means[2, 1] = float("nan")
    return g, c2w, None


def _non_rigid_pose(g, c2w):
    c2w[0, 0] = 2.0
    return g, c2w, None


def _far_camera(g, c2w):
    c2w[:3, 3] = torch.tensor([20_000.0, 0.0, 0.0])
    return g, c2w, None


def _bad_opacity_and_reflection(g, c2w):  # two problems: the first in today's order wins
    g.opacities[0] = 1.5
    c2w[0, 0] = -1.0
    return g, c2w, None


def _far_camera_and_nan_background(g, c2w):  # a warning, then an error
    c2w[:3, 3] = torch.tensor([0.0, 0.0, 30_000.0])
    return g, c2w, torch.tensor([0.1, float("nan"), 0.2])


def _nothing_visible(g, c2w):
    g.means.mul_(1e-4)  # every Gaussian closer than settings.near
    return g, c2w, None


@pytest.mark.parametrize("forward,check", [("default", "fused"), ("lean", "fused"), ("default", "torch")])
@pytest.mark.parametrize("change", [_nan_mean, _non_rigid_pose, _far_camera, _bad_opacity_and_reflection,
                                    _far_camera_and_nan_background, _nothing_visible])
def test_bad_input_raises_and_warns_as_the_torch_backend(monkeypatch, forward, check, change):
    monkeypatch.setattr(triton_backend, "FORWARD", forward)
    monkeypatch.setattr(triton_backend, "CHECK", check)  # the checks queued by one kernel, or by PyTorch
    outcomes = [_outcome(backend, *change(_scene(), torch.eye(4))) for backend in ("torch", "triton")]
    assert outcomes[0][0] is not None or outcomes[0][1]  # the change is bad input indeed
    assert outcomes[1] == outcomes[0]  # the same error, the same warnings, pointing at the same line (this file)


def test_a_failed_check_stops_the_render_at_the_one_read_before_its_buffers_are_sized(monkeypatch):
    from cylindersplat.render import projection

    g, c2w, _ = _nan_mean(_scene(), torch.eye(4))
    sized = []
    original = triton_binning._write_bins
    monkeypatch.setattr(triton_binning, "_write_bins", lambda *args: sized.append(args[4]) or original(*args))
    reads = []
    read = projection.DeferredValues.read_with
    monkeypatch.setattr(projection.DeferredValues, "read_with", lambda self, n: reads.append(n) or read(self, n))
    with pytest.raises(ValueError, match="means contains non-finite values"):
        render(g, c2w.to(DEVICE), Equirect(8, 16), backend="triton")
    assert len(reads) == 1 and sized == []  # NaN centres give any pair count: no buffer sized by it


def test_an_empty_scene_reads_its_checks_once():
    g = Gaussians.empty(device=DEVICE)
    calls = waits_during(lambda: render(g, torch.eye(4, device=DEVICE), Equirect(8, 16), background=(0.1, 0.2, 0.3),
                                        backend="triton"))
    assert calls == [("tolist", "render/projection.py", "read")]  # no pair count to read them with
    g.means = torch.full((0, 3), 0.0, device=DEVICE)
    g.sh = torch.zeros(1, 1, 3, device=DEVICE)
    with pytest.raises(ValueError, match=r"sh must have shape"):  # structure: refused at once, as before
        render(g, torch.eye(4, device=DEVICE), Equirect(8, 16), backend="triton")


def _images_and_gradients(g, poses, camera, settings=None):
    params = {k: v.detach().clone().requires_grad_() for k, v in g.tensors().items()}
    out = render(Gaussians(**params), poses.to(DEVICE), camera, background=(0.2, 0.3, 0.4), backend="triton",
                 settings=settings)
    gen = torch.Generator().manual_seed(5)
    weights = [torch.randn(t.shape, generator=gen).to(DEVICE) for t in (out.rgb, out.depth, out.alpha)]
    loss = sum((wt * t).sum() for wt, t in zip(weights, (out.rgb, out.depth, out.alpha)))
    grads = torch.autograd.grad(loss, list(params.values()), allow_unused=True)
    return out, dict(zip(params, grads))


@pytest.mark.parametrize("forward", ["default", "lean"])
def test_every_pair_gives_the_images_and_gradients_of_the_visible_pairs(monkeypatch, forward):
    # A pinhole camera (most pairs invisible: behind it or outside its view) and two panoramas.
    monkeypatch.setattr(triton_backend, "FORWARD", forward)
    g = _scene(30, seed=33)
    panoramas = torch.stack([yaw_pose(0.3, dtype=F32), yaw_pose(2.0, (0.1, -0.2, 0.1), dtype=F32)])
    for poses, camera in ((yaw_pose(0.2, dtype=F32), Pinhole(K, 20, 24)), (panoramas, Equirect(16, 32))):
        results = []
        for compaction in ("nonzero", "none"):
            monkeypatch.setattr(triton_backend, "COMPACTION", compaction)
            results.append(_images_and_gradients(g, poses, camera, RasterSettings(tile_size=8)))
        (ref, grad_ref), (out, grad) = results
        assert ref.alpha.max() > 0.3
        for name in ("rgb", "depth", "alpha"):
            torch.testing.assert_close(getattr(out, name), getattr(ref, name), atol=1e-6, rtol=1e-5, msg=name)
        for name, expected in grad_ref.items():
            torch.testing.assert_close(grad[name], expected, atol=1e-6, rtol=1e-4, msg=name)


def test_the_every_pair_rows_of_invisible_pairs_meet_no_tile():
    from cylindersplat.render.projection import flatten_cameras, project_gaussians
    from cylindersplat.render.rasterize import tile_spans

    g = _scene(30, seed=33)
    flat, c2w, _ = flatten_cameras(g, yaw_pose(0.2, dtype=F32).to(DEVICE))
    every = project_gaussians(flat, c2w, Pinhole(K, 20, 24), RasterSettings(), every_pair=True)
    visible = project_gaussians(flat, c2w, Pinhole(K, 20, 24), RasterSettings())
    assert len(every.camera) == 30 and int(every.visible) == len(visible.camera) < 30
    counts = tile_spans(every, 16).count
    assert int((counts > 0).sum()) <= int(every.visible)
    assert torch.equal(counts[visible.gaussian], tile_spans(visible, 16).count)
    assert int(counts.sum()) == int(tile_spans(visible, 16).count.sum())


def test_unknown_compaction_is_refused_by_name(monkeypatch):
    monkeypatch.setattr(triton_backend, "COMPACTION", "sparse")
    with pytest.raises(ValueError, match="unknown Triton compaction 'sparse': choose one of none, nonzero"):
        render(_scene(), torch.eye(4, device=DEVICE), Equirect(8, 16), backend="triton")


def test_a_failed_check_is_no_broken_backend_for_auto():
    from cylindersplat.render import api
    from cylindersplat.render.projection import InputCheckFailed

    def fast():
        raise InputCheckFailed("bad input")

    with pytest.raises(InputCheckFailed):
        api._run_fast(triton_backend.triton_backend, "auto", fast, lambda: None, unsupported_is_final=True)
    assert triton_backend.triton_backend not in api._AUTO_DISABLED


def test_the_bench_times_the_compacted_variant_beside_the_default(capsys):
    import argparse

    from cylindersplat.benchmarks import render as bench_render
    from cylindersplat.benchmarks import variants as bench_variants

    name = bench_variants.triton_variant_name
    assert name("default,nonzero") == ("default", "nonzero")
    assert name("lean,none") == ("lean",)
    assert name("default,none") == ("default",)
    with pytest.raises(argparse.ArgumentTypeError, match="COMPACTION one of none, nonzero"):
        name("lean,sparse")
    with bench_variants.triton_variant("default", "nonzero"):
        assert triton_backend.COMPACTION == "nonzero"
    assert triton_backend.COMPACTION == "none"
    bench_render.main(["--num", "30", "--height", "8", "--device", DEVICE, "--backend", "triton", "--repeats", "1",
                       "--stages", "--variants", "default", "default,nonzero"])
    out = capsys.readouterr().out
    assert "'backend': 'triton[default,nonzero]'" in out
    line = next(x for x in out.splitlines() if x.startswith("# agreement triton[default,nonzero] vs"))
    assert "rgb max |diff| 0.00e+00" in line, line


def test_rgb_numbers_are_made_once_per_device_and_type_and_checked_on_the_host():
    from cylindersplat.render import api

    g = _scene()
    first = api._background((0.2, 0.3, 0.4), g, (1,), 1, checks=[])
    again = api._background([0.2, 0.3, 0.4], g, (1,), 1, checks=[])
    assert again is first and first.tolist() == pytest.approx([0.2, 0.3, 0.4])
    assert api._background((1, 1, 1), g, (1,), 1, checks=[]).tolist() == [1.0, 1.0, 1.0]  # ints; one fill
    half = Gaussians(**{k: v.double() for k, v in g.tensors().items()})
    assert api._background((0.2, 0.3, 0.4), half, (1,), 1, checks=[]).dtype == torch.float64
    checks = []
    with pytest.raises(ValueError, match=r"background must be finite \(RGB in \[0, 1\]\), got \[0.2, nan, 0.4\]"):
        api._background((0.2, float("nan"), 0.4), g, (1,), 1, checks=checks)
    assert checks == []  # raised on the host at once: nothing queued for the device
    for bad, error in (((0.2, "x", 0.4), TypeError), ((0.2, 0.3), ValueError)):
        with pytest.raises(error, match="background must be RGB"):
            api._background(bad, g, (1,), 1, checks=None)
    for i in range(api._MAX_BACKGROUNDS + 3):  # bounded: many colours do not pile up tensors
        api._background((0.0, 0.0, i / 100), g, (1,), 1, checks=None)
    assert len(api._BACKGROUNDS) <= api._MAX_BACKGROUNDS


def test_the_bench_skips_the_variants_agreement_where_triton_cannot_run(monkeypatch, capsys):
    # on a GPU machine the tests run without Triton's interpreter: a CPU row of triton is skipped, and its
    # variants' agreement with it (it crashed there, gpu_check 2026-11-27)
    from cylindersplat.benchmarks import render as bench_render

    monkeypatch.delenv("TRITON_INTERPRET", raising=False)
    bench_render.main(["--num", "30", "--height", "8", "--device", "cpu", "--backend", "torch", "triton",
                       "--repeats", "1", "--variants", "default", "default,nonzero"])
    out = capsys.readouterr().out
    assert "# skipping triton on cpu" in out and "# agreement" not in out
    assert "'backend': 'torch'" in out


def _cuda_synchronisations(fn) -> list[str]:
    """Where ``fn`` makes a synchronising CUDA call (CUDA's own watch: every one, not only the Tensor methods
    tensor_waits.py sees): the Python lines that made each (``file:line`` of the last three frames), so that a
    failure says where."""
    found = []

    def record(message, *args, **kwargs):
        # (not PyTorch's one-time notice that this watch is a prototype, whose text says "synchronizing" too)
        if "called a synchronizing CUDA operation" in str(message):
            frames = [f for f in traceback.extract_stack()[:-1] if not f.filename.endswith("warnings.py")][-3:]
            found.append(" < ".join(f"{os.path.relpath(f.filename)}:{f.lineno}" for f in reversed(frames)))

    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = record
        torch.cuda.set_sync_debug_mode("warn")
        try:
            fn()
        finally:
            torch.cuda.set_sync_debug_mode("default")
    return found


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA's synchronisation watch needs a GPU")
@pytest.mark.parametrize("forward", ["default", "lean"])
@pytest.mark.parametrize("camera", ["equirect", "pinhole"])
def test_on_a_gpu_the_forward_synchronises_once_and_the_backward_never(monkeypatch, forward, camera):
    monkeypatch.setattr(triton_backend, "FORWARD", forward)
    params = {k: v.detach().clone().requires_grad_() for k, v in _scene(200, seed=4).tensors().items()}
    poses = torch.stack([yaw_pose(0.3, dtype=F32), yaw_pose(2.0, (0.1, -0.2, 0.1), dtype=F32)]).to(DEVICE)
    model = Equirect(64, 128) if camera == "equirect" else Pinhole(K, 48, 64)
    outputs = []

    def forward_pass():
        # an RGB background as a tuple: made on the device (a host-to-device copy would synchronise)
        outputs.append(render(Gaussians(**params), poses, model, background=(0.2, 0.3, 0.4), backend="triton"))

    def backward_pass():
        (outputs[-1].rgb.sum() + outputs[-1].depth.sum()).backward()

    forward_pass()
    backward_pass()  # warm-up: the kernels compile, the lean capacity grows
    torch.cuda.synchronize()
    forward_syncs, backward_syncs = _cuda_synchronisations(forward_pass), _cuda_synchronisations(backward_pass)
    assert (len(forward_syncs), len(backward_syncs)) == (1, 0), (forward_syncs, backward_syncs)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="poses on another device than the Gaussians need a GPU")
def test_poses_on_the_cpu_are_checked_beside_gaussians_on_the_gpu():
    g = _scene()
    out = render(g, torch.eye(4), Equirect(8, 16), backend="triton")
    assert out.rgb.device.type == "cuda" and out.alpha.max() > 0
    bad = torch.eye(4)
    bad[0, 0] = 2.0
    with pytest.raises(ValueError, match="not orthonormal"):
        render(g, bad, Equirect(8, 16), backend="triton")
