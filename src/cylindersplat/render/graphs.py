"""Renders of fixed sizes replayed as CUDA graphs (issue 35): the host's part of a render made once.

A render on the Triton backend is some twenty kernel launches, the Python between them and one read of the device
(the pair count). Where a render repeats with the same sizes - a viewer's or a video's frames of one scene, a
training step's render of a model's fixed number of Gaussians - :class:`RenderGraph` captures it once as a CUDA graph
(the forward, or the forward and its backward) and then renders by copying the inputs into the graph's, launching it
and making the one read::

    graph = RenderGraph(gaussians, c2w, Pinhole(K, 512, 1024))          # forward only: outputs without gradients
    for pose in poses:
        frame = graph(gaussians, pose).rgb                             # == render(gaussians, pose, camera).rgb

    graph = RenderGraph(gaussians, c2w, camera, backward=True)         # forward and backward, for training
    out = graph(gaussians, c2w); loss(out).backward()                  # gradients reach gaussians' tensors

What is fixed at capture: the camera model, the settings, the background, and the shapes, dtypes and device of the
Gaussians' tensors and of ``c2w`` (and, with ``backward``, which tensors require gradients); another shape is
refused with a message. What a capture cannot know is read after each replay, with the pair count: where the pairs
outgrew the graph's buffers, the render is captured again with room for them; where an input check failed, a camera
is far, or nothing is visible, the render is made again by :func:`.render` - which raises or warns as it always does.
Outputs are the caller's own tensors (copies of the graph's, which the next replay overwrites). With ``backward``,
a render's backward must come before the graph's next render (which replaces what the backward reads); one that
comes after raises.

The capture runs the Triton backend's lean forward (:data:`.triton_backend.FORWARD` ``"lean"``, no compaction),
whose one read is recorded, not made (:func:`.projection.recording_reads`); the images are those of that forward,
which equal the default one's bit for bit, and so are the gradients (to float32 rounding on a GPU, whose atomics
add in any order; ``tests/test_render_graphs.py``).
"""

from __future__ import annotations

import contextlib
from dataclasses import fields

import torch
from torch import Tensor

from ..gaussians import Gaussians
from .api import RenderOutput, render
from .cameras import CameraModel
from .projection import RasterSettings, recording_reads
from .triton_binning import pinned_capacity

__all__ = ["RenderGraph", "CAPACITY_HEADROOM", "CAPACITY_EXTRA"]

# A graph's pair buffers: the pairs of the inputs it is captured with, times this, plus that. Another view of the
# scene may make more pairs (the graph is then captured again: a render and a capture); every place is sorted and
# written at each replay, used or not (a pinhole view of 1.3 M Gaussians made 3.2 M pairs, for which the lean
# binning's first guess, 4 per Gaussian, keeps 5.2 M).
CAPACITY_HEADROOM = 1.2
CAPACITY_EXTRA = 1024


@contextlib.contextmanager
def _capturable_forward():
    """The Triton backend's variant whose forward reads the device once, after all its work: the lean forward, every
    pair projected (no compaction, which would read the count of visible pairs)."""
    from . import triton_backend

    before = triton_backend.FORWARD, triton_backend.COMPACTION
    triton_backend.FORWARD, triton_backend.COMPACTION = "lean", "none"
    try:
        yield
    finally:
        triton_backend.FORWARD, triton_backend.COMPACTION = before


