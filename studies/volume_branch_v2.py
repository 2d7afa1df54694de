"""The volume branch, second attempt (issue 23): colour rules, the stage-3 volume loss, pixel clearing, all-view
attention and k Gaussians per cell, judged against pixel-only models with fills behind.

    python studies/volume_branch_v2.py OUT_DIR [--variants NAME ...] [--seeds 0 1] [--threads 1]
    python studies/volume_branch_v2.py OUT_DIR --table --json studies/results/volume_branch_v2.json

Data: the "wide holes" procedural scenes (occlusion profile, targets 1.5-2.5 m off the contexts' line among 10
occluders; 28 scenes at 64x128, the last 8 held out, 14 % of their target pixels hidden from both inputs),
generated into ``OUT_DIR/data`` when absent. Every variant trains the tiny preset for the study's 600 steps
(full: 300 / 150 / 150) with torch at ``--threads`` threads; finished runs are scored, not retrained, so
several processes may train different variants into the same ``OUT_DIR`` and ``--table`` scores them all.
About 6-10 min per run on the 2-core CPU machine.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch

from cylindersplat.data.synth import profile_config, write_synthetic_dataset
from cylindersplat.study import Schedule, Variant, change_set, pinned_to_earlier_tiny, run_study

VOLUME_ONLY, SURFACE_RECIPE = change_set("volume_only"), change_set("surface_recipe")
PRIOR_ALIGNMENT, FINE_GRID = change_set("prior_alignment"), change_set("fine_grid")

WIDE_HOLES = dict(target_offset=(1.5, 2.5), occluders=10)
SURFACE = ("model.volume.color=surface",)
VOLUME_LOSS = ("loss.volume_loss=released", "loss.volume_weight=1")
CLEARING = ("model.fusion.pixel_clearing=seen_through",)
RECIPE = SURFACE + VOLUME_LOSS + CLEARING
ALIGNED, GRID2X = PRIOR_ALIGNMENT, FINE_GRID
assert set(RECIPE) == set(SURFACE_RECIPE)  # one definition of the recipe's switches, shared with the ablation

# every variant is a switch on the tiny preset as it was when this study ran (issue 23's recipe is its default now)
VARIANTS = pinned_to_earlier_tiny([
    Variant("pixel_only", "pixel branch only (tiny preset: edge fading)", kind="pixel"),
    Variant("pixel_only_no_edge_fading", "pixel branch only, no edge fading", ("model.pixel.edge_sigma=0",),
            kind="pixel"),
    Variant("full", "the tiny preset (Eq. 6 colour, no volume loss)"),
    Variant("surface", "full, nearest-observed-surface colour (9x9 taps, T = 0.1 m)", SURFACE),
    Variant("surface_vloss", "full, surface colour + the released stage-3 volume loss", SURFACE + VOLUME_LOSS),
    Variant("recipe", "full, surface colour + volume loss + pixel clearing (seen-through space)", RECIPE),
    Variant("recipe_eq6", "the recipe with Eq. 6 colour", VOLUME_LOSS + CLEARING),
    Variant("recipe_released_mlp", "the recipe with the released tap MLP colour",
            ("model.volume.color=released_mlp",) + VOLUME_LOSS + CLEARING),
    Variant("recipe_learned_T", "the recipe, temperature learned", RECIPE + ("model.volume.learn_temperature=true",)),
    Variant("recipe_all_views", "the recipe, triplane-to-image attention over all views",
            RECIPE + ("model.volume.image_views=all",)),
    Variant("recipe_k3", "the recipe, 3 Gaussians per cell", RECIPE + ("model.volume.gaussians_per_cell=3",)),
    Variant("recipe_edge_0.1", "the recipe with stronger edge fading (pixel.edge_sigma 0.1)",
            RECIPE + ("model.pixel.edge_sigma=0.1",)),
    # ground-truth depth as the input prior (an oracle input): can the recipe clear the bar with sharp depth?
    Variant("recipe_gt_prior", "the recipe, ground-truth input depth", RECIPE + ("data.depth_prior=gt",)),
    Variant("pixel_only_gt_prior", "pixel branch only, ground-truth input depth", ("data.depth_prior=gt",),
            kind="pixel"),
    # the inputs' depth priors rescaled to the poses' metric scale (photometric search), for both sides of the bar
    Variant("full_aligned", "the tiny preset, depth priors photometrically rescaled", ALIGNED),
    Variant("recipe_aligned", "the recipe, depth priors photometrically rescaled", RECIPE + ALIGNED),
    Variant("recipe_aligned_grid2x", "the recipe, priors rescaled, triplane grid 8x32x16 (tiny: 4x16x8)",
            RECIPE + ALIGNED + GRID2X),
    Variant("pixel_only_aligned", "pixel branch only, depth priors photometrically rescaled", ALIGNED, kind="pixel"),
    Variant("pixel_only_no_edge_fading_aligned", "pixel branch only, no edge fading, priors photometrically rescaled",
            ("model.pixel.edge_sigma=0",) + ALIGNED, kind="pixel"),
    # the colour oracle's widest window (17x17 taps: 19.45 dB hidden with the rescaled prior vs 19.08 for 9x9) and
    # stronger edge fading (the probe's +0.2 dB at test time), with the pixel-only row given the same edge fading
    Variant("recipe_aligned_grid2x_w8_edge0.1", "recipe, priors rescaled, 8x32x16 grid, 17x17 colour "
            "taps, pixel.edge_sigma 0.1", RECIPE + ALIGNED + GRID2X + ("model.volume.surface_window=8",
                                                                 "model.pixel.edge_sigma=0.1")),
    Variant("pixel_only_aligned_edge0.1", "pixel branch only, priors rescaled, pixel.edge_sigma 0.1",
            ALIGNED + ("model.pixel.edge_sigma=0.1",), kind="pixel"),
    Variant("volume_only_cylindrical", "volume only, cylindrical, surface colour", VOLUME_ONLY + SURFACE,
            kind="volume"),
    Variant("volume_only_spherical", "volume only, spherical, surface colour",
            VOLUME_ONLY + SURFACE + ("model.volume.coordinates=spherical",), kind="volume"),
    Variant("volume_only_cartesian", "volume only, Cartesian, surface colour",
            VOLUME_ONLY + SURFACE + ("model.volume.coordinates=cartesian",), kind="volume"),
    Variant("volume_only_cylindrical_eq6", "volume only, cylindrical, Eq. 6 colour", VOLUME_ONLY, kind="volume"),
    # the coordinate ordering again with the recipe's volume-side parts (surface colour, rescaled priors, 8x32x16
    # cells in every coordinate system; the volume loss and clearing act on fusion, which volume-only runs skip)
    *(Variant(f"volume_only_{coordinates}_recipe", f"volume only, {coordinates}, surface colour, priors rescaled, "
              "8x32x16 grid", VOLUME_ONLY + SURFACE + ALIGNED + GRID2X + (f"model.volume.coordinates={coordinates}",),
              kind="volume")
      for coordinates in ("cylindrical", "spherical", "cartesian")),
])


def hidden_targets(data: Path):
    """``(sample, hidden mask, latitude weights on it)`` of every held-out target with enough hidden pixels."""
    from cylindersplat.data import SyntheticDataset
    from cylindersplat.data.occlusion import occluded_mask
    from cylindersplat.evaluation.masked import MIN_OCCLUDED_PIXELS
    from cylindersplat.metrics.image import ws_weights

    for sample in SyntheticDataset(data, views="two_view", scenes=SyntheticDataset(data).scenes[-8:]):
        mask = occluded_mask(sample.target_depths[0], sample.target_poses[0], sample.context_gt_depths,
                             sample.context_poses)
        if int(mask.sum()) >= MIN_OCCLUDED_PIXELS:
            yield sample, mask, ws_weights(mask.shape[0])[:, None] * mask


@torch.no_grad()
def branch_report(weights: Path, data: Path) -> dict[str, float]:
    """On the held-out targets' hidden pixels (robust mask), one checkpoint: the mean alpha of the pixel Gaussians
    as fused (after any clearing) and with clearing off, of the volume Gaussians, and the WS-PSNR of the fused render
    and of the volume branch's own render (its Gaussians alone, before fusion)."""
    from cylindersplat.evaluation.masked import masked_ws_psnr
    from cylindersplat.model import load_model
    from cylindersplat.render import render_equirect

    model = load_model(weights).eval()
    acc: dict[str, list[float]] = {}
    for sample, mask, weight in hidden_targets(data):
        h, w = mask.shape
        truth = sample.target_images[0]

        def render(gaussians):
            return render_equirect(gaussians, sample.target_poses[None, :1], h, w)

        parts = {}
        clearing = model.config.fusion.pixel_clearing
        for setting in dict.fromkeys((clearing, "none")):
            model.config.fusion.pixel_clearing = setting
            out = model.set_mode("both")(sample.context_images[None], sample.context_priors[None],
                                         sample.context_poses[None])
            n = out.pixel_gaussians.num_gaussians
            fused = out.gaussians
            parts[f"pixel alpha ({setting})"] = render(_slice(fused, 0, n)).alpha[0, 0]
            if setting == clearing:
                parts["volume alpha"] = render(_slice(fused, n, fused.num_gaussians)).alpha[0, 0]
                parts["fused"] = render(fused).rgb[0, 0]
                parts["volume alone"] = render(out.volume_gaussians).rgb[0, 0]
        model.config.fusion.pixel_clearing = clearing
        for key, value in parts.items():
            if "alpha" in key:
                acc.setdefault(key, []).append(float((value * weight).sum() / weight.sum()))
            else:
                hidden = float(masked_ws_psnr(value.clamp(0, 1), truth, mask))
                acc.setdefault(f"WS-PSNR hidden, {key}", []).append(hidden)
    return {k: sum(v) / len(v) for k, v in acc.items()}


