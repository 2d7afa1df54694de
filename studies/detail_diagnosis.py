"""Issue 34's diagnosis: where the model loses detail against a forward warp, step by step.

    python studies/detail_diagnosis.py --data <pano_grf fixture> --out studies/results/detail_diagnosis_fixture.json
    python studies/detail_diagnosis.py --data <synthetic dataset> --format synthetic --scenes LAST8 --sizes 64 \
        --out studies/results/detail_diagnosis_synthetic.json

For every example, protocol and size: WS-PSNR of each rung of :func:`cylindersplat.evaluation.diagnosis.ladder`
(inpaint fill behind each, as the warp has) on the target regions (seen by the nearest input, seen only by another,
hidden, depth-edge band) and SSIM, beside FW + inpaint; which Gaussians draw each region; the pixel head's footprint,
opacity and depth movement. ``--drawing paper`` (default) draws the weights as the paper does (dilation 0.3, learned
footprints and opacities, refinement everywhere); ``--drawing model`` as their config says (the shipped weights:
recipes/tiny_sharp). Prints a Markdown table (means over examples and targets) and writes everything to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import torch

from cylindersplat.data.datasets import make_dataset
from cylindersplat.evaluation.diagnosis import REGIONS, RUNGS, SOURCES, diagnose_sample
from cylindersplat.evaluation.evaluate import stored_depths_for
from cylindersplat.model.pretrained import from_pretrained
from cylindersplat.render import RasterSettings

# the switches of docs/model.md ("Sharp pixel Gaussians") at the paper's values
PAPER_DRAWING = {"render_dilation": 0.3, "pixel.footprint": "learned", "pixel.opacity": "learned",
                 "pixel.refine_depth": "everywhere", "fusion.surface_clearance": 0.0,
                 "fusion.pixel_clearing": "seen_through", "render_layering": "one_pass",
                 "render_pixel_blending": "over", "fusion.pixel_footprint": "per_view"}


def _mean(values):
    values = [v for v in values if v is not None and math.isfinite(v)]
    return sum(values) / len(values) if values else None


def table(summary: dict) -> str:
    lines = []
    for key, block in summary.items():
        lines.append(f"\n**{key}** (pixels per region: {block['pixels']})\n")
        lines.append("| rung | " + " | ".join(REGIONS) + " | SSIM |")
        lines.append("|---|" + "---|" * (len(REGIONS) + 1))
        for rung in RUNGS:
            row = block["rungs"][rung]
            cells = [f"{row[r]:.2f}" if row[r] is not None else "-" for r in REGIONS]
            lines.append(f"| {rung} | " + " | ".join(cells) + f" | {row['ssim']:.3f} |")
        shares = block["shares"]
        lines.append("\nshare of the full model's render drawn by " + ", ".join(
            f"{region}: " + " / ".join(f"{shares[region][s]:.2f}" if shares[region][s] is not None else "-"
                                       for s in SOURCES) for region in REGIONS) + f" ({' / '.join(SOURCES)})")
        lines.append(f"pixel head: {json.dumps({k: round(v, 3) for k, v in block['pixel'].items()})}")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True)
    p.add_argument("--format", default="pano_grf")
    p.add_argument("--scenes", default=None, help="synthetic data: comma list of scene ids")
    p.add_argument("--sizes", default="64,128,256", help="panorama heights")
    p.add_argument("--protocols", default="two_view,one_view")
    p.add_argument("--depth-prior", default="gt")
    p.add_argument("--checkpoint", default="tiny-synth")
    p.add_argument("--drawing", choices=("paper", "model"), default="paper",
                   help="paper: the weights drawn as the paper draws them (learned footprints and opacities, "
                        "refinement everywhere, no surface clearance); model: as the checkpoint's config says "
                        "(the shipped tiny-synth: recipes/tiny_sharp)")
    p.add_argument("--dilation", type=float, default=None,
                   help="the rasterizer's dilation for every rung "
                        "(default: 0.3 with --drawing paper, else the model's)")
    p.add_argument("--max-examples", type=int, default=None)
    p.add_argument("--out", required=True)
    args = p.parse_args()
    model = from_pretrained(args.checkpoint)
    if args.drawing == "paper":
        model = model.with_config(**PAPER_DRAWING)
    if args.dilation is None:
        args.dilation = model.config.render_dilation
    settings = RasterSettings(dilation=args.dilation)
    options = {"scenes": args.scenes.split(",")} if args.scenes else {}
    summary = {}
    for protocol in args.protocols.split(","):
        for h in map(int, args.sizes.split(",")):
            start = time.time()
            dataset = make_dataset(args.format, args.data, views=protocol, resolution=(h, 2 * h),
                                   depth_prior=args.depth_prior, **options)
            rows, shares, pixel, pixels = [], [], [], []
            for i in range(min(len(dataset), args.max_examples or len(dataset))):
                sample = dataset[i]
                result = diagnose_sample(model, sample, stored_depths_for(dataset, i, sample), settings=settings)
                rows += result["rows"]
                shares += result["shares"]
                pixel.append(result["pixel"])
                pixels += result["pixels"]
            key = (f"{protocol} {h}x{2 * h}, prior {args.depth_prior}, {args.drawing} drawing, "
                   f"dilation {args.dilation:g}")
            summary[key] = {
                "rungs": {rung: {**{r: _mean([row.ws_psnr[r] for row in rows if row.rung == rung]) for r in REGIONS},
                                 "ssim": _mean([row.ssim for row in rows if row.rung == rung])} for rung in RUNGS},
                "shares": {r: {s: _mean([sh[r][s] for sh in shares]) for s in SOURCES} for r in REGIONS},
                "pixel": {k: _mean([px[k] for px in pixel]) for k in pixel[0]},
                "pixels": {r: sum(px[r] for px in pixels) for r in REGIONS},
                "examples": i + 1,
            }
            print(table({key: summary[key]}), f"\n({time.time() - start:.0f} s)", flush=True)
            out = Path(args.out)
            out.parent.mkdir(parents=True, exist_ok=True)
            previous = json.loads(out.read_text()) if out.exists() else {}
            out.write_text(json.dumps({**previous, **summary}, indent=1))


if __name__ == "__main__":
    torch.set_grad_enabled(False)
    main()