class _CudaGraphReplay:
    """A function of tensors captured as CUDA graphs: its forward (under ``torch.no_grad`` where not ``backward``),
    and with ``backward`` the gradients of its floating outputs with respect to its inputs that require them. Calling
    it copies the inputs into the graph's and replays; the outputs are the graph's own tensors, and with
    ``backward`` a backward through them replays the backward graph (:class:`_Replayed`)."""

    def __init__(self, fn, inputs: tuple[Tensor, ...], backward: bool):
        self.backward, self._inputs = backward, inputs
        self._wanting = [i for i, t in enumerate(inputs) if backward and t.requires_grad]
        wanted = [inputs[i] for i in self._wanting]

        def forward():
            # (autocast off: its cache of cast copies, made and freed around a capture, cannot be held by a graph;
            # the render computes in float32 whatever autocast says)
            with torch.autocast(device_type="cuda", enabled=False), torch.set_grad_enabled(backward):
                return fn(*inputs)

        def gradients(outputs, output_grads):
            return torch.autograd.grad(self._differentiable(outputs), wanted, output_grads, allow_unused=True)

        self._warm_up(forward, gradients)
        pool = self._pool()  # one pool: the backward reads what the forward saved
        self._forward, self._outputs = self._captured(forward, pool)
        if self._wanting:
            self._output_grads = [torch.empty_like(o) for o in self._differentiable(self._outputs)]
            self._backward, self._input_grads = self._captured(
                lambda: gradients(self._graph_outputs(), self._output_grads), pool)

    def _warm_up(self, forward, gradients) -> None:
        """Two runs on a side stream: the kernels compile and the caches fill outside the capture."""
        current, side = torch.cuda.current_stream(), torch.cuda.Stream()
        side.wait_stream(current)
        with torch.cuda.stream(side):
            for _ in range(2):
                outputs = forward()
                if self._wanting:
                    gradients(outputs, [torch.ones_like(o) for o in self._differentiable(outputs)])
        current.wait_stream(side)

    def _pool(self):
        return torch.cuda.graph_pool_handle()

    def _captured(self, work, pool):
        """``work()`` captured: the graph and the tensors it wrote (its outputs at every replay)."""
        graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(graph, pool=pool):
            result = work()
        return graph, result

    def _graph_outputs(self) -> tuple[Tensor, ...]:
        """The forward's outputs the backward's capture differentiates (the captured forward's own)."""
        return self._outputs

    @staticmethod
    def _differentiable(outputs) -> list[Tensor]:
        return [o for o in outputs if o.requires_grad]

    def copy_in(self, inputs: tuple[Tensor, ...]) -> None:
        for mine, given in zip(self._inputs, inputs):
            if mine.data_ptr() != given.data_ptr():
                mine.copy_(given.detach())

    def __call__(self, *inputs: Tensor) -> tuple[Tensor, ...]:
        if self._wanting:
            return _Replayed.apply(self, *inputs)
        self.copy_in(inputs)
        self._forward.replay()
        return self._outputs


class _Replayed(torch.autograd.Function):
    """A forward replay whose backward replays the backward graph. The gradients handed back are copies: the
    graph's own buffers are overwritten by its next backward (a caller's ``.grad`` must not be one of them)."""

    @staticmethod
    def forward(ctx, engine, *inputs):
        engine.copy_in(inputs)
        engine._forward.replay()
        ctx.engine = engine
        outputs = tuple(o.detach() for o in engine._outputs)
        ctx.mark_non_differentiable(*(o for o, mine in zip(outputs, engine._outputs) if not mine.requires_grad))
        return outputs

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, *grads):
        engine = ctx.engine
        given = [g for g, mine in zip(grads, engine._outputs) if mine.requires_grad]
        for buffer, grad in zip(engine._output_grads, given):
            buffer.zero_() if grad is None else buffer.copy_(grad)
        engine._backward.replay()
        out = [None] * len(engine._inputs)
        for i, grad in zip(engine._wanting, engine._input_grads):
            out[i] = None if grad is None else grad.clone()
        return (None, *out)


_ENGINES = {"cuda": _CudaGraphReplay}  # device type -> how a render is captured and replayed