@torch.no_grad()
def clearing_probe(weights: Path, data: Path) -> dict[str, dict[str, float]]:
    """Test-time settings on one checkpoint, scored on the held-out hidden pixels: pixel clearing at several sigmas,
    clearing against the contexts' *true* depth (an oracle: which pixel Gaussians sit in space an input truly saw
    empty), and stronger edge fading. Per setting: the pixel Gaussians' mean alpha there and the fused WS-PSNR."""
    from dataclasses import replace

    from cylindersplat.evaluation.masked import masked_ws_psnr
    from cylindersplat.model import load_model
    from cylindersplat.model.config import set_dotted
    from cylindersplat.model.fusion import hidden_confidence
    from cylindersplat.render import render_equirect

    settings = {"as trained": {}, "no clearing": {"fusion.pixel_clearing": "none"},
                "clearing sigma 0.03": {"fusion.sigma": 0.03}, "clearing sigma 0.3": {"fusion.sigma": 0.3},
                "edge sigma 0.1": {"pixel.edge_sigma": 0.1}, "edge sigma 0.05": {"pixel.edge_sigma": 0.05},
                "clearing against true context depth (oracle)": {"oracle": True}}
    acc: dict[str, dict[str, list[float]]] = {}
    for name, changes in settings.items():
        model = load_model(weights).eval()
        for key, value in changes.items():
            if key != "oracle":
                set_dotted(model.config, key, value)
        for sample, mask, weight in hidden_targets(data):
            h, w = mask.shape
            c2w = sample.context_poses[None]
            out = model(sample.context_images[None], sample.context_priors[None], c2w)
            fused, n = out.gaussians, out.pixel_gaussians.num_gaussians
            if changes.get("oracle"):
                conf = hidden_confidence(out.pixel_gaussians.means, c2w, sample.context_gt_depths[None],
                                         model.config.fusion.sigma)
                opacities = fused.opacities.clone()
                opacities[:, :n] = out.pixel_gaussians.opacities * conf
                fused = replace(fused, opacities=opacities)
            pixel_alpha = render_equirect(_slice(fused, 0, n), sample.target_poses[None, :1], h, w).alpha[0, 0]
            rgb = render_equirect(fused, sample.target_poses[None, :1], h, w).rgb[0, 0]
            part = acc.setdefault(name, {})
            part.setdefault("pixel alpha hidden", []).append(float((pixel_alpha * weight).sum() / weight.sum()))
            hidden = float(masked_ws_psnr(rgb.clamp(0, 1), sample.target_images[0], mask))
            part.setdefault("WS-PSNR hidden", []).append(hidden)
            part.setdefault("WS-PSNR all", []).append(float(masked_ws_psnr(rgb.clamp(0, 1), sample.target_images[0],
                                                                           torch.ones_like(mask))))
    return {name: {k: sum(v) / len(v) for k, v in part.items()} for name, part in acc.items()}


