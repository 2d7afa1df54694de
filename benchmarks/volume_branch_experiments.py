"""The volume-branch experiments of benchmarks/RESULTS.md ("Volume branch"), one seed each.

    python benchmarks/volume_branch_experiments.py OUT_DIR      (about 35 min on the 2-core CPU machine)

Every variant trains the tiny model for 600 steps (300 / 150 / 150 over the stages it runs) on 20
procedural scenes of the occlusion profile at 64x128 and is scored on the same 8 held-out scenes,
all pixels and pixels no input view sees; then each checkpoint's branches are scored alone
(stage-2 and final weights) to see what each contributes.
"""

import sys
from pathlib import Path

from cylindersplat.data import SyntheticDataset
from cylindersplat.data.synth import write_synthetic_dataset
from cylindersplat.evaluation import evaluate, model_method
from cylindersplat.experiments.ablation import Schedule, Variant, run_study, study_sequence_config
from cylindersplat.metrics import DepthRange
from cylindersplat.model import load_model

PAPER = ("model.fusion.strategy=concat", "train.stage2_render=volume")  # the paper's recipe on the tiny model
VARIANTS = [
    Variant("pixel_only", "pixel branch only", PAPER, kind="pixel"),
    Variant("paper_recipe", "concat fusion, volume-only stage 2", PAPER),
    Variant("own_view_fusion", "depth_prune side=front", ("model.fusion.strategy=depth_prune", "model.fusion.side=front",
                                                          "train.stage2_render=volume")),
    Variant("hidden_fusion", "depth_prune side=hidden", ("train.stage2_render=volume",)),
    Variant("hidden_fusion_fused_stage2", "the tiny preset's recipe", ()),
    Variant("fine_grid_own_view_fusion", "grid 8x32x16", ("model.volume.grid=[8,32,16]", "model.volume.image_grid=[4,16,8]",
                                                          "model.fusion.strategy=depth_prune", "model.fusion.side=front",
                                                          "train.stage2_render=volume")),
    Variant("recipe_occluded_weight_4", "the recipe + loss.occluded_weight=4", ("loss.occluded_weight=4",)),
]


def branches(weights: Path, dataset) -> str:
    parts = []
    for mode in ("pixel", "volume", "both"):
        model = load_model(weights).set_mode(mode)
        m = evaluate(dataset, [model_method(model, mode)], depth_range=DepthRange(0.05, 1000), progress=False).means[mode]
        parts.append(f"{mode} {m['ws_psnr']:.2f} / {m.get('ws_psnr_occluded') or float('nan'):.2f}")
    return "; ".join(parts)


def main(out: str) -> None:
    out = Path(out)
    data = out / "data"
    if not (data / "meta.json").is_file():
        write_synthetic_dataset(data, 28, (64, 128), study_sequence_config(), seed=0)
    run_study(data, out / "study", VARIANTS, seeds=(0,), schedule=Schedule(300, 150, 150), held_out=8)
    held_out = SyntheticDataset(data, views="two_view", scenes=SyntheticDataset(data).scenes[-8:])
    for v in VARIANTS[1:]:
        run = out / "study" / "runs" / v.name / "seed0"
        for name in ("model_stage2.safetensors", "model.safetensors"):
            if (run / name).is_file():
                print(f"{v.name} {name}: WS-PSNR all / occluded: {branches(run / name, held_out)}", flush=True)
    print((out / "study" / "ablation.md").read_text())


if __name__ == "__main__":
    main(sys.argv[1])
