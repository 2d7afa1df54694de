"""Evaluation: per-view scores equal direct metric calls, tables are shaped like the paper's, the CLI runs."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from PIL import Image

from cylindersplat.cli import main
from cylindersplat.data import SyntheticDataset
from cylindersplat.evaluation import evaluate, forward_warp_method, model_method, results_to_markdown
from cylindersplat.evaluation.evaluate import comparison_image, normalized_depth
from cylindersplat.metrics import DepthRange, abs_rel, delta1, pcc, psnr, rmse, ssim, ws_psnr
from cylindersplat.model import save_model
from cylindersplat.utils.picture_grid import LABEL_HEIGHT


@pytest.mark.slow  # 40 s at load 9 (2 shared cores)
def test_eval_cli_loc360_context_views_and_gaps(tiny_model, tmp_path, capsys):
    """`eval --format loc360 --views 2,3 --gap 2`: one table per view count, the chosen frames scored (no GT depth)."""
    from test_data_loaders import write_loc360

    write_loc360(tmp_path / "loc", frames=9, size=(16, 32))
    checkpoint = tmp_path / "model.safetensors"
    save_model(tiny_model, checkpoint)
    out = tmp_path / "eval"
    assert main(["eval", "--format", "loc360", "--data", str(tmp_path / "loc"), "--protocols", "all_between",
                 "--views", "2,3", "--gap", "2", "--depth-prior", "constant:2", "--checkpoint", str(checkpoint),
                 "--max-examples", "2", "--pictures", "1", "--lpips", "off", "--device", "cpu", "--fills", "none",
                 "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "0.94 m between neighbouring contexts, 1.88 m first to last" in printed  # 3 views, frames 0.47 m apart
    data = json.loads((out / "results.json").read_text(), parse_constant=_refuse)  # strict JSON: no Infinity/NaN
    assert data["settings"] == {
        "all_between_2views_gap2": {"protocol": "all_between", "context_views": 2, "gap": 2,
                                    "context_layout": "spaced"},
        "all_between_3views_gap2": {"protocol": "all_between", "context_views": 3, "gap": 2,
                                    "context_layout": "spaced"}}
    # 9 frames, 100 starts: 2 views span 2 -> first starts 0, 0; 3 views span 4 -> 0, 0: targets 0..2 and 0..4
    rows = data["views"]["all_between_3views_gap2"]
    assert len(rows) == 2 * 5 * 2 and {r["view"] for r in rows} == set(range(5))  # examples x targets x methods
    assert len(data["views"]["all_between_2views_gap2"]) == 2 * 3 * 2
    means = data["means"]["loc — all_between, 3 views, gap 2 (2 examples)"]
    assert set(means) == {"CylinderSplat", "Forward warp"} and means["Forward warp"]["abs_rel"] is None
    assert 0 < means["Forward warp"]["ssim"] <= 1
    # the warp reproduces its own input views exactly (infinite PSNR, null in the file): the means use the other
    # views, and say so
    exact = [r for r in rows if r["method"] == "Forward warp" and r["ws_psnr"] is None]
    assert len(exact) == 2 * 3 and all(r["psnr"] is None and r["ssim"] == pytest.approx(1.0) for r in exact)
    assert means["Forward warp"]["ws_psnr"] < 100
    others = [r["ws_psnr"] for r in rows if r["method"] == "Forward warp" and r["ws_psnr"] is not None]
    assert means["Forward warp"]["ws_psnr"] == pytest.approx(np.mean(others))
    assert "Forward warp: 6 of 10 target views rendered exactly (infinite ws_psnr, psnr" in printed
    assert "Forward warp: 6 of 10 target views rendered exactly" in (out / "results.md").read_text()
    assert len(list((out / "examples" / "all_between_3views_gap2").glob("*.png"))) == 1
    # released layout, 4 views: contexts (s, s+1, s+3, s+4), targets s+1..s+3
    assert main(["eval", "--format", "loc360", "--data", str(tmp_path / "loc"), "--views", "4", "--gap", "2",
                 "--views-layout", "released", "--protocols", "all_between", "--depth-prior", "constant:2",
                 "--no-model",
                 "--fills", "none", "--max-examples", "1", "--pictures", "0", "--lpips", "off", "--out",
                 str(tmp_path / "e4")]) == 0
    data = json.loads((tmp_path / "e4" / "results.json").read_text())
    assert [r["view"] for r in data["views"]["all_between_4views_gap2_released"]] == [0, 1, 2]
    # errors: one line, exit 1
    capsys.readouterr()
    assert main(["eval", "--format", "loc360", "--data", str(tmp_path / "loc"), "--protocols", "all_between",
                 "--views", "3", "--gap", "5", "--depth-prior", "constant:2", "--out", str(tmp_path / "e")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "span 10 frames, but the longest sequence has 9" in err[0]


def _refuse(constant):
    raise ValueError(f"non-standard JSON constant {constant}")


def test_result_files_are_strict_json():
    from cylindersplat.utils.jsonfile import json_text, strict_json

    value = {"a": [1.0, float("inf"), (float("nan"), -float("inf"))], "b": {"c": 2, "d": "x", "e": None}}
    assert strict_json(value) == {"a": [1.0, None, [None, None]], "b": {"c": 2, "d": "x", "e": None}}
    assert json.loads(json_text(value), parse_constant=_refuse) == strict_json(value)


def test_every_view_exact_gives_an_infinite_mean_and_says_so(synth_root):
    from cylindersplat.evaluation import Method
    from cylindersplat.render.api import RenderOutput

    def exact(sample):
        return RenderOutput(sample.target_images, sample.target_depths, torch.ones_like(sample.target_depths))

    dataset = SyntheticDataset(synth_root, views="one_view")
    result = evaluate(dataset, [Method("copy", exact)], depth_range=DepthRange(0.05, 1000.0), progress=False)
    assert result.means["copy"]["ws_psnr"] == float("inf") and result.means["copy"]["psnr"] == float("inf")
    assert result.means["copy"]["ssim"] == pytest.approx(1.0)
    views = result.means["copy"]["views"]
    assert any(f"copy: {views} of {views} target views rendered exactly" in n and "those means are infinite" in n
               for n in result.notes)


def test_eval_cli_views_need_loc360(tmp_path, capsys):
    (tmp_path / "meta.json").write_text("{}")  # read as a synthetic dataset
    assert main(["eval", "--data", str(tmp_path), "--views", "3", "--out", str(tmp_path / "e")]) == 1
    assert "--format loc360" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["eval", "--data", str(tmp_path), "--gap", "0"])
    assert "integers >= 1" in capsys.readouterr().err


@pytest.fixture(scope="module")
def synth_root(synth_dataset):  # conftest.py; the same data as test_eval_occluded.py
    return synth_dataset(2, seed=3)


def _seam_error(depth, ref, depth_range):
    """The released evaluation's ``continuity`` (paper: LRCE), written out: rows whose reference ends are valid."""
    rows = [i for i in range(ref.shape[0])
            if all(depth_range.near < float(ref[i, j]) < depth_range.far for j in (0, -1))]
    return np.mean([abs(float(depth[i, 0] - depth[i, -1]) - float(ref[i, 0] - ref[i, -1])) for i in rows])


