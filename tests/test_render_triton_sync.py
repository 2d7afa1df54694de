"""Host synchronisations of the Triton render path (issue 35): none of its own host copies, and no new implicit
synchronisation beyond the known ones listed here (which the issue wants gone; removing one updates the list).

On a machine without a GPU the path runs in Triton's interpreter (conftest.py); the check records which
``torch.Tensor`` methods that wait for the device are called *directly from cylindersplat's code* (Triton's
interpreter copies tensors itself; those calls are not the render path's)."""

import pytest
import torch

pytest.importorskip("triton")

from cylindersplat.gaussians import Gaussians  # noqa: E402
from cylindersplat.render import render_equirect  # noqa: E402
from render_scenes import shell_scene  # noqa: E402
from tensor_waits import HOST_COPIES, waits_during  # noqa: E402

DEVICE = "cuda" if torch.cuda.is_available() else "cpu"
# The implicit synchronisations left (file, function): input validation (finite values, rigid poses, camera
# distance), the compaction of visible pairs and the pair count that sizes the binning's buffers.
KNOWN = {
    ("__bool__", "gaussians/container.py", "validate"),
    ("__bool__", "geometry/poses.py", "validate_c2w"),
    ("__float__", "validation.py", "farthest_camera"),
    ("nonzero", "render/projection.py", "_compact"),
    ("__int__", "render/triton_binning.py", "bin_to_tiles_by_key"),
}


def _calls_during(fn) -> set:
    """(method, file under cylindersplat/, function) of every watched Tensor method cylindersplat calls in ``fn``."""
    return set(waits_during(fn))


@pytest.mark.parametrize("binning,backward", [("key64", "sums"), ("depth_tile", "joined"), ("fused", "chunked8")])
def test_the_triton_render_path_makes_no_host_copies_and_no_new_synchronisation(monkeypatch, binning, backward):
    from cylindersplat.render import triton_backend, triton_binning

    monkeypatch.setattr(triton_binning, "BINNING", binning)  # every variant (issue 35) makes the same one sync
    monkeypatch.setattr(triton_backend, "BACKWARD", backward)
    g = shell_scene(20, seed=1, dtype=torch.float32)
    params = {k: v.to(DEVICE).requires_grad_() for k, v in g.tensors().items()}

    def forward_and_backward():
        out = render_equirect(Gaussians(**params), torch.eye(4, device=DEVICE), 8, 16, backend="triton")
        (out.rgb.sum() + out.depth.sum()).backward()

    calls = _calls_during(forward_and_backward)
    assert params["means"].grad.abs().max() > 0  # the path really ran, backward included
    assert not {c for c in calls if c[0] in HOST_COPIES}, calls
    assert calls - KNOWN == set(), f"new host synchronisation in the render path: {sorted(calls - KNOWN)}"


# The lean forward (triton_backend.FORWARD = "lean") reads the pair count once, after the compositing is queued,
# instead of the binning's read before it sizes its buffers.
LEAN_KNOWN = KNOWN - {("__int__", "render/triton_binning.py", "bin_to_tiles_by_key")} | {
    ("__int__", "render/triton_backend.py", "_lean_backend")}


@pytest.mark.parametrize("backward", ["joined", "chunked4"])
def test_the_lean_forward_reads_the_pair_count_once_after_compositing(monkeypatch, backward):
    from cylindersplat.render import triton_backend, triton_binning

    monkeypatch.setattr(triton_backend, "FORWARD", "lean")
    monkeypatch.setattr(triton_backend, "BACKWARD", backward)
    monkeypatch.setattr(triton_binning, "_CAPACITY", {})
    g = shell_scene(20, seed=1, dtype=torch.float32)
    params = {k: v.to(DEVICE).requires_grad_() for k, v in g.tensors().items()}
    binnings = []
    original = triton_binning.bin_lean
    monkeypatch.setattr(triton_binning, "bin_lean", lambda *args: binnings.append(args[2]) or original(*args))

    def forward_and_backward():
        out = render_equirect(Gaussians(**params), torch.eye(4, device=DEVICE), 8, 16, backend="triton")
        (out.rgb.sum() + out.depth.sum()).backward()

    calls = _calls_during(forward_and_backward)
    assert params["means"].grad.abs().max() > 0
    assert not {c for c in calls if c[0] in HOST_COPIES}, calls
    assert calls - LEAN_KNOWN == set(), f"new host synchronisation in the lean path: {sorted(calls - LEAN_KNOWN)}"
    assert ("__int__", "render/triton_binning.py", "bin_to_tiles_by_key") not in calls
    assert len(binnings) == 1  # the first capacity was large enough: no rerun
