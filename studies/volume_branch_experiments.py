"""The volume-branch experiments of benchmarks/RESULTS.md ("Volume branch"); one seed unless said.

    python studies/volume_branch_experiments.py OUT_DIR [--suite NAME]

``recipes`` (session 5, about 35 min on the 2-core CPU machine): fusion strategies and curricula.
``coverage`` (session 7, about 50 min): triplane bounds, the windowed colour retrieval, the auxiliary
volume loss, targets farther off the contexts' line, test-time fusion settings on a volume-only
checkpoint, and what each branch covers and paints on the occluded pixels.
``gt_prior`` (session 8, about 30 min): full, pixel-only and volume-only (cylindrical, spherical) with
ground-truth depth as the input prior, two seeds. ``sharp_prior`` (session 8, about 20 min): full and
pixel-only on the simulated prior with 0.5 px of edge blur instead of 1.5 px, two seeds.
``wide_holes`` (session 9, about 40 min): full, pixel-only (with and without edge fading) and volume-only on
targets 1.5-2.5 m off the line among 10 occluders (16 % occluded), two seeds, then ``ceilings`` (seconds):
the occluded-pixel WS-PSNR of fills of the *true* target (nearest visible pixel; true mean colours per target,
per hidden region, per region and depth band). ``fine_grids_at_scale`` (session 9, about 40 min, two runs side
by side): volume only and full with finer triplane grids on 200 scenes (session 8's data) for 3000 steps,
one seed. ``decoded_colour_at_scale`` (session 9, about 20 min): the same volume-only run with colours decoded
from the triplane instead of retrieved from the inputs.

Unless a suite says otherwise, every variant trains the tiny model for 600 steps (300 / 150 / 150 over the stages it
runs) on 20 procedural scenes of the occlusion profile at 64x128 and is scored on the same 8 held-out scenes, all
pixels and pixels no input view sees.
"""

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch
from colour_rule_oracle import nearest_visible, region_fill  # the fills of the true target, shared

from cylindersplat.data import SyntheticDataset
from cylindersplat.data.occlusion import occluded_mask
from cylindersplat.data.synth import profile_config, write_synthetic_dataset
from cylindersplat.evaluation import evaluate, model_method
from cylindersplat.evaluation.methods import reconstruct, render_views
from cylindersplat.metrics import DepthRange
from cylindersplat.metrics.image import ws_weights
from cylindersplat.model import load_model
from cylindersplat.study import Schedule, Variant, change_set, default_variants, pinned_to_earlier_tiny
from cylindersplat.study import run_study as _run_study


def run_study(data, out, variants, **options):
    """The ablation's study with every variant a switch on the tiny preset of sessions 5-9 (it has changed since)."""
    return _run_study(data, out, pinned_to_earlier_tiny(variants), **options)