def test_scores_equal_direct_metric_calls(synth_root, tiny_model, tmp_path):
    dataset = SyntheticDataset(synth_root, views="two_view")
    methods = [model_method(tiny_model, "tiny"), forward_warp_method()]
    depth_range = DepthRange(0.05, 1000.0)
    result = evaluate(dataset, methods, max_examples=2, example_dir=tmp_path, num_pictures=3,
                      depth_range=depth_range, progress=False)
    assert result.num_examples == 2
    assert set(result.means) == {"tiny", "Forward warp"}
    for method in methods:
        per_view = []
        for index in range(2):
            sample = dataset[index]
            out = method.run(sample)
            rgb, gt = out.rgb.clamp(0, 1), sample.target_images
            depth = normalized_depth(out.depth, out.alpha)
            ref = sample.target_depths
            for view in range(gt.shape[0]):
                per_view.append({
                    "ws_psnr": ws_psnr(rgb, gt)[view], "psnr": psnr(rgb, gt)[view], "ssim": ssim(rgb, gt)[view],
                    "lrce": _seam_error(depth[view], ref[view], depth_range),
                    "pcc": pcc(depth, ref, depth_range=depth_range)[view],
                    "abs_rel": abs_rel(depth, ref, depth_range=depth_range)[view],
                    "rmse": rmse(depth, ref, depth_range=depth_range)[view],
                    "delta1": delta1(depth, ref, depth_range=depth_range)[view],
                })
        means = result.means[method.name]
        for key in per_view[0]:
            expected = float(np.mean([float(v[key]) for v in per_view]))
            assert means[key] == pytest.approx(expected, rel=1e-5, abs=1e-6), (method.name, key)
        assert means["time_s"] > 0
        assert "lpips" not in means  # no LPIPS network given
    rows = [r for r in result.rows if r["method"] == "tiny"]
    assert len(rows) == 2  # two_view: one target per example
    pictures = sorted(tmp_path.glob("example_*.png"))
    assert len(pictures) == 2  # one target per example, fewer than the 3 asked for
    sheet = np.asarray(Image.open(pictures[0]))
    # titles; GT + 2 methods, captioned
    assert sheet.shape == (LABEL_HEIGHT + 3 * (4 + LABEL_HEIGHT + 32), 2 * 64 + 4, 3)


