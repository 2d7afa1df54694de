"""``bench render --variants``: the Triton forward, compaction and input-check variants it times side by side
(issue 35)."""

import argparse
import ast

import pytest
import torch

from cylindersplat.benchmarks import render as bench_render
from cylindersplat.benchmarks import variants as bench_variants
from cylindersplat.benchmarks.views import view_camera
from cylindersplat.render import triton_backend


def test_variant_names_are_checked_against_the_backends_lists():
    assert bench_variants.triton_variant_name("lean") == ("lean",)
    assert bench_variants.triton_variant_name("default,nonzero") == ("default", "nonzero")
    assert bench_variants.triton_variant_name("default,none,torch") == ("default", "torch")
    # Options in any order, one name per variant (its row's): the forward, then the options that are not their
    # switch's default, in the switches' order.
    assert bench_variants.triton_variant_name("lean,none,fused") == ("lean",)
    assert bench_variants.triton_variant_name("lean,rects,nonzero") == ("lean", "nonzero", "rects")
    assert bench_variants.triton_variant_name("default,ids,row") == ("default",)
    assert bench_variants.triton_variant_name("lean,id,rects,nonzero") == ("lean", "nonzero", "rects", "id")
    for bad, message in (("thin", "'thin' is not a forward"), ("", "'' is not a forward"),
                         ("ids", "'ids' is not a forward"),
                         ("default,all", "'all' is not an option"), ("lean,none,numpy", "'numpy' is not an option"),
                         ("lean,ids,rects", "gives PAIR_FIELD twice (ids, rects)"),
                         ("fused,joined", "'fused' is not a forward")):  # the old BINNING,BACKWARD form
        with pytest.raises(argparse.ArgumentTypeError, match=message.replace("(", r"\(").replace(")", r"\)")) as e:
            bench_variants.triton_variant_name(bad)
        assert "FORWARD one of default, lean" in str(e.value) and "PAIR_FIELD one of ids, rects" in str(e.value)


def test_a_variant_holds_inside_and_the_defaults_come_back_even_after_an_error():
    def switches():
        return (triton_backend.FORWARD, triton_backend.COMPACTION, triton_backend.CHECK, triton_backend.PAIR_FIELD,
                triton_backend.LOOKAHEAD)

    before = switches()
    with pytest.raises(RuntimeError):
        with bench_variants.triton_variant("lean", "rects", "nonzero", "id", "torch"):
            assert switches() == ("lean", "nonzero", "torch", "rects", "id")
            raise RuntimeError("a failing row")
    assert switches() == before
    before = switches()[:3]
    with bench_variants.triton_variant(None, "nonzero"):
        assert (triton_backend.FORWARD, triton_backend.COMPACTION) == (before[0], "nonzero")
    assert (triton_backend.FORWARD, triton_backend.COMPACTION, triton_backend.CHECK) == before


def test_the_lean_variant_is_timed_beside_the_default_with_its_agreement(capsys):
    bench_render.main(["--num", "30", "--height", "8", "--device", "cpu", "--backend", "triton", "--repeats", "1",
                       "--stages", "--variants", "default", "lean"])
    out = capsys.readouterr().out
    assert "'backend': 'triton[lean]'" in out and "'num_pairs'" in out
    line = next(x for x in out.splitlines() if x.startswith("# agreement triton[lean] vs triton[default]"))
    assert "rgb max |diff| 0.00e+00" in line, line


def test_the_id_pairs_are_timed_by_stage_beside_the_rectangles_with_their_agreement(capsys):
    bench_render.main(["--num", "30", "--height", "8", "--device", "cpu", "--backend", "triton", "--repeats", "1",
                       "--stages", "--variants", "default", "default,rects", "lean,rects"])
    out = capsys.readouterr().out
    rows = {row["backend"]: row for row in (ast.literal_eval(x) for x in out.splitlines() if x.startswith("{"))}
    pairs = {name: row["stages_ms"]["num_pairs"] for name, row in rows.items()}
    assert pairs["triton[default,rects]"] == pairs["triton[lean,rects]"] == pairs["triton[default]"] > 0
    for name in ("default,rects", "lean,rects"):
        line = next(x for x in out.splitlines() if x.startswith(f"# agreement triton[{name}] vs triton[default]"))
        assert "rgb max |diff| 0.00e+00" in line and "means 0.0e+00" in line, line
    assert triton_backend.PAIR_FIELD == "ids"  # the default is back


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
                                           (["--backend", "nope"], "invalid choice: 'nope'"),
                                           (["--graph"], "--graph needs --backend triton"),
                                           (["--variants", "lean", "--backend", "torch", "numba"],
                                            "--variants needs --backend triton")])