VOLUME_ONLY = change_set("volume_only")
PAPER = VOLUME_ONLY  # the paper's recipe on the tiny model: concatenated Gaussians, volume-only stage 2
RECIPES = [
    Variant("pixel_only", "pixel branch only", PAPER, kind="pixel"),
    Variant("paper_recipe", "concat fusion, volume-only stage 2", PAPER),
    Variant("own_view_fusion", "depth_prune side=front",
            ("model.fusion.strategy=depth_prune", "model.fusion.side=front",
                                                          "train.stage2_render=volume")),
    Variant("hidden_fusion", "depth_prune side=hidden", ("train.stage2_render=volume",)),
    Variant("hidden_fusion_fused_stage2", "the tiny preset's recipe", ()),
    Variant("fine_grid_own_view_fusion", "grid 8x32x16",
            ("model.volume.grid=[8,32,16]", "model.volume.image_grid=[4,16,8]",
                                                          "model.fusion.strategy=depth_prune",
             "model.fusion.side=front",
                                                          "train.stage2_render=volume")),
    Variant("recipe_occluded_weight_4", "the recipe + loss.occluded_weight=4", ("loss.occluded_weight=4",)),
]
ROOM_BOUNDS = ("model.volume.radius=5", "model.volume.height=4")  # triplanes sized to the rooms (10 m: the paper's)
COVERAGE = [
    Variant("full", "the tiny preset", ()),
    Variant("full_room_bounds", "triplanes of radius 5 m, height 4 m", ROOM_BOUNDS),
    Variant("volume_only_room_bounds", "volume only, radius 5 m, height 4 m", VOLUME_ONLY + ROOM_BOUNDS, kind="volume"),
    Variant("volume_only_spherical_room_bounds", "volume only, spherical, radius 5 m",
            VOLUME_ONLY + ("model.volume.coordinates=spherical", "model.volume.radius=5"), kind="volume"),
    Variant("retrieval_window_2", "colour of the nearest observed surface points in 5x5 pixels",
            ("model.volume.color=surface", "model.volume.surface_window=2", "model.volume.surface_temperature=1")),
    Variant("volume_weight_1", "the volume branch's own render in the loss", ("loss.volume_weight=1",)),
    Variant("volume_weight_1_volume_stage2", "the same, stage 2 renders the volume branch alone",
            ("loss.volume_weight=1", "train.stage2_render=volume")),
]
# Ground-truth depth as the input prior (an oracle, sharp at occlusion boundaries), two questions:
# does the all-pixel coordinate ordering come from the prior's errors (the sphere's (theta, latitude) plane takes
# pixel features at their own direction whatever their depth; every cylindrical plane places them by depth), and
# how much of the occluded-pixel lead do the blurred prior's flying pixels cost?
GT_PRIOR = [
    Variant("full_gt_prior", "full, ground-truth depth as the input prior", ("data.depth_prior=gt",)),
    Variant("pixel_only_no_edge_fading_gt_prior", "pixel only, no edge fading, ground-truth input depth",
            ("model.pixel.edge_sigma=0", "data.depth_prior=gt"), kind="pixel"),
    Variant("pixel_only_gt_prior", "pixel only, ground-truth input depth", ("data.depth_prior=gt",), kind="pixel"),
    Variant("volume_only_cylindrical_gt_prior", "volume only, cylindrical, ground-truth depth as the input prior",
            VOLUME_ONLY + ("data.depth_prior=gt",), kind="volume"),
    Variant("volume_only_spherical_gt_prior", "volume only, spherical, ground-truth depth as the input prior",
            VOLUME_ONLY + ("model.volume.coordinates=spherical", "data.depth_prior=gt"), kind="volume"),
]
# The simulated prior with a third of its edge blur (0.5 px instead of 1.5 px at 64x128).
SHARP = ("data.depth_prior=simulated:blur_sigma=0.5",)
SHARP_PRIOR = [
    Variant("full_sharp_prior", "full, simulated prior blurred 0.5 px", SHARP),
    Variant("pixel_only_no_edge_fading_sharp_prior", "pixel only, no edge fading, simulated prior blurred 0.5 px",
            ("model.pixel.edge_sigma=0",) + SHARP, kind="pixel"),
    Variant("pixel_only_sharp_prior", "pixel only, simulated prior blurred 0.5 px", SHARP, kind="pixel"),
]
# test-time settings tried on the volume-only checkpoint: (label, mode, fusion changes)
HIDDEN = {"strategy": "depth_prune", "side": "hidden"}
TEST_TIME = [
    ("volume alone", "volume", {}),
    ("pixel alone", "pixel", {}),
    ("both, concat", "both", {}),
    ("both, hidden sigma 0.03", "both", dict(HIDDEN, sigma=0.03)),
    ("both, hidden sigma 0.1", "both", dict(HIDDEN, sigma=0.1)),
    ("both, hidden sigma 0.3", "both", dict(HIDDEN, sigma=0.3)),
    ("both, own view (front) sigma 0.1", "both", {"strategy": "depth_prune", "side": "front", "sigma": 0.1}),
]


