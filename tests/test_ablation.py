"""The ablation study harness: variants, schedule bookkeeping, resumable runs, tables."""

import json

import pytest

from cylindersplat.cli import main
from cylindersplat.data.synth import SequenceConfig, write_synthetic_dataset
from cylindersplat.experiments.ablation import Schedule, Variant, all_variants, default_variants, run_study, study_table


def test_every_variant_gets_the_same_number_of_steps():
    schedule = Schedule(30, 20, 10)
    for variant in all_variants():
        stages, steps = variant.stages(schedule)
        assert sum(steps) == schedule.total, variant.name
        assert stages == {"full": (1, 2, 3), "pixel": (1,), "volume": (1, 2)}[variant.kind]


def test_the_default_study_has_the_issue_rows_and_every_named_variant_is_a_valid_config():
    from cylindersplat.experiments.ablation import _check_variants

    names = [v.name for v in default_variants()]
    assert {"full", "pixel_only", "volume_only_cylindrical", "volume_only_spherical", "volume_only_cartesian",
            "wo_rgb_retrieval", "central_triplane", "cartesian_scale", "full_res_query", "isolated_init",
            "full_paper_recipe"} <= set(names)
    _check_variants(all_variants())  # raises on an unknown key or an invalid value


@pytest.mark.slow
def test_study_trains_scores_resumes_and_tabulates(tmp_path):
    data = tmp_path / "data"
    write_synthetic_dataset(data, 3, (32, 64), SequenceConfig(frames=3, spacing=(0.5, 1.0)), seed=2, progress=False)
    variants = [Variant("full", "both branches"), Variant("pixel_only", "pixel", kind="pixel")]
    lines = []
    report = run_study(data, tmp_path / "study", variants, seeds=(0, 1), schedule=Schedule(3, 2, 2), held_out=1,
                       resolution=(32, 64), log=lines.append)
    assert len(lines) == 4
    saved = json.loads((tmp_path / "study" / "ablation.json").read_text())
    fill_rows = {"pixel_only + mean fill", "pixel_only + inpaint fill", "forward_warp", "forward_warp + mean fill",
                 "forward_warp + inpaint fill"}
    assert set(saved["variants"]) == {"full", "pixel_only"} | fill_rows
    # A fill row is the same weights with a fill behind: its image scores differ, its depth scores do not.
    plain, filled = (saved["variants"][k]["metrics"] for k in ("pixel_only", "pixel_only + mean fill"))
    assert filled["abs_rel"]["seeds"] == plain["abs_rel"]["seeds"] and filled["ws_psnr"]["seeds"] != plain["ws_psnr"]["seeds"]
    assert len(saved["variants"]["forward_warp"]["metrics"]["ws_psnr"]["seeds"]) == 1
    ws = saved["variants"]["full"]["metrics"]["ws_psnr"]
    assert len(ws["seeds"]) == 2 and ws["mean"] == pytest.approx(sum(ws["seeds"]) / 2)
    assert ws["spread"] == pytest.approx(abs(ws["seeds"][0] - ws["seeds"][1]) / 2)
    # pixel-only outputs one Gaussian per pixel of the two inputs; full adds the volume branch's
    full, pixel = (saved["variants"][k]["metrics"]["gaussians_total"]["mean"] for k in ("full", "pixel_only"))
    assert pixel == 2 * 32 * 64 and full > pixel
    table = (tmp_path / "study" / "ablation.md").read_text()
    assert "| full |" in table and "| pixel_only |" in table and "WS-PSNR" in table
    assert "| pixel_only + mean fill |" in table and "| forward_warp + inpaint fill |" in table
    assert "Background where a render covers no pixel: black, except the fill rows (+ mean fill: the inputs' mean colour" in table
    # A second call scores the finished runs without training them again.
    again = run_study(data, tmp_path / "study", variants, seeds=(0, 1), schedule=Schedule(3, 2, 2), held_out=1,
                      resolution=(32, 64), log=lambda *_: None)
    assert again["variants"]["full"]["metrics"]["train_s"] == report["variants"]["full"]["metrics"]["train_s"]
    assert study_table(again) == study_table(again)


