"""``cylindersplat ablate``: the ablation study (train variants x seeds, score on held-out scenes)."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..utils.atomic import atomic_write_text
from ..utils.jsonfile import json_text
from ._arguments import device, fill_list, model_resolution, positive_float, positive_int


def _steps(text: str) -> tuple[int, int, int]:
    try:
        parts = tuple(int(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--steps must be three integers like 300,150,150, got {text!r}") from None
    if len(parts) != 3 or min(parts) < 0 or parts[0] == 0:
        raise argparse.ArgumentTypeError(f"--steps needs stage-1,stage-2,stage-3 steps (stage 1 > 0), got {text!r}")
    return parts


def register(subparsers) -> None:
    from ..study import extra_variants, variant_names

    extras = [v.name for v in extra_variants()]

    p = subparsers.add_parser(
        "ablate", help="ablation study: train model variants with several seeds and tabulate them",
        description="Train the tiny model's variants (full, pixel only, volume only with cylindrical / spherical / "
        "Cartesian triplanes, and the paper's switches) with one schedule and several seeds on procedural scenes, "
        "score them on the same held-out scenes (all pixels and pixels no input view sees) and write ablation.md / "
        "ablation.json. Resumable: finished runs are scored, not retrained. Results: benchmarks/RESULTS.md.",
    )
    p.add_argument("--data", type=Path, help="synthetic dataset (default: generate OUT/data "
                                             "with the occlusion profile)")
    p.add_argument("--out", type=Path, default=Path("outputs/ablation"),
                   help="output folder (default outputs/ablation)")
    p.add_argument("--variants", nargs="+", default=None, metavar="NAME",
                   help="variants to run (default: the default study, "
                   f"{', '.join(n for n in variant_names() if n not in extras)}; also available: {', '.join(extras)})")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1], help="training seeds (default 0 1)")
    p.add_argument("--steps", type=_steps, default=(300, 150, 150),
                   help="optimizer steps of stages 1,2,3 of the full model; other variants get the same "
                        "total (default 300,150,150)")
    p.add_argument("--lr", type=positive_float, default=2e-3, help="peak learning rate (default 2e-3)")
    p.add_argument("--scenes", type=positive_int, default=28,
                   help="scenes to generate when --data is not given (default 28)")
    p.add_argument("--held-out", type=int, default=8, help="last N scenes are scored, not trained on (default 8)")
    p.add_argument("--resolution", type=model_resolution, default=(64, 128), help="panorama HxW (default 64x128)")
    p.add_argument("--depth-prior", default="default", metavar="SPEC",
                   help="input depth prior of every variant, trained and scored (a data.depth_prior spec: gt, "
                   "simulated:blur_sigma=0.5, ...; default: the synthetic data's simulated prior)")
    p.add_argument("--device", type=device, default="auto",
                   help="auto (CUDA when available), cpu, cuda[:N] (default auto)")
    p.add_argument("--fills", type=fill_list, default=["mean", "inpaint"], metavar="FILL[,FILL...]",
                   help="fill rows of the pixel-only variants and the forward warp: mean (the inputs' mean colour) or "
                   "inpaint (a 2-D inpaint) behind the pixels a render leaves uncovered; none for no fill rows "
                   "(default mean,inpaint)")
    p.add_argument("--threads", type=positive_int, default=2, help="torch threads of every run (default 2): part of "
                   "the recipe, as the thread count sets the order of float sums; the same count "
                   "gives bit-identical reruns")
    p.add_argument("--json", type=Path, help="also copy ablation.json here (e.g. studies/results/ablation.json)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from ..study import Schedule, all_variants, default_variants, run_study

    known = {v.name: v for v in all_variants()}
    names = args.variants or [v.name for v in default_variants()]
    unknown = [n for n in names if n not in known]
    if unknown:
        raise ValueError(f"unknown variant(s) {unknown}; choose from {list(known)}")
    data = args.data or _generate(args)
    schedule = Schedule(*args.steps, lr=args.lr)
    report = run_study(data, args.out, [known[n] for n in names], tuple(args.seeds), schedule, args.held_out,
                       args.resolution, args.device, depth_prior=args.depth_prior, fills=tuple(args.fills),
                       threads=args.threads)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(args.json, json_text(report))
    print((args.out / "ablation.md").read_text())
    return 0


def _generate(args) -> Path:
    from ..data.synth import profile_config, write_synthetic_dataset

    root = args.out / "data"
    # the occlusion profile (targets off the contexts' line, occluders, doorways): a real share of every target
    # is hidden from both inputs
    write_synthetic_dataset(root, args.scenes, args.resolution, profile_config("occlusion"), seed=0)
    return root