def scores(model, dataset) -> str:
    m = evaluate(dataset, [model_method(model, "m")], depth_range=DepthRange(0.05, 1000), progress=False).means["m"]
    return f"{m['ws_psnr']:.2f} / {m.get('ws_psnr_occluded') or float('nan'):.2f}"


def branches(weights: Path, dataset) -> str:
    return "; ".join(f"{mode} {scores(load_model(weights).set_mode(mode), dataset)}"
                     for mode in ("pixel", "volume", "both"))


def test_time_fusion(weights: Path, dataset) -> list[str]:
    rows = []
    for label, mode, fusion in TEST_TIME:
        model = load_model(weights).set_mode(mode)
        model.config.fusion = replace(model.config.fusion, **fusion)
        rows.append(f"| {label} | {scores(model, dataset)} |")
    return rows


@torch.no_grad()
def branch_coverage(weights: Path, dataset) -> dict[str, float]:
    """On occluded pixels, per branch alone and fused: WS-PSNR, mean alpha, and the WS-PSNR of the colour
    it paints (rgb / alpha) where its alpha exceeds 0.3 - coverage and colour told apart."""
    model = load_model(weights)
    acc: dict[str, list[float]] = {}
    for sample in dataset:
        mask = occluded_mask(sample.target_depths[0], sample.target_poses[0], sample.context_gt_depths,
                             sample.context_poses)
        if not mask.any():
            continue
        h, w = sample.target_images.shape[-2:]
        weight = ws_weights(h)[:, None].expand(h, w) * mask
        truth = sample.target_images[0].double()
        for mode in ("pixel", "volume", "both"):
            out = render_views(reconstruct(model.set_mode(mode), sample), sample.target_poses, h, w, (0, 0, 0))
            rgb, alpha = out.rgb[0].double(), out.alpha[0].double()
            painted = weight * (alpha > 0.3)
            for key, image, wt in ((f"{mode} WS-PSNR", rgb, weight),
                                   (f"{mode} colour WS-PSNR", rgb / alpha.clamp_min(1e-3), painted)):
                if wt.sum() > 0:
                    mse = float((((image.clamp(0, 1) - truth) ** 2).mean(0) * wt).sum() / wt.sum())
                    acc.setdefault(key, []).append(-10 * np.log10(mse))
            acc.setdefault(f"{mode} alpha", []).append(float((alpha * weight).sum() / weight.sum()))
    return {k: float(np.mean(v)) for k, v in acc.items()}


def oracle_mean_fill(dataset, regions: str = "target") -> float:
    """WS-PSNR on occluded pixels of the *true* target with occluded pixels replaced by true mean colours: of
    all the target's occluded pixels (``regions="target"``), of each connected hidden region (``"component"``),
    or of each region split into 10 %-wide depth bands (``"component_depth"``, roughly one surface each).
    Oracles that know what colour hidden regions have on average but nothing of their texture."""
    values = []
    for sample in dataset:
        mask = occluded_mask(sample.target_depths[0], sample.target_poses[0], sample.context_gt_depths,
                             sample.context_poses)
        if not mask.any():
            continue
        truth = sample.target_images[0].double().numpy()
        fill = region_fill(truth, mask.numpy(), regions, sample.target_depths[0].numpy())
        values.append(_hidden_psnr(fill, truth, mask.numpy()))
    return float(np.mean(values))


def _hidden_psnr(fill: np.ndarray, truth: np.ndarray, hidden: np.ndarray) -> float:
    weight = ws_weights(truth.shape[1])[:, None].numpy() * hidden
    return float(-10 * np.log10((((fill - truth) ** 2).mean(0) * weight).sum() / weight.sum()))