class _Handout(torch.autograd.Function):
    """The graph's outputs handed to the caller as copies (the next replay overwrites the graph's), whose backward
    refuses to run once another render of the graph has replaced what the graph's backward reads."""

    @staticmethod
    def forward(ctx, graph, generation, rgb, depth, alpha):
        ctx.graph, ctx.generation = graph, generation
        return rgb.clone(), depth.clone(), alpha.clone()

    @staticmethod
    def backward(ctx, grad_rgb, grad_depth, grad_alpha):
        if ctx.graph.renders != ctx.generation:
            raise RuntimeError(
                f"this render's backward came after render {ctx.graph.renders} of the same RenderGraph, which replaced "
                f"what it needs (the graph keeps one render's intermediates): call backward before the next render")
        return None, None, grad_rgb, grad_depth, grad_alpha


def _check_types(gaussians, c2w) -> None:
    if not isinstance(gaussians, Gaussians):
        raise TypeError(f"gaussians must be a cylindersplat.gaussians.Gaussians, got {type(gaussians).__name__}")
    if not isinstance(c2w, Tensor):
        raise TypeError(f"c2w must be a tensor of 4x4 camera-to-world poses, got {type(c2w).__name__}")


class RenderGraph:
    """:func:`.render` on the Triton backend, captured once as a CUDA graph for inputs of the sizes of ``gaussians``
    and ``c2w`` and replayed at each call (module docstring).

    Args:
        gaussians, c2w: inputs of the sizes to capture (their values are used to warm up and size the buffers).
        camera, background, settings: as for :func:`.render`, fixed for the graph.
        backward: capture the backward too (outputs with gradients); else outputs carry none, and a call whose
            inputs require gradients while gradients are enabled is refused.
    """

    def __init__(self, gaussians: Gaussians, c2w: Tensor, camera: CameraModel,
                 background: Tensor | tuple[float, float, float] | None = None,
                 settings: RasterSettings | None = None, backward: bool = False):
        _check_types(gaussians, c2w)
        device = gaussians.device
        if device.type not in _ENGINES:
            raise ValueError(f"RenderGraph captures CUDA graphs and needs the Gaussians on a CUDA device, got "
                             f"{device}; render() there instead")
        self.camera, self.settings, self.backward = camera, settings, bool(backward)
        # The graph reads the background where it is: a tensor this graph keeps (numbers are made on the device once;
        # render()'s own cache of them may drop one that a graph still reads).
        if background is not None and not isinstance(background, Tensor):
            background = torch.as_tensor([float(x) for x in background], dtype=gaussians.dtype).to(device)
        self.background = background
        self._names = [f.name for f in fields(Gaussians)]
        self._shapes = {name: (tuple(t.shape), t.dtype, t.requires_grad if backward else None)
                        for name, t in zip((*self._names, "c2w"), self._inputs(gaussians, c2w.to(device)), strict=True)}
        self._device = device
        self._replay = None
        self.capacity = 0  # the graph's pair buffers (sized at capture for the pairs of its inputs, with headroom)
        self.renders = 0  # replays made (a handed-out output's backward must belong to the latest)
        self.captures = 0  # graphs captured (again where the pairs outgrew a graph's buffers)

    def _inputs(self, gaussians: Gaussians, c2w: Tensor) -> tuple[Tensor, ...]:
        return (*(getattr(gaussians, name) for name in self._names), c2w)

    def _checked_inputs(self, gaussians: Gaussians, c2w: Tensor) -> tuple[Tensor, ...]:
        _check_types(gaussians, c2w)
        inputs = self._inputs(gaussians, c2w.to(self._device))
        for name, t in zip(self._shapes, inputs, strict=True):
            shape, dtype, grad = self._shapes[name]
            if tuple(t.shape) != shape or t.dtype != dtype or t.device != self._device:
                raise ValueError(f"this RenderGraph was captured for {name} of shape {shape}, {dtype} on "
                                 f"{self._device}; got {tuple(t.shape)}, {t.dtype} on {t.device}: make a RenderGraph "
                                 "for these sizes (or render() them)")
            if grad is not None and t.requires_grad != grad:
                raise ValueError(f"this RenderGraph was captured with {name}.requires_grad={grad}; got "
                                 f"{t.requires_grad}: make one for these inputs")
        if not self.backward and torch.is_grad_enabled() and any(t.requires_grad for t in inputs):
            raise ValueError("this RenderGraph was made without backward=True, so its outputs carry no gradients, "
                             "but its inputs require them: make it with backward=True, or call it under "
                             "torch.no_grad()")
        return inputs

    def _render_recorded(self, *inputs: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """The captured function: ``(*Gaussian tensors, c2w) -> (rgb, depth, alpha, read)``, ``read`` the recorded
        values (:class:`.projection.RecordedRead`), in pair buffers of :attr:`capacity`."""
        *tensors, c2w = inputs
        with pinned_capacity(self.capacity), _capturable_forward(), recording_reads() as record:
            out = render(Gaussians(**dict(zip(self._names, tensors))), c2w, self.camera, self.background,
                         backend="triton", settings=self.settings)
        if record.values is None or record.capacity != self.capacity:
            raise RuntimeError("the captured render made no recorded read of its pair count in the graph's buffers: "
                               "it cannot be replayed")
        return out.rgb, out.depth, out.alpha, record.values

    def _pair_count(self, inputs: tuple[Tensor, ...]) -> int:
        """The pairs of ``inputs``, by one render as the graph makes it (its output dropped); inputs that fail a
        check are refused here, by :func:`.render`'s own error."""
        gaussians = Gaussians(**dict(zip(self._names, (t.detach() for t in inputs[:-1]))))
        with torch.no_grad():
            with _capturable_forward(), recording_reads() as record:
                render(gaussians, inputs[-1], self.camera, self.background, backend="triton", settings=self.settings)
            count, problem, *_ = record.values.tolist() + [0]
            if problem:
                render(gaussians, inputs[-1], self.camera, self.background, backend="triton", settings=self.settings)
        return count

    def _capture(self, inputs: tuple[Tensor, ...], count: int):
        """The engine of a graph whose buffers hold ``count`` pairs with headroom (:data:`CAPACITY_HEADROOM`)."""
        self.capacity = int(count * CAPACITY_HEADROOM) + CAPACITY_EXTRA
        # The graph reads its inputs where they are: a leaf tensor (a scene's, a trained parameter) is read in place,
        # with no copy where the same tensor comes again; another (a network's output) through a copy of its own.
        sample = tuple(t if t.grad_fn is None else t.detach().clone().requires_grad_(t.requires_grad and self.backward)
                       for t in inputs)
        self.captures += 1
        return _ENGINES[self._device.type](self._render_recorded, sample, self.backward)

    def __call__(self, gaussians: Gaussians, c2w: Tensor) -> RenderOutput:
        """``render(gaussians, c2w, camera, background, backend="triton", settings)``, by the graph."""
        inputs = self._checked_inputs(gaussians, c2w)
        if self._replay is None:
            self._replay = self._capture(inputs, self._pair_count(inputs))
        while True:
            rgb, depth, alpha, read = self._replay(*inputs)
            self.renders += 1
            count, *flags = read.tolist()  # the one wait for the device
            if count <= self.capacity:
                break
            self._replay = self._capture(inputs, count)  # the pairs outgrew the graph's buffers
        problem, far, *visible = flags  # the deferred checks (DeferredValues), the number visible where counted
        if problem or far or (visible and visible[0] == 0):  # render() raises or warns, as it does
            return render(gaussians, c2w, self.camera, self.background, backend="triton", settings=self.settings)
        if self.backward:
            rgb, depth, alpha = _Handout.apply(self, self.renders, rgb, depth, alpha)
        else:
            rgb, depth, alpha = rgb.clone(), depth.clone(), alpha.clone()
        return RenderOutput(rgb=rgb, depth=depth, alpha=alpha)
