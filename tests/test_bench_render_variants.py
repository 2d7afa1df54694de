"""``bench render --variants``: the Triton forward, compaction and input-check variants it times side by side
(issue 35)."""

import argparse
import ast

import pytest

from cylindersplat.benchmarks import render as bench_render
from cylindersplat.render import triton_backend


def test_variant_names_are_checked_against_the_backends_lists():
    assert bench_render.triton_variant_name("lean") == ("lean",)
    assert bench_render.triton_variant_name("default,nonzero") == ("default", "nonzero")
    assert bench_render.triton_variant_name("default,none,torch") == ("default", "none", "torch")
    # Trailing defaults are left out: every spelling of one variant has one name (its row's).
    assert bench_render.triton_variant_name("lean,none,fused") == ("lean",)
    for bad, field in (("thin", "FORWARD one of default, lean"), ("", "FORWARD one of"),
                       ("default,all", "COMPACTION one of none, nonzero"), ("lean,none,numpy", "CHECK one of fused"),
                       ("lean,none,fused,x", "is not FORWARD[,COMPACTION[,CHECK]]"),
                       ("fused,joined", "FORWARD one of")):  # the old BINNING,BACKWARD form
        with pytest.raises(argparse.ArgumentTypeError, match=field.replace("[", r"\[")):
            bench_render.triton_variant_name(bad)


def test_a_variant_holds_inside_and_the_defaults_come_back_even_after_an_error():
    before = triton_backend.FORWARD, triton_backend.COMPACTION, triton_backend.CHECK
    with pytest.raises(RuntimeError):
        with bench_render.triton_variant("lean", "nonzero", "torch"):
            assert (triton_backend.FORWARD, triton_backend.COMPACTION, triton_backend.CHECK) == ("lean", "nonzero",
                                                                                                "torch")
            raise RuntimeError("a failing row")
    assert (triton_backend.FORWARD, triton_backend.COMPACTION, triton_backend.CHECK) == before
    with bench_render.triton_variant(None, "nonzero"):
        assert (triton_backend.FORWARD, triton_backend.COMPACTION) == (before[0], "nonzero")
    assert (triton_backend.FORWARD, triton_backend.COMPACTION, triton_backend.CHECK) == before


def test_the_lean_variant_is_timed_beside_the_default_with_its_agreement(capsys):
    bench_render.main(["--num", "30", "--height", "8", "--device", "cpu", "--backend", "triton", "--repeats", "1",
                       "--stages", "--variants", "default", "lean"])
    out = capsys.readouterr().out
    assert "'backend': 'triton[lean]'" in out and "'num_pairs'" in out
    line = next(x for x in out.splitlines() if x.startswith("# agreement triton[lean] vs triton[default]"))
    assert "rgb max |diff| 0.00e+00" in line, line


def test_the_input_checks_variant_and_launches_are_counted(capsys):
    bench_render.main(["--num", "30", "--height", "8", "--device", "cpu", "--backend", "triton", "--repeats", "1",
                       "--launches", "--variants", "default", "default,none,torch"])
    rows = [ast.literal_eval(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]  # printed rows
    fused, torch_checks = (row["launches"] for row in rows)
    assert fused["forward_triton"] == torch_checks["forward_triton"] + 1  # the checks kernel
    assert torch_checks["forward"] - fused["forward"] >= 60 and fused["backward"] == torch_checks["backward"]
    assert triton_backend.CHECK == "fused"  # the default is back


def test_bad_variants_stop_the_command_in_one_line(capsys):
    with pytest.raises(SystemExit) as exit_info:
        bench_render.main(["--device", "cpu", "--backend", "triton", "--variants", "default", "fused,sums"])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and "FORWARD one of default, lean" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("argv, message", [(["--device", "tpu"], "not a torch device: 'tpu'"),
                                           (["--backend", "nope"], "invalid choice: 'nope'")])
def test_a_bad_device_or_backend_is_one_line(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        bench_render.main(argv)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_stages_time_the_numba_backends_own_stages():
    """``--stages`` with the numba backend times its own projection, binning and compositing, not the reference's
    (which it did until session 19): no fragment stage, and the reference's pair count."""
    import torch

    from cylindersplat.render.numba_backend import numba_available
    from cylindersplat.scenes import random_indoor

    if not numba_available():
        pytest.skip("numba is not installed")
    g = random_indoor(300)
    for t in g.tensors().values():
        t.requires_grad_()
    c2w = torch.eye(4)
    stages = {b: bench_render.stage_breakdown(g, c2w, 8, 16, torch.device("cpu"), 1, b) for b in ("numba", "torch")}
    assert list(stages["numba"]) == ["checks", "project", "bin", "composite", "backward", "num_pairs"]
    assert "fragments" in stages["torch"] and stages["numba"]["num_pairs"] == stages["torch"]["num_pairs"] > 0
    assert bench_render._stage_kind("auto", torch.device("cpu")) == "numba"
    assert bench_render._stage_kind("auto", torch.device("cuda")) == "triton"