@torch.no_grad()
def completion_figure(checkpoints: dict[str, Path], dataset, path: Path, examples: int = 4) -> None:
    """One row per held-out target: the truth, then each checkpoint's render. Pixels some input view sees are
    shown in dim grey, so what keeps its colour is what the model had to complete."""
    from cylindersplat.data.io import write_rgb

    models = {name: load_model(weights) for name, weights in checkpoints.items()}
    rows = []
    for index in range(min(examples, len(dataset))):
        sample = dataset[index]
        mask = occluded_mask(sample.target_depths[0], sample.target_poses[0], sample.context_gt_depths,
                             sample.context_poses)
        h, w = sample.target_images.shape[-2:]
        def highlight(tile):  # visible pixels: half-bright grey; occluded pixels: as rendered
            return torch.where(mask, tile, tile.mean(0, keepdim=True) * 0.5)

        tiles = [sample.target_images[0]] + [
            render_views(reconstruct(model, sample), sample.target_poses, h, w, (0, 0, 0)).rgb[0].clamp(0, 1)
            for model in models.values()]
        gap = torch.ones(3, h, 2)
        rows.append(torch.cat([torch.cat([highlight(tile), gap], dim=2) for tile in tiles], dim=2))
        rows.append(torch.ones(3, 2, rows[-1].shape[2]))
    image = torch.cat(rows[:-1], dim=1).repeat_interleave(2, 1).repeat_interleave(2, 2)
    write_rgb(path, image)
    print(f"wrote {path}: columns truth, {', '.join(models)}", flush=True)


def nearest_visible_fill(dataset) -> float:
    """WS-PSNR on occluded pixels of the *true* target with every occluded pixel replaced by its nearest
    visible one: what copying the surroundings (a 2D inpainting with perfect neighbours) would score."""
    values = []
    for sample in dataset:
        mask = occluded_mask(sample.target_depths[0], sample.target_poses[0], sample.context_gt_depths,
                             sample.context_poses)
        if not mask.any():
            continue
        truth = sample.target_images[0].double().numpy()
        values.append(_hidden_psnr(nearest_visible(truth, mask.numpy()), truth, mask.numpy()))
    return float(np.mean(values))


@torch.no_grad()
def latitude_bands(weights: Path, dataset) -> dict[str, float]:
    """WS-PSNR (all pixels) per latitude band: |lat| < 30, 30-60 and > 60 degrees."""
    model, acc = load_model(weights), {"|lat| < 30": [], "30-60": [], "> 60": []}
    for sample in dataset:
        h, w = sample.target_images.shape[-2:]
        out = render_views(reconstruct(model, sample), sample.target_poses, h, w, (0, 0, 0))
        error = ((out.rgb[0].clamp(0, 1) - sample.target_images[0]) ** 2).mean(0).double()
        lat, weight = ((torch.arange(h) + 0.5) / h * 180 - 90).abs(), ws_weights(h)
        for (name, values), rows in zip(acc.items(), (lat < 30, (lat >= 30) & (lat < 60), lat >= 60)):
            values.append(-10 * np.log10(float((error[rows] * weight[rows, None]).sum() / (weight[rows].sum() * w))))
    return {k: float(np.mean(v)) for k, v in acc.items()}


def held_out(data: Path) -> SyntheticDataset:
    return SyntheticDataset(data, views="two_view", scenes=SyntheticDataset(data).scenes[-8:])


def ensure_dataset(root: Path, cfg) -> Path:
    if not (root / "meta.json").is_file():
        write_synthetic_dataset(root, 28, (64, 128), cfg, seed=0)
    return root


def recipes(out: Path) -> None:
    data = ensure_dataset(out / "data", profile_config("occlusion"))
    run_study(data, out / "study", RECIPES, seeds=(0,), schedule=Schedule(300, 150, 150), held_out=8)
    test = held_out(data)
    for v in RECIPES[1:]:
        run = out / "study" / "runs" / v.name / "seed0"
        for name in ("model_stage2.safetensors", "model.safetensors"):
            if (run / name).is_file():
                print(f"{v.name} {name}: WS-PSNR all / occluded: {branches(run / name, test)}", flush=True)
    print((out / "study" / "ablation.md").read_text())


