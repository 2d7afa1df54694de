"""The pieces of ``benchmarks/gpu_check.sh`` that run without a GPU: the gsplat comparison's own side
(gsplat itself needs CUDA) and the training-run verdict."""

import ast
import importlib.util
import json
from pathlib import Path

import pytest
import torch

from cylindersplat.benchmarks import gsplat_compare
from cylindersplat.benchmarks import train as bench_train
from cylindersplat.benchmarks.gsplat_compare import compare
from cylindersplat.render import triton_backend

ROOT = Path(__file__).resolve().parents[1]


def test_gsplat_comparison_times_our_side_and_says_why_gsplat_is_missing():
    rows = compare(200, 8, torch.device("cpu"), ["torch"], repeats=1)
    ours = [r for r in rows if r.get("renderer") == "cylindersplat-torch"]
    assert len(ours) == 1 and ours[0]["forward_ms"] > 0 and ours[0]["fwd_bwd_ms"] > 0
    assert any(r.get("renderer") == "gsplat" and "CUDA" in r["skipped"] for r in rows)


def test_gsplat_comparison_times_each_triton_variant_with_its_launches(capsys):
    """``--variants`` on pinhole views (issue 35: the lean forward and the compaction judged where most pairs are
    invisible): one row per variant, each variant's own launch counts, the defaults back afterwards."""
    gsplat_compare.main(["--num", "40", "--height", "8", "--device", "cpu", "--backend", "triton", "--repeats", "1",
                         "--launches", "--variants", "default", "default,nonzero"])
    rows = [ast.literal_eval(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    ours = {r["renderer"]: r for r in rows if "forward_ms" in r}
    assert set(ours) == {"cylindersplat-triton[default]", "cylindersplat-triton[default,nonzero]"}
    every_pair, compacted = ours.values()
    # The compaction's nonzero (and its gathers) are launches the default does not make.
    assert compacted["launches"]["forward"] > every_pair["launches"]["forward"]
    assert every_pair["launches"]["forward_triton"] == compacted["launches"]["forward_triton"]
    assert (triton_backend.FORWARD, triton_backend.COMPACTION) == ("default", "none")


def test_gsplat_comparison_profiles_one_forward_of_each_renderer(capsys):
    """``--profile``: a line of host and device totals per renderer, then its top operators (here the CPU's: the
    reference renders with PyTorch operations, whose names the table must show)."""
    gsplat_compare.main(["--num", "40", "--height", "8", "--device", "cpu", "--backend", "torch", "--repeats", "1",
                         "--profile"])
    out = capsys.readouterr().out.splitlines()
    head = [x for x in out if x.startswith("# profile, one forward: cylindersplat-torch, 40 Gaussians")]
    assert len(head) == 1 and "host " in head[0] and "device 0.00 ms in 0 kernels" in head[0], out
    top = out[out.index(head[0]) + 1:out.index(head[0]) + 11]
    assert len(top) == 10 and all(x.startswith("#   ") and " ms  x" in x for x in top), top
    assert any("aten::" in x for x in top)
    rows = [ast.literal_eval(x) for x in out if x.startswith("{")]
    assert all("profile" not in r for r in rows)  # the lines print as lines, not inside the rows


def test_gsplat_comparison_has_a_graph_row_that_says_why_it_is_missing_without_cuda(capsys):
    """``--graph``: one more row, the Triton backend replayed as CUDA graphs (``bench_render_variants`` checks the
    replayed renderer itself); without CUDA the row says why."""
    gsplat_compare.main(["--num", "40", "--height", "8", "--device", "cpu", "--backend", "triton", "--repeats", "1",
                         "--graph"])
    rows = [ast.literal_eval(x) for x in capsys.readouterr().out.splitlines() if x.startswith("{")]
    assert {"num": 40, "renderer": "cylindersplat-triton[graph]", "skipped": "CUDA graphs need CUDA"} in rows
    assert [r["renderer"] for r in rows if "forward_ms" in r] == ["cylindersplat-triton"]
    assert [x[0] for x in gsplat_compare._our_renderers(["torch", "triton"], [("lean",)], graph=True)] == [
        "cylindersplat-torch", "cylindersplat-triton[lean]", "cylindersplat-triton[graph]"]


def test_graph_rows_are_one_per_set_of_the_variants_options():
    # A graph captures the lean forward with every pair projected, whatever the variant's forward and compaction.
    from cylindersplat.benchmarks.variants import graph_variants

    assert graph_variants([]) == [("graph", None)]
    assert graph_variants([("default",), ("default", "rects", "id"), ("lean", "rects", "id"), ("default", "nonzero"),
                           ("default", "id")]) == [
        ("graph", ("lean",)), ("graph,rects,id", ("lean", "rects", "id")), ("graph,id", ("lean", "id"))]


def test_the_parity_verdict_needs_every_size_forward_and_backward():
    lines = gsplat_compare.parity_lines({
        "ours[a]": [(100_000, 0.95, 0.99), (1_300_000, 1.0, 0.7)],
        "ours[b]": [(100_000, 0.9, 0.8), (1_300_000, 1.2, 0.9)],  # one size slower forward
        "ours[c]": [(100_000, 0.9, 1.01)],  # slower forward + backward
    })
    assert lines[0] == ("# parity ours[a] (no slower than gsplat at 0.1 M/1.3 M, forward and fwd+bwd): MET; worst "
                        "forward 1.00x (1300000), worst fwd+bwd 0.99x (100000)")
    assert ": not met; worst forward 1.20x (1300000)" in lines[1] and ": not met;" in lines[2]
    assert gsplat_compare.parity_lines({}) == []


def test_the_comparison_table_puts_each_renderer_beside_gsplat_at_every_size():
    rows = [
        {"num": 100_000, "renderer": "ours[a]", "forward_ms": 1.5, "fwd_bwd_ms": 3.0},
        {"num": 100_000, "renderer": "gsplat", "forward_ms": 1.0, "fwd_bwd_ms": 4.0},
        {"num": 100_000, "renderer": "ours[graph]", "skipped": "CUDA graphs need CUDA"},
        {"num": 100_000, "agreement": "ours[a] vs gsplat", "mean_abs": 0.1, "psnr_db": 30.0},
        {"num": 1_300_000, "renderer": "ours[a]", "forward_ms": 2.0, "fwd_bwd_ms": 5.0},
        {"num": 1_300_000, "renderer": "gsplat", "error": "out of memory"},
    ]
    assert gsplat_compare.comparison_table(rows) == [
        "| renderer | 0.1 M: fwd / fwd+bwd ms (x gsplat) | 1.3 M: fwd / fwd+bwd ms (x gsplat) |",
        "|---|---|---|",
        "| ours[a] | 1.50 / 3.00 (1.50x / 0.75x) | 2.00 / 5.00 |",
        "| gsplat | 1.00 / 4.00 | out of memory |",
        "| ours[graph] | CUDA graphs need CUDA |  |",
    ]
    assert gsplat_compare.comparison_table([]) == []


@pytest.mark.parametrize("argv, message", [
    (["--variants", "lean", "--backend", "torch"], "--variants needs --backend triton"),
    (["--variants", "default,wrong"], "COMPACTION one of"),
    (["--num", "0"], "--num"),
    (["--backend", "cuda"], "invalid choice"),
    (["--graph", "--backend", "torch"], "--graph needs --backend triton"),
])
def test_gsplat_comparison_refuses_bad_arguments_in_one_line(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        gsplat_compare.main(["--device", "cpu", *argv])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def test_the_training_step_bench_times_every_stage_on_the_cpu(capsys):
    """``bench train`` (the ``train`` item): one row per curriculum stage, a positive time, the Gaussians drawn, and on
    the CPU the process's peak memory (it printed nan)."""
    bench_train.main(["--config", "tiny_paper", "--height", "16", "--steps", "1", "--warmup", "0", "--lpips", "off",
                      "--device", "cpu"])
    out = capsys.readouterr().out
    rows = [json.loads(x) for x in out.splitlines() if x.startswith("{")]
    assert [r["stage"] for r in rows] == [1, 2, 3]
    assert all(r["median_s"] > 0 and r["peak_mb"] > 0 and r["gaussians"] > 0 for r in rows), rows
    assert "nan" not in out and "(CPU memory: the process's peak resident memory" in out


@pytest.mark.parametrize("argv, message", [
    (["--config", "papr"], "invalid choice: 'papr' (choose from 'paper',"),
    (["--device", "tpu"], "not a torch device: 'tpu'"),
    (["--steps", "0"], "--steps"),
    (["--height", "-8"], "--height"),
])
def test_the_training_step_bench_refuses_bad_arguments_in_one_line(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        bench_train.main(argv)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and message in err and len(err.strip().splitlines()) == 1, err


def _summary_module():
    spec = importlib.util.spec_from_file_location("train_run_summary", ROOT / "benchmarks/train_run_summary.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _metrics(path, losses_per_stage):
    with open(path, "w") as f:
        step = 0
        for stage, losses in losses_per_stage.items():
            for loss in losses:
                step += 1
                f.write(json.dumps({"stage": stage, "step": step, "train/total": loss, "train/step_time": 0.1}) + "\n")
    return str(path)


def test_training_run_verdict(tmp_path, capsys):
    summary = _summary_module()
    falling = _metrics(tmp_path / "a.jsonl", {1: [1.0, 0.9, 0.8, 0.7, 0.6, 0.5, 0.45, 0.4], 3: [0.5, 0.5]})
    assert summary.main(falling, require_fall=True) == 0
    assert "loss falls (stage 1: fell; stage 3: too short to tell)" in capsys.readouterr().out
    rising = _metrics(tmp_path / "b.jsonl", {1: [0.4, 0.45, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0]})
    assert summary.main(rising, require_fall=True) == 1
    assert summary.main(rising) == 0  # without --require-fall the verdict is only printed
    assert "NOT converging" in capsys.readouterr().out


def test_training_run_verdict_is_not_decided_by_one_hard_batch(tmp_path, capsys):
    """A single batch of a hard scene at the end (as the GPU run of 2026-11-26 logged: its depth term jumps
    from 0.05 to 0.9 with the scene drawn) must not turn a falling run into "NOT converging": medians of the
    first and last quarter, not the last value."""
    summary = _summary_module()
    noisy = [0.05, 0.04, 0.06, 0.05, 0.04, 0.045, 0.035, 0.03, 0.04, 0.03, 0.028, 0.12]
    path = _metrics(tmp_path / "c.jsonl", {1: noisy})
    assert summary.main(path, require_fall=True) == 0
    assert "stage 1: fell" in capsys.readouterr().out


def test_bench_render_reports_a_reference_out_of_memory_instead_of_crashing(monkeypatch, capsys):
    """The reference running out of memory (as at 1.3 M Gaussians on an 80 GB GPU) is a row and a table cell, and
    the other backend is still timed."""
    from cylindersplat.benchmarks import render as bench_render

    real = bench_render.render

    def reference_out_of_memory(*args, backend="auto", **kwargs):
        if backend == "torch":
            raise torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 40.00 GiB")
        return real(*args, backend=backend, **kwargs)

    monkeypatch.setattr(bench_render, "render", reference_out_of_memory)
    bench_render.main(["--num", "300", "--height", "8", "--device", "cpu", "--backend", "torch", "numba",
                       "--repeats", "1", "--default-malloc"])
    out = capsys.readouterr().out
    assert "# numba vs torch (300 Gaussians, 8x16, cpu): torch: out of memory - no ratio" in out
    assert "| cpu | torch | 300 | 8x16 | out of memory | out of memory |  |" in out
    numba_row = next(line for line in out.splitlines() if line.startswith("| cpu | numba | 300 |"))
    assert float(numba_row.split("|")[5]) > 0  # its forward was timed
    # the CPU's peak is the process's so far (it read the reference's ~1.9 GB as numba's): said under the table
    assert "# peak MB on the CPU: the process's peak resident memory up to that row" in out


def test_gpu_check_skips_what_would_start_past_its_total_budget(tmp_path):
    """One run of the check has a total budget (9 minutes by default): an item that would start after it is
    skipped and says so in the summary, instead of the run being cut off with no summary."""
    import os
    import subprocess

    env = {**os.environ, "CHECK_TOTAL_SECONDS": "5", "CHECK_WORK": str(tmp_path / "work"),
           "CHECK_WHEELS": str(tmp_path)}
    out = tmp_path / "check"
    proc = subprocess.run(["bash", str(ROOT / "benchmarks/gpu_check.sh"), "--smoke", str(out), "render model"],
                          env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    summary = (out / "summary.md").read_text()
    assert "## render — skipped: the 5-second budget of this run is spent" in summary
    assert "## model — skipped: the 5-second budget of this run is spent" in summary


def test_the_scene_line_counts_the_visible_gaussians_and_their_tile_pairs():
    from cylindersplat.render import Pinhole, RasterSettings
    from cylindersplat.render.rasterize import bin_to_tiles
    from cylindersplat.scenes import random_indoor

    line = gsplat_compare.scene_line(3000, 16, torch.device("cpu"), tile_size=8)
    g = random_indoor(3000)
    k, h, w = gsplat_compare._camera(16, "cpu")
    proj = Pinhole(k, h, w).project(g, torch.eye(4)[None], RasterSettings())
    pairs = len(bin_to_tiles(proj, 8).gaussian)  # the reference binning's own pairs
    assert 0 < len(proj.depth) < 3000 and pairs > 0
    assert line == (f"# scene: {len(proj.depth):,} of 3,000 Gaussians visible, {pairs:,} (Gaussian, tile) pairs "
                    "(8 px tiles)")
