"""Issue 34: test-time variants of the shipped weights against the forward warp + inpaint, on the real fixture.

    python studies/sharp_variants.py --data <pano_grf fixture> --out studies/results/sharp_variants_fixture.json

Rows: FW + inpaint (the bar), and the tiny-synth weights drawn with the switches of docs/model.md ("Sharp pixel
Gaussians") turned on one at a time (``--variants``; ``tiny_sharp`` is the shipped drawing, ``tiny_sharp (per-view
footprint)`` that of session 16, ``tiny (the paper's drawing)`` the same weights drawn as the paper does), their
pixel branches with a fill behind (``--pixel-rows``);
per protocol, size and prior (``--priors``: gt, degraded:KIND, constant:M, default): WS-PSNR all / occluded, SSIM,
AbsRel. Results are appended to ``--out`` (settings already there are skipped).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch

from cylindersplat.data.datasets import make_dataset
from cylindersplat.evaluation.evaluate import evaluate
from cylindersplat.evaluation.methods import forward_warp_method, model_method, with_fill
from cylindersplat.model.pretrained import from_pretrained

SHARP = {"render_dilation": 0.0, "pixel.footprint": "surface", "pixel.footprint_px": 0.5, "pixel.opacity": "opaque"}
# the shipped weights' drawing of session 16 (one footprint for every pixel Gaussian); the variants studied with it
# keep it, so that their stored results are what these names give
RECIPE = {"render_dilation": 0.0, "pixel.footprint": "surface", "pixel.footprint_px": 0.5, "pixel.opacity": "opaque",
          "pixel.refine_depth": "where_missing", "fusion.surface_clearance": 0.2,
          "fusion.pixel_clearing": "at_depth_edges", "render_pixel_blending": "surface",
          "fusion.pixel_footprint": "per_view"}
# the shipped weights' drawing since session 17: configs/recipes/tiny_sharp.yaml (footprints by covisibility)
SHIPPED = {**RECIPE, "pixel.footprint_px": 0.7, "fusion.pixel_footprint": "covisible"}
# the recipe before session 16 (the front-most pixel splat wins): the variants studied with it keep it, so that their
# stored results (studies/results/sharp_*.json of 2026-11-26 before session 16) are what these names give
OVER = {**RECIPE, "render_pixel_blending": "over"}
VARIANTS = {
    "shipped": {},
    "dilation 0": {"render_dilation": 0.0},
    "+ pixel footprint": {"render_dilation": 0.0, "pixel.footprint": "pixel"},
    "+ opaque": {"render_dilation": 0.0, "pixel.footprint": "pixel", "pixel.opacity": "opaque"},
    "+ no refinement": {"render_dilation": 0.0, "pixel.footprint": "pixel", "pixel.opacity": "opaque",
                        "pixel.max_log_depth_offset": 0.0},
    "surface + opaque": {"render_dilation": 0.0, "pixel.footprint": "surface", "pixel.opacity": "opaque"},
    "surface + opaque + no refinement": {"render_dilation": 0.0, "pixel.footprint": "surface",
                                         "pixel.opacity": "opaque", "pixel.max_log_depth_offset": 0.0},
    "surface 0.5 + opaque + no refinement": {"render_dilation": 0.0, "pixel.footprint": "surface",
                                           "pixel.footprint_px": 0.5, "pixel.opacity": "opaque",
                                           "pixel.max_log_depth_offset": 0.0},
    "sharp": SHARP,
    "sharp + measured depth kept": {**SHARP, "pixel.refine_depth": "where_missing"},
    "tiny_sharp": SHIPPED,
    "tiny_sharp (per-view footprint)": RECIPE,
    "tiny_sharp + over": OVER,
    "tiny (the paper's drawing)": "paper",
    "tiny_sharp + layers": {**SHIPPED, "render_layering": "pixel_over_volume"},
    "tiny_sharp (per-view footprint) + layers": {**RECIPE, "render_layering": "pixel_over_volume"},
    "tiny_sharp + over + layers": {**OVER, "render_layering": "pixel_over_volume"},
    **{f"tiny_sharp + clearance {c:g}": {**OVER, "fusion.surface_clearance": c} for c in (0.0, 0.05, 0.1, 0.4)},
    "tiny_sharp + clearing seen_through": {**OVER, "fusion.pixel_clearing": "seen_through"},
    "tiny_sharp + blending + clearing seen_through": {**RECIPE, "fusion.pixel_clearing": "seen_through"},
    "tiny_sharp + no clearing": {**OVER, "fusion.pixel_clearing": "none"},
    **{f"tiny_sharp + edge step {e:g}": {**OVER, "fusion.clearing_edge_step": e} for e in (0.02, 0.1)},
    **{f"tiny_sharp + fusion sigma {v:g}": {**OVER, "fusion.sigma": v} for v in (0.02, 0.05)},
    **{f"tiny_sharp + footprint {f:g}": {**OVER, "pixel.footprint_px": f} for f in (0.4, 0.6, 0.7)},
    # session 17: the footprint again under surface blending, where a larger splat averages instead of hiding
    **{f"tiny_sharp + blended footprint {f:g}": {**RECIPE, "pixel.footprint_px": f} for f in (0.6, 0.7, 0.85, 1.0)},
    **{f"tiny_sharp + covisible footprint {f:g}": {**SHIPPED, "pixel.footprint_px": f} for f in (0.6, 0.7)},
    **{f"tiny_sharp + refinement within {m:g}": {**OVER, "pixel.refine_depth": "everywhere",
                                                   "pixel.max_log_depth_offset": m} for m in (0.02, 0.05, 0.1)},
}


def record(results: dict, key: str, res, out: Path, start: float,
           metrics=("ws_psnr", "ws_psnr_occluded", "ssim", "abs_rel")) -> None:
    """Put one setting's mean scores (an ``evaluate`` result) into ``results[key]``, print them and write all
    results to ``out`` (so an interrupted study keeps every setting it finished)."""
    results[key] = {m: {k: res.means[m].get(k) for k in metrics} for m in res.means}
    print(key, f"{time.time() - start:.0f}s", flush=True)
    for m, v in results[key].items():
        print(f"   {m:20s} " + "  ".join(f"{k}={v[k]:.3f}" if v[k] is not None else f"{k}=-" for k in v), flush=True)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(results, indent=1))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--data", required=True)
    p.add_argument("--format", default="pano_grf")
    p.add_argument("--sizes", default="64,128,256")
    p.add_argument("--protocols", default="two_view,one_view")
    p.add_argument("--priors", default="gt,degraded:mono")
    p.add_argument("--variants", default=",".join(VARIANTS))
    p.add_argument("--checkpoint", default="tiny-synth")
    p.add_argument("--scenes", default=None, help="synthetic data: comma list of scene ids")
    p.add_argument("--pixel-rows", default="", help="variants whose pixel branch + inpaint fill gets a row too")
    p.add_argument("--out", required=True)
    args = p.parse_args()
    base = from_pretrained(args.checkpoint)
    paper = {"render_dilation": 0.3, "pixel.footprint": "learned", "pixel.opacity": "learned",
             "pixel.refine_depth": "everywhere", "fusion.surface_clearance": 0.0,
             "fusion.pixel_clearing": "seen_through", "render_layering": "one_pass",
             "render_pixel_blending": "over", "fusion.pixel_footprint": "per_view"}
    models = {name: base.with_config(**(paper if VARIANTS[name] == "paper" else VARIANTS[name]))
              for name in args.variants.split(",")}
    results = {}
    out = Path(args.out)
    if out.exists():
        results = json.loads(out.read_text())
    for prior in args.priors.split(","):
        for protocol in args.protocols.split(","):
            for h in map(int, args.sizes.split(",")):
                key = f"{protocol} {h}x{2 * h} {prior}"
                if key in results:
                    continue
                start = time.time()
                options = {"scenes": args.scenes.split(",")} if args.scenes else {}
                dataset = make_dataset(args.format, args.data, views=protocol, resolution=(h, 2 * h), depth_prior=prior,
                                       **options)
                methods = [with_fill(forward_warp_method(), "inpaint", "FW + inpaint")]
                methods += [model_method(m, name) for name, m in models.items()]
                for name in filter(None, args.pixel_rows.split(",")):
                    pixel_only = model_method(models[name].with_config().set_mode("pixel"), name)
                    methods += [with_fill(pixel_only, fill, f"{name}: pixel branch + {fill}")
                                for fill in ("inpaint", "mean")]
                res = evaluate(dataset, methods, progress=False)
                record(results, key, res, out, start)


if __name__ == "__main__":
    torch.set_grad_enabled(False)
    main()