def coverage(out: Path) -> None:
    data = ensure_dataset(out / "data", profile_config("occlusion"))
    run_study(data, out / "study", COVERAGE, seeds=(0,), schedule=Schedule(300, 150, 150), held_out=8)
    print((out / "study" / "ablation.md").read_text())
    # targets 1-2 m off the contexts' line: twice the occluded share, wider hidden regions
    known = {v.name: v for v in default_variants()}
    far = ensure_dataset(out / "data_far_targets", profile_config("occlusion", target_offset=(1.0, 2.0)))
    run_study(far, out / "far_targets", [known["full"], known["pixel_only_no_edge_fading"]], seeds=(0,), held_out=8)
    print((out / "far_targets" / "ablation.md").read_text())
    test = held_out(data)
    print(f"nearest visible pixel fill, occluded WS-PSNR: {nearest_visible_fill(test):.2f} (far targets: "
          f"{nearest_visible_fill(held_out(far)):.2f})")
    runs = out / "study" / "runs"
    print("| volume-only checkpoint, at test time | WS-PSNR all / occluded |\n|---|---|")
    print("\n".join(test_time_fusion(runs / "volume_only_room_bounds" / "seed0" / "model.safetensors", test)))
    for name in ("volume_only_room_bounds", "volume_only_spherical_room_bounds"):
        bands = latitude_bands(runs / name / "seed0" / "model.safetensors", test)
        print(name, "WS-PSNR by latitude:", ", ".join(f"{k} {v:.2f}" for k, v in bands.items()), flush=True)
    for name in ("full", "volume_weight_1_volume_stage2", "volume_only_room_bounds"):
        cover = branch_coverage(runs / name / "seed0" / "model.safetensors", test)
        print(name, ", ".join(f"{k} {v:.2f}" for k, v in cover.items()), flush=True)


def two_seed_suite(name: str, variants: list[Variant]):
    """A suite of ``variants`` on the study's data, schedule and seeds (0 and 1), written to ``OUT/name``."""
    def suite(out: Path) -> None:
        data = ensure_dataset(out / "data", profile_config("occlusion"))
        run_study(data, out / name, variants, seeds=(0, 1), schedule=Schedule(300, 150, 150), held_out=8)
        print((out / name / "ablation.md").read_text())
    return suite


gt_prior = two_seed_suite("gt_prior", GT_PRIOR)  # ground-truth input depth

# Targets 1.5-2.5 m off the contexts' line among 10 extra occluders: 16 % of the target pixels hidden from both
# inputs, in regions wide enough that stretching pixel Gaussians over them cannot look right.
WIDE_HOLES = dict(target_offset=(1.5, 2.5), occluders=10)
WIDE_HOLES_VARIANTS = ("full", "pixel_only", "pixel_only_no_edge_fading", "volume_only_cylindrical")
WIDE_HOLES_FIGURE = ("pixel_only", "full", "volume_only_cylindrical")  # columns after the truth


def wide_holes(out: Path) -> None:
    data = ensure_dataset(out / "data_wide_holes", profile_config("occlusion", **WIDE_HOLES))
    known = {v.name: v for v in default_variants()}
    run_study(data, out / "wide_holes", [known[n] for n in WIDE_HOLES_VARIANTS], seeds=(0, 1), held_out=8)
    print((out / "wide_holes" / "ablation.md").read_text())
    ceilings(out)
    runs = out / "wide_holes" / "runs"
    completion_figure({name: runs / name / "seed0" / "model.safetensors" for name in WIDE_HOLES_FIGURE},
                      held_out(data), Path(__file__).parent / "figures" / "completion_wide_holes.png")