def test_known_values_of_an_oracle(synth_root):
    # A method that returns ground truth + 0.01 and depth x 1.1 has closed-form scores.
    from cylindersplat.evaluation import Method
    from cylindersplat.render.api import RenderOutput

    def run(sample):
        rgb = sample.target_images
        rgb = torch.where(rgb < 0.5, rgb + 0.01, rgb - 0.01)  # error exactly 0.01 everywhere
        depth = sample.target_depths * 1.1
        return RenderOutput(rgb, depth, torch.ones_like(depth))

    dataset = SyntheticDataset(synth_root, views="one_view")
    means = evaluate(dataset, [Method("oracle", run)], depth_range=DepthRange(0.05, 1000.0),
                     progress=False).means["oracle"]
    assert means["psnr"] == pytest.approx(40.0, abs=1e-3)
    assert means["ws_psnr"] == pytest.approx(40.0, abs=1e-3)
    assert means["abs_rel"] == pytest.approx(0.1, rel=1e-4)
    assert means["delta1"] == 1.0
    assert means["pcc"] == pytest.approx(1.0, abs=1e-5)


def test_comparison_image_rows_are_the_inputs():
    rgb = torch.rand(3, 8, 16)
    depth = torch.rand(8, 16) + 1
    sheet = comparison_image(rgb, depth, {"a": (rgb * 0, depth, torch.ones(8, 16))}, labels=False)
    np.testing.assert_array_equal(sheet[:8, :16], (rgb.permute(1, 2, 0).numpy() * 255 + 0.5).astype(np.uint8))
    np.testing.assert_array_equal(sheet[12:20, :16], 0)  # the method's black render
    np.testing.assert_array_equal(sheet[:8, 20:], sheet[12:20, 20:])  # same depth -> same colours


def test_markdown_table():
    results = {"synthetic — two_view": {
        "A": {"pcc": 0.9, "ws_psnr": 20.0, "ssim": 0.7, "lpips": None, "lrce": 0.01, "time_s": 1.0},
        "B": {"pcc": 0.8, "ws_psnr": 25.0, "ssim": 0.6, "lpips": None, "lrce": 0.02, "time_s": 0.1},
    }}
    text = results_to_markdown(results, title="T")
    lines = text.splitlines()
    header = next(line for line in lines if line.startswith("| Method"))
    assert header == "| Method | PCC ↑ | WS-PSNR ↑ | SSIM ↑ | LRCE ↓ | Time (s) ↓ |"
    row_a = next(line for line in lines if line.startswith("| A "))
    row_b = next(line for line in lines if line.startswith("| B "))
    assert row_a == "| A | **0.900** | 20.00 | **0.700** | **0.0100** | 1.00 |"
    assert row_b == "| B | 0.800 | **25.00** | 0.600 | 0.0200 | **0.10** |"
    assert "Not available here: PSNR, LPIPS, AbsRel, RMSE, δ1" in text


@pytest.mark.slow  # 41 s at load 9 (2 shared cores)
def test_eval_cli_writes_tables_and_pictures(synth_root, tiny_model, tmp_path, capsys):
    checkpoint = tmp_path / "model.safetensors"
    save_model(tiny_model, checkpoint)
    out = tmp_path / "eval"
    assert main(["eval", "--data", str(synth_root), "--checkpoint", str(checkpoint), "--out", str(out),
                 "--protocols", "two_view,one_view", "--pictures", "1", "--lpips", "off", "--fills", "none"]) == 0
    table = (out / "results.md").read_text()
    assert table.count("| CylinderSplat |") == 2 and table.count("| Forward warp |") == 2
    data = json.loads((out / "results.json").read_text())
    assert len(data["means"]) == 2
    one_view = next(v for k, v in data["means"].items() if "one_view" in k)
    assert set(one_view) == {"CylinderSplat", "Forward warp"}
    assert 0 < one_view["Forward warp"]["ssim"] <= 1
    assert len(data["views"]["one_view"]) == 2 * 2 * 2  # examples x outer targets x methods
    assert len(list((out / "examples" / "two_view").glob("*.png"))) == 1


def test_eval_cli_errors(synth_root, tmp_path, capsys):
    with pytest.raises(SystemExit):  # argparse: W != 2H
        main(["eval", "--data", str(synth_root), "--resolution", "32x32"])
    assert "W == 2H" in capsys.readouterr().err
    # User errors: exit code 1 and one line naming the problem.
    assert main(["eval", "--data", str(synth_root), "--checkpoint", str(tmp_path / "nope.safetensors"),
                 "--out", str(tmp_path / "e")]) == 1
    assert "nope.safetensors" in capsys.readouterr().err
    assert main(["eval", "--data", str(synth_root), "--no-baseline", "--no-model", "--out", str(tmp_path / "e")]) == 1
    assert "nothing to evaluate" in capsys.readouterr().err
    assert main(["eval", "--data", str(tmp_path / "missing"), "--out", str(tmp_path / "e")]) == 1
    assert "missing" in capsys.readouterr().err
