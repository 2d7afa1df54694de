"""How many kernels a function launches: PyTorch operations that run one (views, allocations and other
metadata-only operations left out) and Triton kernel launches, counted without a GPU (issue 35: on an H100 the
Triton render path is launch-bound, so fewer launches is the CPU-checkable half of a faster render).

    counts = count_launches(lambda: render_equirect(g, c2w, 64, 128, backend="triton"))
    counts.kernels, counts.triton, counts.torch_ops

Under Triton's CPU interpreter the interpreter's own tensor copies are not counted (they are not the render's).
A PyTorch operation may launch more than one kernel on a GPU (a sort, a cumsum): each counts once here.
"""

from __future__ import annotations

import collections
import contextlib
from dataclasses import dataclass, field
from typing import Callable

from torch.utils._python_dispatch import TorchDispatchMode

__all__ = ["LaunchCount", "count_launches", "count_render_launches"]

# Operations that launch nothing: views and shape/metadata changes, uninitialised allocations, type queries.
_NO_KERNEL = {"empty", "empty_like", "empty_strided", "new_empty", "new_empty_strided", "detach", "alias",
              "lift_fresh", "_unsafe_view", "promote_types", "result_type", "_local_scalar_dense", "set_", "resize_",
              "is_nonzero", "sym_size", "sym_stride", "sym_numel", "sym_storage_offset", "dim", "size", "stride"}


@dataclass
class LaunchCount:
    torch_ops: collections.Counter = field(default_factory=collections.Counter)  # name -> launches
    triton: collections.Counter = field(default_factory=collections.Counter)  # kernel name -> launches

    @property
    def kernels(self) -> int:
        """All launches: PyTorch operations that run a kernel and Triton kernels."""
        return sum(self.torch_ops.values()) + sum(self.triton.values())

    def summary(self) -> str:
        return f"{self.kernels} ({sum(self.triton.values())} Triton)"


class _Counter(TorchDispatchMode):
    def __init__(self, counts: LaunchCount, inside_triton: list[bool]):
        super().__init__()
        self.counts, self.inside_triton = counts, inside_triton

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        name = func.overloadpacket.__name__
        if not self.inside_triton[0] and not func.is_view and name not in _NO_KERNEL:
            self.counts.torch_ops[name] += 1
        return func(*args, **(kwargs or {}))


@contextlib.contextmanager
def _triton_launches(counts: LaunchCount, inside: list[bool]):
    """Count ``kernel[grid](...)`` launches while inside (Triton's ``KernelInterface``: compiled and interpreted)."""
    try:
        from triton.runtime.jit import KernelInterface
    except ImportError:
        yield
        return
    original = KernelInterface.__getitem__

    def getitem(self, grid):
        launch = original(self, grid)

        def counted(*args, **kwargs):
            counts.triton[getattr(getattr(self, "fn", None), "__name__", type(self).__name__)] += 1
            inside[0] = True
            try:
                return launch(*args, **kwargs)
            finally:
                inside[0] = False
        return counted

    KernelInterface.__getitem__ = getitem
    try:
        yield
    finally:
        KernelInterface.__getitem__ = original


def count_launches(fn: Callable[[], object]) -> LaunchCount:
    """The launches of one call of ``fn`` (its result is dropped)."""
    counts, inside = LaunchCount(), [False]
    with _triton_launches(counts, inside), _Counter(counts, inside):
        fn()
    return counts


def count_render_launches(render: Callable[[], object]) -> tuple[LaunchCount, LaunchCount]:
    """The launches of one forward of ``render`` (a call returning a ``RenderOutput``) and of its backward (of
    ``rgb.sum() + depth.sum()``), after one uncounted call (first-call work: compilation, caches)."""
    render()
    outputs = []
    forward = count_launches(lambda: outputs.append(render()))
    backward = count_launches(lambda: (outputs[0].rgb.sum() + outputs[0].depth.sum()).backward())
    return forward, backward