def ensure_scale_dataset(root: Path) -> Path:
    """Session 8's 208 scenes of the study's profile (seed 0), ordered so that the study's 8 held-out scenes
    (20-27) come last: 200 training scenes, the same held-out scenes as every other suite."""
    import json

    ids = [f"{i:08d}" for i in range(208)]
    if not all((root / i / "meta.json").is_file() for i in ids):  # new, or a killed generation: it resumes
        write_synthetic_dataset(root, 208, (64, 128), profile_config("occlusion"), seed=0)
    meta = json.loads((root / "meta.json").read_text())
    if meta["scenes"] != ids[:20] + ids[28:] + ids[20:28]:
        meta["scenes"] = ids[:20] + ids[28:] + ids[20:28]
        (root / "meta.json").write_text(json.dumps(meta, indent=1))
    return root


# Volume only at 200 scenes and 3000 steps with finer triplanes: does the volume branch's resolution (22.5 deg x
# 2.5 m cells in the tiny preset) cap what it paints on hidden regions once data and steps are there?
FINE_GRIDS = [
    Variant("volume_only_grid_8x32x16", "volume only, grid 8x32x16 (11.25 deg, 1.25 m cells)",
            VOLUME_ONLY + ("model.volume.grid=[8,32,16]", "model.volume.image_grid=[4,16,8]"), kind="volume"),
    Variant("volume_only_grid_8x64x16", "volume only, grid 8x64x16 (5.6 deg, 1.25 m cells)",
            VOLUME_ONLY + ("model.volume.grid=[8,64,16]", "model.volume.image_grid=[4,32,8]"), kind="volume"),
    Variant("full_grid_8x64x16", "full (the tiny preset's recipe), grid 8x64x16",
            ("model.volume.grid=[8,64,16]", "model.volume.image_grid=[4,32,8]")),
]


def fine_grids_at_scale(out: Path) -> None:
    data = ensure_scale_dataset(out / "data_208")
    run_study(data, out / "fine_grids_at_scale", FINE_GRIDS, seeds=(0,), schedule=Schedule(1500, 750, 750), held_out=8)
    print((out / "fine_grids_at_scale" / "ablation.md").read_text())


# Volume only at 200 scenes and 3000 steps with colours decoded from the triplane instead of retrieved from the
# input views (Eq. 6): for a hidden point retrieval lands on the occluder, a decoder can learn the hidden colour.
DECODED_AT_SCALE = [Variant("volume_only_decoded_colour", "volume only, colour decoded from triplane features",
                            VOLUME_ONLY + ("model.volume.color=decoded",), kind="volume")]


def decoded_colour_at_scale(out: Path) -> None:
    data = ensure_scale_dataset(out / "data_208")
    run_study(data, out / "decoded_colour_at_scale", DECODED_AT_SCALE, seeds=(0,), schedule=Schedule(1500, 750, 750),
              held_out=8)
    print((out / "decoded_colour_at_scale" / "ablation.md").read_text())


def ceilings(out: Path) -> None:
    """What copying the surroundings, or knowing the hidden regions' mean colours, scores on occluded pixels."""
    for label, data in (("study data", ensure_dataset(out / "data", profile_config("occlusion"))),
                        ("wide holes", ensure_dataset(out / "data_wide_holes",
                                                      profile_config("occlusion", **WIDE_HOLES)))):
        test = held_out(data)
        oracles = ", ".join(f"{regions} {oracle_mean_fill(test, regions):.2f}"
                            for regions in ("target", "component", "component_depth"))
        print(f"{label}: occluded WS-PSNR of the true target filled with its nearest visible pixel "
              f"{nearest_visible_fill(test):.2f}; with true mean colours per {oracles}", flush=True)
sharp_prior = two_seed_suite("sharp_prior", SHARP_PRIOR)  # simulated prior blurred 0.5 px


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("out", type=Path)
    suites = {"recipes": recipes, "coverage": coverage, "gt_prior": gt_prior, "sharp_prior": sharp_prior,
              "wide_holes": wide_holes, "ceilings": ceilings, "fine_grids_at_scale": fine_grids_at_scale,
              "decoded_colour_at_scale": decoded_colour_at_scale}
    parser.add_argument("--suite", choices=tuple(suites), default="recipes")
    args = parser.parse_args()
    suites[args.suite](args.out)
