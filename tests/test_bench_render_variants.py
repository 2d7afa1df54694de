"""``bench render --variants``: the Triton binning and backward variants it times side by side (issue 35)."""

import argparse

import pytest

from cylindersplat.benchmarks import render as bench_render
from cylindersplat.render import triton_backend, triton_binning


def test_variant_names_are_checked_against_the_backends_lists():
    assert bench_render.triton_variant_name("fused,chunked8") == ("fused", "chunked8")
    for bad in ("fused", "fused,", "radix,sums", "key64,warp", "key64,sums,x"):
        with pytest.raises(argparse.ArgumentTypeError, match="BINNING one of key64, depth_tile, fused"):
            bench_render.triton_variant_name(bad)


def test_a_variant_holds_inside_and_the_defaults_come_back_even_after_an_error():
    before = triton_binning.BINNING, triton_backend.BACKWARD
    with pytest.raises(RuntimeError):
        with bench_render.triton_variant("depth_tile", "joined"):
            assert (triton_binning.BINNING, triton_backend.BACKWARD) == ("depth_tile", "joined")
            raise RuntimeError("a failing row")
    assert (triton_binning.BINNING, triton_backend.BACKWARD) == before
    with bench_render.triton_variant(None, "chunked4"):
        assert (triton_binning.BINNING, triton_backend.BACKWARD) == (before[0], "chunked4")
    assert (triton_binning.BINNING, triton_backend.BACKWARD) == before