def test_a_bad_device_backend_or_triton_only_flag_is_one_line(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        bench_render.main(argv)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_stages_time_the_numba_backends_own_stages():
    """``--stages`` with the numba backend times its own projection, binning and compositing, not the reference's
    (which it did until session 19): no fragment stage, and the reference's pair count."""
    from cylindersplat.render.numba_backend import numba_available
    from cylindersplat.scenes import random_indoor

    if not numba_available():
        pytest.skip("numba is not installed")
    g = random_indoor(300)
    for t in g.tensors().values():
        t.requires_grad_()
    c2w = torch.eye(4)
    camera = view_camera("equirect", 8)
    stages = {b: bench_render.stage_breakdown(g, c2w, camera, torch.device("cpu"), 1, b) for b in ("numba", "torch")}
    assert list(stages["numba"]) == ["checks", "project", "bin", "composite", "backward", "num_pairs"]
    assert "fragments" in stages["torch"] and stages["numba"]["num_pairs"] == stages["torch"]["num_pairs"] > 0
    assert bench_render._stage_kind("auto", torch.device("cpu")) == "numba"
    assert bench_render._stage_kind("auto", torch.device("cuda")) == "triton"


def test_the_pinhole_view_is_timed_by_stage_with_the_pairs_gsplat_compare_counts(capsys):
    from cylindersplat.benchmarks import gsplat_compare

    bench_render.main(["--num", "300", "--height", "16", "--device", "cpu", "--backend", "torch", "numba",
                       "--repeats", "1", "--stages", "--camera", "pinhole"])
    rows = [ast.literal_eval(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    assert [row["camera"] for row in rows] == ["pinhole", "pinhole"]
    pairs = {row["stages_ms"]["num_pairs"] for row in rows}
    line = gsplat_compare.scene_line(300, 16, torch.device("cpu"))  # the same view, the reference's count
    assert len(pairs) == 1 and f" {next(iter(pairs)):,} (Gaussian, tile) pairs" in line, (pairs, line)


def test_the_cubemap_route_is_a_panorama_only_option(capsys):
    with pytest.raises(SystemExit) as exit_info:
        bench_render.main(["--device", "cpu", "--camera", "pinhole", "--cubemap"])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and "--cubemap renders panoramas" in err and len(err.strip().splitlines()) == 1


def test_the_graph_row_replays_renders_with_and_without_gradients(monkeypatch):
    """``--graph`` (``variants.graphed_render``): a graph without gradients under ``torch.no_grad``, one with the
    backward otherwise, each made once; both give render()'s images and gradients (here replayed by the graphs'
    stand-in, ``graph_standin.py``: this machine may have no CUDA)."""
    from cylindersplat.render import graphs, render
    from cylindersplat.scenes import random_indoor
    from graph_standin import RerunGraphReplay

    monkeypatch.setitem(graphs._ENGINES, "cpu", RerunGraphReplay)
    g = random_indoor(60)
    params = [t.requires_grad_() for t in g.tensors().values()]
    c2w, camera = torch.eye(4), view_camera("pinhole", 8)
    replay = bench_variants.graphed_render(g, c2w, camera)
    with torch.no_grad():
        ref = render(g, c2w, camera, backend="triton")
        for _ in range(2):
            assert torch.equal(replay().rgb, ref.rgb)
    out = replay()
    out.rgb.sum().backward()
    grads = [p.grad for p in params]
    for p in params:
        p.grad = None
    render(g, c2w, camera, backend="triton").rgb.sum().backward()
    assert all(torch.equal(a, p.grad) for a, p in zip(grads, params)) and grads[0].abs().max() > 0
    assert sorted(replay.graphs) == [False, True]
    assert [graph.captures for graph in replay.graphs.values()] == [1, 1]


def test_a_graph_that_fails_to_capture_is_a_row_not_a_crash(monkeypatch, capsys):
    """The graph row is new on a device: a capture that fails there (e.g. a wait for the device inside it) fills its
    row's error cell and prints its traceback; the benchmark goes on."""
    from cylindersplat.render import graphs

    class FailingCapture:
        def __init__(self, *args):
            raise RuntimeError("operation not permitted when stream is capturing\n(more lines)")

    monkeypatch.setitem(graphs._ENGINES, "cpu", FailingCapture)
    row = bench_render.bench(30, 8, torch.device("cpu"), "triton", 1, False, False, graph=True)
    assert row["backend"] == "triton[graph]" and "forward_ms" not in row
    assert row["error"] == "graph failed: RuntimeError: operation not permitted when stream is capturing"
    assert "Traceback" in capsys.readouterr().err
    cell = "graph failed: RuntimeError: operation not permitted when stream is capturing"
    assert bench_render.table([row])[-1] == f"| cpu | triton[graph] | 30 | 8x16 | {cell} | {cell} |  |"
