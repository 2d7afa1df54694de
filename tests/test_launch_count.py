"""``count_launches`` (issue 35): the kernels a function launches, counted on any device - the PyTorch operations that
run a kernel (not views, not uninitialised allocations) and Triton kernel launches (not the interpreter's own
tensor copies)."""

import pytest
import torch

from cylindersplat.benchmarks.launches import count_launches


def test_operations_that_run_a_kernel_count_and_views_and_allocations_do_not():
    x = torch.arange(12.0)

    def work():
        y = x.view(3, 4).t()[1:]  # views: nothing launched
        z = torch.empty(5)  # uninitialised: nothing launched
        z.fill_(1.0)  # one
        return (y + 1).sum() + z.sum()  # add, sum, sum, add: four

    counts = count_launches(work)
    assert counts.kernels == 5 and dict(counts.torch_ops) == {"fill_": 1, "add": 2, "sum": 2}
    assert counts.summary() == "5 (0 Triton)"


def test_triton_launches_count_once_each_and_their_interpreter_copies_do_not():
    triton = pytest.importorskip("triton")
    import triton.language as tl

    @triton.jit
    def double_kernel(x_ptr, n, BLOCK: tl.constexpr):
        at = tl.program_id(0) * BLOCK + tl.arange(0, BLOCK)
        tl.store(x_ptr + at, tl.load(x_ptr + at, mask=at < n) * 2, mask=at < n)

    device = "cuda" if torch.cuda.is_available() else "cpu"
    x = torch.ones(100, device=device)
    counts = count_launches(lambda: [double_kernel[(4,)](x, 100, BLOCK=32) for _ in range(3)])
    assert dict(counts.triton) == {"double_kernel": 3} and counts.kernels == 3  # no copies counted
    assert torch.equal(x, torch.full((100,), 8.0, device=device))
