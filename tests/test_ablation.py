"""The study library (cylindersplat.study): variants as data, schedule bookkeeping, resumable runs, tables."""

import json

import pytest

from cylindersplat.cli import main
from cylindersplat.data.synth import SequenceConfig, write_synthetic_dataset
from cylindersplat.study import Schedule, Variant, all_variants, default_variants, run_study, study_table

# The catalogue's overrides as the Python tables wrote them before they became data (issue 36): a variant's
# overrides are recorded in every report and compared on resume, so their text must not change.
EARLIER_TINY = ("model.volume.color=retrieval", "loss.volume_loss=scaled", "loss.volume_weight=0",
                "model.fusion.pixel_clearing=none", "model.prior_alignment=none",
                "model.volume.grid=[4,16,8]", "model.volume.image_grid=[2,8,4]")
VOLUME_ONLY = ("model.fusion.strategy=concat", "train.stage2_render=volume")
OVERRIDES_BEFORE = {
    "full": (), "full_paper_recipe": VOLUME_ONLY, "pixel_only": (),
    "pixel_only_no_edge_fading": ("model.pixel.edge_sigma=0",),
    "volume_only_cylindrical": VOLUME_ONLY,
    "volume_only_spherical": VOLUME_ONLY + ("model.volume.coordinates=spherical",),
    "volume_only_cartesian": VOLUME_ONLY + ("model.volume.coordinates=cartesian",),
    "wo_rgb_retrieval": ("model.volume.color=decoded",), "central_triplane": ("model.volume.placement=central",),
    "cartesian_scale": ("model.volume.scale_transform=cartesian",),
    "full_res_query": ("model.volume.image_query=full",),
    "isolated_init": ("model.volume.init=isolated",), "no_edge_fading": ("model.pixel.edge_sigma=0",),
    "full_earlier_recipe": EARLIER_TINY,
    "full_priors_as_given_coarse_grid": ("model.prior_alignment=none", "model.volume.grid=[4,16,8]",
                                         "model.volume.image_grid=[2,8,4]"),
    "depth_fusion_own_view": ("model.fusion.strategy=depth_prune", "model.fusion.side=front"),
    "retrieval_window_2": EARLIER_TINY + ("model.volume.color=surface", "model.volume.surface_window=2",
                                          "model.volume.surface_temperature=1"),
    "volume_weight_1": EARLIER_TINY + ("loss.volume_weight=1",),
    "pixel_stage_leaves_hidden": ("loss.pixel_stage_hidden=leave",),
}
KINDS_BEFORE = {"pixel_only": "pixel", "pixel_only_no_edge_fading": "pixel", "volume_only_cylindrical": "volume",
                "volume_only_spherical": "volume", "volume_only_cartesian": "volume"}


def test_the_catalogue_data_gives_the_overrides_the_python_tables_gave():
    from cylindersplat.study import change_set, recipe

    assert {v.name: v.overrides for v in all_variants()} == OVERRIDES_BEFORE
    assert list(OVERRIDES_BEFORE)[:13] == [v.name for v in default_variants()]  # table order kept
    assert {v.name: v.kind for v in all_variants() if v.kind != "full"} == KINDS_BEFORE
    assert recipe("tiny_earlier") == EARLIER_TINY and change_set("volume_only") == VOLUME_ONLY
    assert change_set("fine_grid") == ("model.volume.grid=[8,32,16]", "model.volume.image_grid=[4,16,8]")
    with pytest.raises(ValueError, match="unknown recipe 'nope'"):
        change_set("nope")


def test_the_earlier_tiny_recipe_differs_from_the_tiny_preset_only_where_it_says():
    """``configs/recipes/tiny_earlier.yaml`` undoes what tiny.yaml's header says issue 23's recipe changed."""
    from cylindersplat.study import recipe
    from cylindersplat.training import load_config
    from cylindersplat.training.config import config_as_dict

    def flat(tree, prefix=""):
        out = {}
        for key, value in tree.items():
            out.update(flat(value, f"{prefix}{key}.") if isinstance(value, dict) else {f"{prefix}{key}": value})
        return out

    now = flat(config_as_dict(load_config("tiny")))
    earlier = flat(config_as_dict(load_config("tiny", recipe("tiny_earlier"))))
    changed = {k for k in now if now[k] != earlier[k]}
    assert changed == {o.split("=")[0] for o in EARLIER_TINY}
    # and it is a preset of its own: its base with its changes, the same config
    assert flat(config_as_dict(load_config("recipes/tiny_earlier"))) == earlier


def test_every_variant_gets_the_same_number_of_steps():
    schedule = Schedule(30, 20, 10)
    for variant in all_variants():
        stages, steps = variant.stages(schedule)
        assert sum(steps) == schedule.total, variant.name
        assert stages == {"full": (1, 2, 3), "pixel": (1,), "volume": (1, 2)}[variant.kind]


def test_the_default_study_has_the_issue_rows_and_every_named_variant_is_a_valid_config():
    from cylindersplat.study import check_variants

    names = [v.name for v in default_variants()]
    assert {"full", "pixel_only", "volume_only_cylindrical", "volume_only_spherical", "volume_only_cartesian",
            "wo_rgb_retrieval", "central_triplane", "cartesian_scale", "full_res_query", "isolated_init",
            "full_paper_recipe"} <= set(names)
    check_variants(all_variants())  # raises on an unknown key or an invalid value


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
    assert filled["abs_rel"]["seeds"] == plain["abs_rel"]["seeds"]
    assert filled["ws_psnr"]["seeds"] != plain["ws_psnr"]["seeds"]
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
    assert ("Background where a render covers no pixel: black, except the fill rows (+ mean "
            "fill: the inputs' mean colour") in table
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


@pytest.mark.slow
def test_a_variant_is_scored_with_the_depth_prior_it_trains_with(tmp_path, monkeypatch):
    from cylindersplat.data import datasets

    data = tmp_path / "data"
    write_synthetic_dataset(data, 2, (32, 64), SequenceConfig(frames=3), seed=3, progress=False)
    priors, make_dataset = [], datasets.make_dataset
    monkeypatch.setattr(datasets, "make_dataset", lambda *a, **k: priors.append(k.get("depth_prior"))
                        or make_dataset(*a, **k))
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


@pytest.mark.slow
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
