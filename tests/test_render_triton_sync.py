"""Host synchronisations of the Triton render path (issue 35): one read of the device per forward, none in the
backward.

On a machine without a GPU the path runs in Triton's interpreter (conftest.py); the check records which
``torch.Tensor`` methods that wait for the device are called *directly from cylindersplat's code* (Triton's
interpreter copies tensors itself; those calls are not the render path's), in order, each call once.

The rule: the whole forward + backward makes exactly one such call, :data:`ONE_READ` - the ``tolist`` of
:meth:`.projection.DeferredValues.read_with`, which copies the pair count that sizes the binning's buffers (or, in
the lean forward, tells whether they held every pair) together with the render's deferred input checks (the
Gaussians' and poses' values, the cameras' distance, the number of visible pairs) in one copy. That ``tolist`` is
the only host copy allowed; any other call, of a host copy or of an implicit wait (``__bool__``, ``__int__``,
``nonzero``, ...), fails the test. With ``triton_backend.COMPACTION = "nonzero"`` (the visible pairs compacted
first) there is one more, the compaction's ``nonzero``.
"""

import pytest
import torch

pytest.importorskip("triton")

from cylindersplat.gaussians import Gaussians  # noqa: E402
from cylindersplat.render import render_equirect  # noqa: E402
from render_scenes import shell_scene  # noqa: E402
from tensor_waits import waits_during  # noqa: E402

DEVICE = "cuda" if torch.cuda.is_available() else "cpu"
ONE_READ = ("tolist", "render/projection.py", "read_with")  # the pair count and the deferred checks, one copy
COMPACTION_READ = ("nonzero", "render/projection.py", "_pairs")  # COMPACTION = "nonzero" only


def _params():
    g = shell_scene(20, seed=1, dtype=torch.float32)
    return {k: v.to(DEVICE).requires_grad_() for k, v in g.tensors().items()}


def _forward_then_backward(params, background=None) -> tuple[list, list]:
    """The waits of one render's forward, then of its backward (each a list, in order)."""
    outputs = []

    def forward():
        outputs.append(render_equirect(Gaussians(**params), torch.eye(4, device=DEVICE), 8, 16,
                                       background=background, backend="triton"))

    forward_waits = waits_during(forward)
    out = outputs[0]
    backward_waits = waits_during(lambda: (out.rgb.sum() + out.depth.sum()).backward())
    assert params["means"].grad.abs().max() > 0  # the path really ran, backward included
    return forward_waits, backward_waits


@pytest.mark.parametrize("background", [None, [1, 1, 1], (0.2, 0.3, 0.4)], ids=["black", "white", "rgb"])
def test_the_triton_render_path_reads_the_device_once(background):
    # a background given as numbers is made on the device by fills, not copied there (a copy would wait)
    forward_waits, backward_waits = _forward_then_backward(_params(), background)
    assert forward_waits == [ONE_READ]
    assert backward_waits == []


def test_a_pinhole_render_reads_its_intrinsics_when_the_camera_is_made_not_per_render():
    # (intrinsics on a GPU read as numbers each render were four waits for the device a render)
    from cylindersplat.render import Pinhole, render

    k = torch.tensor([[14.0, 0.0, 12.3], [0.0, 15.0, 9.6], [0.0, 0.0, 1.0]], device=DEVICE)
    camera = Pinhole(k, 20, 24)
    params = _params()
    outputs = []
    forward_waits = waits_during(lambda: outputs.append(render(Gaussians(**params), torch.eye(4, device=DEVICE),
                                                               camera, backend="triton")))
    assert forward_waits == [ONE_READ]
    assert waits_during(lambda: (outputs[0].rgb.sum() + outputs[0].depth.sum()).backward()) == []
    assert outputs[0].alpha.max() > 0


def test_the_lean_forward_reads_the_device_once_after_compositing(monkeypatch):
    from cylindersplat.render import triton_backend, triton_binning

    monkeypatch.setattr(triton_backend, "FORWARD", "lean")
    monkeypatch.setattr(triton_binning, "_CAPACITY", {})
    binnings = []
    original = triton_binning.bin_lean
    monkeypatch.setattr(triton_binning, "bin_lean", lambda *args: binnings.append(args[2]) or original(*args))
    forward_waits, backward_waits = _forward_then_backward(_params())
    assert forward_waits == [ONE_READ]
    assert backward_waits == []
    assert len(binnings) == 1  # the first capacity was large enough: no rerun


@pytest.mark.parametrize("forward", ["default", "lean"])
def test_compacting_the_visible_pairs_adds_its_one_nonzero(monkeypatch, forward):
    from cylindersplat.render import triton_backend

    monkeypatch.setattr(triton_backend, "COMPACTION", "nonzero")
    monkeypatch.setattr(triton_backend, "FORWARD", forward)
    forward_waits, backward_waits = _forward_then_backward(_params())
    assert forward_waits == [COMPACTION_READ, ONE_READ]
    assert backward_waits == []