def test_bad_variants_fail_before_training(tmp_path, capsys):
    data = tmp_path / "data"
    write_synthetic_dataset(data, 2, (32, 64), SequenceConfig(frames=3), seed=3, progress=False)
    with pytest.raises(ValueError, match="not available"):
        run_study(data, tmp_path / "s", [Variant("broken", "x", ("model.volume.nope=1",))], seeds=(0,), held_out=1,
                  resolution=(32, 64))
    assert main(["ablate", "--data", str(data), "--variants", "nonsense"]) == 1
    assert "unknown variant" in capsys.readouterr().err


def test_a_variant_is_scored_with_the_depth_prior_it_trains_with(tmp_path, monkeypatch):
    from cylindersplat.data import datasets

    data = tmp_path / "data"
    write_synthetic_dataset(data, 2, (32, 64), SequenceConfig(frames=3), seed=3, progress=False)
    priors, make_dataset = [], datasets.make_dataset
    monkeypatch.setattr(datasets, "make_dataset", lambda *a, **k: priors.append(k.get("depth_prior")) or make_dataset(*a, **k))
    variant = Variant("gt_prior", "pixel branch on ground-truth depth", ("data.depth_prior=gt",), kind="pixel")
    assert variant.depth_prior == "gt" and Variant("x", "y").depth_prior == "default"
    run_study(data, tmp_path / "s", [variant], seeds=(0,), schedule=Schedule(2, 0, 0), held_out=1, resolution=(32, 64),
              log=lambda *_: None)
    assert priors[-2:] == ["gt", "default"]  # the variant scored with its prior; the forward-warp rows with the study's
    assert json.loads((tmp_path / "s" / "runs" / "gt_prior" / "seed0" / "study_run.json").read_text())["overrides"] == [
        "data.depth_prior=gt"]
    # --depth-prior: every variant's prior (trained and scored), recorded in the report and the table's caption
    plain = Variant("pixel", "pixel branch", kind="pixel")
    report = run_study(data, tmp_path / "t", [plain], seeds=(0,), schedule=Schedule(2, 0, 0), held_out=1,
                       resolution=(32, 64), log=lambda *_: None, depth_prior="simulated:blur_sigma=0")
    assert priors[-1] == "simulated:blur_sigma=0" and report["depth_prior"] == "simulated:blur_sigma=0"
    assert "input depth prior simulated:blur_sigma=0" in study_table(report)
    # a finished run trained with other settings is not reused as if it were this one
    with pytest.raises(ValueError, match="other settings"):
        run_study(data, tmp_path / "t", [plain], seeds=(0,), schedule=Schedule(2, 0, 0), held_out=1,
                  resolution=(32, 64), log=lambda *_: None)
    with pytest.raises(ValueError, match="unknown depth prior"):
        run_study(data, tmp_path / "u", [plain], seeds=(0,), held_out=1, depth_prior="sharp")


def test_study_reruns_are_bit_identical_at_a_fixed_thread_count(tmp_path):
    """The thread count is part of the recipe (it orders float sums): two runs with the same one give the same bytes."""
    import hashlib

    import torch

    data = tmp_path / "data"
    write_synthetic_dataset(data, 2, (32, 64), SequenceConfig(frames=3), seed=4, progress=False)
    before = torch.get_num_threads()
    digests, reports = [], []
    for name in ("a", "b"):
        reports.append(run_study(data, tmp_path / name, [Variant("full", "both branches")], seeds=(0,),
                                 schedule=Schedule(2, 1, 1), held_out=1, resolution=(32, 64), log=lambda *_: None,
                                 fills=(), threads=1))
        weights = tmp_path / name / "runs" / "full" / "seed0" / "model.safetensors"
        digests.append(hashlib.sha256(weights.read_bytes()).hexdigest())
        assert json.loads((weights.parent / "study_run.json").read_text())["threads"] == 1
    assert digests[0] == digests[1]
    assert reports[0]["threads"] == 1 and torch.get_num_threads() == before  # restored afterwards
    ws = [r["variants"]["full"]["metrics"]["ws_psnr"]["seeds"] for r in reports]
    assert ws[0] == ws[1]
    with pytest.raises(ValueError, match="threads must be an integer >= 1"):
        run_study(data, tmp_path / "c", [Variant("full", "x")], seeds=(0,), held_out=1, threads=0)
