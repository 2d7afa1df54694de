"""``bench render --variants``: the Triton binning and backward variants it times side by side (issue 35)."""

import argparse
import ast

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


def test_a_third_field_picks_the_forward_and_default_is_the_pair():
    assert bench_render.triton_variant_name("fused,joined,lean") == ("fused", "joined", "lean")
    assert bench_render.triton_variant_name("fused,joined,default") == ("fused", "joined")
    with pytest.raises(argparse.ArgumentTypeError, match="FORWARD one of default, lean"):
        bench_render.triton_variant_name("fused,joined,thin")
    before = triton_backend.FORWARD
    with bench_render.triton_variant("fused", "joined", "lean"):
        assert triton_backend.FORWARD == "lean"
    assert triton_backend.FORWARD == before


def test_the_lean_variant_is_timed_beside_the_default_with_its_agreement(capsys):
    bench_render.main(["--num", "30", "--height", "8", "--device", "cpu", "--backend", "triton", "--repeats", "1",
                       "--stages", "--variants", "fused,joined", "fused,joined,lean"])
    out = capsys.readouterr().out
    assert "'backend': 'triton[fused,joined,lean]'" in out and "'num_pairs'" in out
    line = next(x for x in out.splitlines() if x.startswith("# agreement triton[fused,joined,lean] vs"))
    assert "rgb max |diff| 0.00e+00" in line, line


def test_a_fifth_field_picks_the_input_checks_and_launches_are_counted(capsys):
    assert bench_render.triton_variant_name("fused,joined,default,none,torch") == ("fused", "joined", "default",
                                                                                  "none", "torch")
    assert bench_render.triton_variant_name("fused,joined,default,none,fused") == ("fused", "joined")
    with pytest.raises(argparse.ArgumentTypeError, match="CHECK one of fused, torch"):
        bench_render.triton_variant_name("fused,joined,default,none,numpy")
    bench_render.main(["--num", "30", "--height", "8", "--device", "cpu", "--backend", "triton", "--repeats", "1",
                       "--launches", "--variants", "fused,joined", "fused,joined,default,none,torch"])
    rows = [ast.literal_eval(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]  # printed rows
    fused, torch_checks = (row["launches"] for row in rows)
    assert fused["forward_triton"] == torch_checks["forward_triton"] + 1  # the checks kernel
    assert torch_checks["forward"] - fused["forward"] >= 60 and fused["backward"] == torch_checks["backward"]
    assert triton_backend.CHECK == "fused"  # the default is back
