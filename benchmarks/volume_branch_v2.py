"""The volume branch, second attempt (issue 23): colour rules, the stage-3 volume loss, pixel clearing, all-view
attention and k Gaussians per cell, judged against pixel-only models with fills behind.

    python benchmarks/volume_branch_v2.py OUT_DIR [--variants NAME ...] [--seeds 0 1] [--threads 1]
    python benchmarks/volume_branch_v2.py OUT_DIR --table --json benchmarks/results/volume_branch_v2.json

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

from cylindersplat.data.synth import profile_config, write_synthetic_dataset
from cylindersplat.experiments.ablation import VOLUME_ONLY, Schedule, Variant, run_study

WIDE_HOLES = dict(target_offset=(1.5, 2.5), occluders=10)
SURFACE = ("model.volume.color=surface",)
VOLUME_LOSS = ("loss.volume_loss=released", "loss.volume_weight=1")
CLEARING = ("model.fusion.pixel_clearing=seen_through",)
RECIPE = SURFACE + VOLUME_LOSS + CLEARING

VARIANTS = [
    Variant("pixel_only", "pixel branch only (tiny preset: edge fading)", kind="pixel"),
    Variant("pixel_only_no_edge_fading", "pixel branch only, no edge fading", ("model.pixel.edge_sigma=0",), kind="pixel"),
    Variant("full", "the tiny preset (Eq. 6 colour, no volume loss)"),
    Variant("surface", "full, nearest-observed-surface colour (9x9 taps, T = 0.1 m)", SURFACE),
    Variant("surface_vloss", "full, surface colour + the released stage-3 volume loss", SURFACE + VOLUME_LOSS),
    Variant("recipe", "full, surface colour + volume loss + pixel clearing (seen-through space)", RECIPE),
    Variant("recipe_eq6", "the recipe with Eq. 6 colour", VOLUME_LOSS + CLEARING),
    Variant("recipe_released_mlp", "the recipe with the released tap MLP colour",
            ("model.volume.color=released_mlp",) + VOLUME_LOSS + CLEARING),
    Variant("recipe_learned_T", "the recipe, temperature learned", RECIPE + ("model.volume.learn_temperature=true",)),
    Variant("recipe_all_views", "the recipe, triplane-to-image attention over all views", RECIPE + ("model.volume.image_views=all",)),
    Variant("recipe_k3", "the recipe, 3 Gaussians per cell", RECIPE + ("model.volume.gaussians_per_cell=3",)),
    Variant("volume_only_cylindrical", "volume only, cylindrical, surface colour", VOLUME_ONLY + SURFACE, kind="volume"),
    Variant("volume_only_spherical", "volume only, spherical, surface colour",
            VOLUME_ONLY + SURFACE + ("model.volume.coordinates=spherical",), kind="volume"),
    Variant("volume_only_cartesian", "volume only, Cartesian, surface colour",
            VOLUME_ONLY + SURFACE + ("model.volume.coordinates=cartesian",), kind="volume"),
    Variant("volume_only_cylindrical_eq6", "volume only, cylindrical, Eq. 6 colour", VOLUME_ONLY, kind="volume"),
]


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
    args = parser.parse_args()
    data = ensure_data(args.data or args.out / "data")
    chosen = [v for v in VARIANTS if args.variants is None or v.name in args.variants]
    if args.table:  # only what has finished for every seed
        chosen = [v for v in chosen if all((args.out / "runs" / v.name / f"seed{s}" / "model.safetensors").is_file()
                                           for s in args.seeds)]
    report = run_study(data, args.out, chosen, seeds=tuple(args.seeds), schedule=Schedule(), held_out=8,
                       threads=args.threads)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=1))
    print((args.out / "ablation.md").read_text())


if __name__ == "__main__":
    main()