def _slice(gaussians, start: int, stop: int):
    """Gaussians ``start:stop`` of a batched container (B, N, ...)."""
    from dataclasses import fields, replace

    return replace(gaussians, **{f.name: getattr(gaussians, f.name)[:, start:stop] for f in fields(gaussians)})


def ensure_data(root: Path) -> Path:
    if not (root / "meta.json").is_file():
        write_synthetic_dataset(root, 28, (64, 128), profile_config("occlusion", **WIDE_HOLES), seed=0)
    return root


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("--variants", nargs="+", choices=[v.name for v in VARIANTS])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--data", type=Path, help="the wide-holes data (default OUT/data; generated when absent)")
    parser.add_argument("--table", action="store_true", help="score every variant with finished runs of all seeds")
    parser.add_argument("--json", type=Path, help="copy the report here")
    parser.add_argument("--probe", help="a variant: test-time clearing / edge-fading settings "
                                        "on its seed-0 run, printed")
    parser.add_argument("--branches", action="store_true",
                        help="with --table: per variant and seed, each branch's alpha and WS-PSNR on hidden pixels")
    args = parser.parse_args()
    data = ensure_data(args.data or args.out / "data")
    if args.probe:
        probe = clearing_probe(args.out / "runs" / args.probe / "seed0" / "model.safetensors", data)
        for name, values in probe.items():
            print(f"{name}: " + ", ".join(f"{k} {v:.3f}" for k, v in values.items()), flush=True)
        if args.json:
            args.json.write_text(json.dumps({"variant": args.probe, "seed": 0, "settings": probe}, indent=1))
        return
    chosen = [v for v in VARIANTS if args.variants is None or v.name in args.variants]
    if args.table:  # only what has finished for every seed
        chosen = [v for v in chosen if all((args.out / "runs" / v.name / f"seed{s}" / "model.safetensors").is_file()
                                           for s in args.seeds)]
    report = run_study(data, args.out, chosen, seeds=tuple(args.seeds), schedule=Schedule(), held_out=8,
                       threads=args.threads)
    if args.table and args.branches:
        for v in chosen:
            if v.kind != "full":
                continue
            report["variants"][v.name]["branches"] = per_seed = {}
            for seed in args.seeds:
                per_seed[str(seed)] = branch_report(args.out / "runs" / v.name / f"seed{seed}" / "model.safetensors",
                                                    data)
                print(v.name, seed, {k: round(x, 3) for k, x in per_seed[str(seed)].items()}, flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1))
    print((args.out / "ablation.md").read_text())


if __name__ == "__main__":
    main()
