"""``cylindersplat eval``: the paper's protocols on a dataset -> Markdown + JSON tables and pictures."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..utils.atomic import atomic_write_text

from ._arguments import device, equirect_resolution


def open_eval_dataset(args, protocol: str):
    from ..data.datasets import make_dataset

    options = {"scenes": args.scenes.split(",")} if args.format == "synthetic" and args.scenes else {}
    # The PCC reference: gt is Sample.target_depths; file:NAME arrives as Sample.target_reference_depths.
    reference = "none" if args.pcc_reference == "gt" else args.pcc_reference
    return make_dataset(args.format, args.data, views=protocol, split=args.split, resolution=args.resolution,
                        depth_prior=args.depth_prior, reference=reference, prior_option="--depth-prior",
                        reference_option="--pcc-reference", **options)


def _apply_preset(args) -> None:
    """Fill --format, --depth-prior and --pcc-reference the user left out from the preset's data/eval sections."""
    preset = None
    if args.config:
        from ..training import load_config

        preset = load_config(args.config)
    defaults = {"format": ("synthetic", lambda c: c.data.format), "depth_prior": ("default", lambda c: c.data.depth_prior),
                "pcc_reference": ("gt", lambda c: c.eval.pcc_reference)}
    for key, (default, from_preset) in defaults.items():
        if getattr(args, key) is None:
            setattr(args, key, from_preset(preset) if preset is not None else default)
    from ..data.datasets import check_reference_spec

    check_reference_spec(args.pcc_reference, "--pcc-reference", allowed=("gt",))


def run(args: argparse.Namespace) -> int:
    from ..evaluation import METRIC_COLUMNS, VIEW_COUNTS, evaluate, forward_warp_method, model_method, results_to_markdown
    from ..metrics import DepthRange, load_lpips
    from ..model import load_model

    _apply_preset(args)
    # Every dataset first: a missing prior or reference fails before any model is loaded.
    datasets = {protocol: open_eval_dataset(args, protocol) for protocol in args.protocols.split(",")}
    methods = []
    if args.checkpoint:
        methods.append(model_method(load_model(args.checkpoint, map_location=args.device), "CylinderSplat", device=args.device))
    if not args.no_baseline:
        methods.append(forward_warp_method())
    if not methods:
        raise ValueError("nothing to evaluate: give --checkpoint and/or drop --no-baseline")
    lpips_net = None
    if args.lpips_weights or args.lpips == "on":
        lpips_net = load_lpips(args.lpips_weights)
    else:
        try:
            lpips_net = load_lpips(None) if args.lpips == "auto" else None
        except FileNotFoundError:
            print("LPIPS: no local weights (set $CYLINDERSPLAT_LPIPS_WEIGHTS or --lpips-weights); column shown as n/a")
    depth_range = DepthRange(*args.depth_range) if args.depth_range else (
        DepthRange() if args.format == "pano_grf" else DepthRange(0.05, 1000.0))
    args.out.mkdir(parents=True, exist_ok=True)
    results, details = {}, {}
    for protocol, dataset in datasets.items():
        result = evaluate(dataset, methods, lpips_net, args.max_examples, args.out / "examples" / protocol,
                          num_pictures=args.pictures, depth_range=depth_range,
                          pcc_reference="gt" if args.pcc_reference == "gt" else "reference")
        key = f"{Path(args.data).name} — {protocol} ({result.num_examples} examples)"
        keys = [column[0] for column in METRIC_COLUMNS] + list(VIEW_COUNTS)
        results[key] = {name: {k: m.get(k) for k in keys} for name, m in result.means.items()}
        details[protocol] = result.rows
        if args.pcc_reference != "gt":
            result.notes.append(f"PCC against {args.pcc_reference} (AbsRel, RMSE, δ1 against the ground truth, where there is one)")
        for note in result.notes:
            print(f"{protocol}: {note}")
    table = results_to_markdown(results, title="Evaluation")
    atomic_write_text(args.out / "results.md", table)
    atomic_write_text(args.out / "results.json", json.dumps({"means": results, "views": details}, indent=1))
    print(table)
    print(f"wrote {args.out}/results.md, results.json and examples/")
    return 0


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "eval", help="evaluate a checkpoint (and the forward-warp baseline) on a dataset",
        description=(
            "Run the paper's protocols (two_view: first+last frame in, middle out; one_view: middle "
            "in, outer out; n_view: all but the middle in; all_between: 360Loc) and write a table "
            "(PCC, WS-PSNR, SSIM, LPIPS, AbsRel, RMSE, delta1, LRCE, time, then WS-PSNR, PSNR, L1 and AbsRel "
            "on the occluded pixels -- those no input view sees, found with the ground-truth depth of targets "
            "and inputs -- and their share) as Markdown and JSON plus comparison pictures (ground truth / "
            "methods; RGB | depth). See docs/evaluation.md."
        ),
    )
    parser.add_argument("--data", required=True, help="dataset folder (synthetic output, png_render_* folder or 360Loc root)")
    parser.add_argument("--format", choices=["synthetic", "pano_grf", "loc360"], help="dataset layout (default synthetic, or the --config preset's)")
    parser.add_argument("--config", help="training preset or YAML (e.g. paper) whose data.format, data.depth_prior and "
                        "eval.pcc_reference are the defaults of --format, --depth-prior and --pcc-reference")
    parser.add_argument("--checkpoint", help="model .safetensors (from cylindersplat train); omit to score only the baseline")
    parser.add_argument("--protocols", default="two_view", help="comma list of two_view, one_view, n_view, all_between (default two_view)")
    parser.add_argument("--out", type=Path, default=Path("outputs/eval"), help="output folder (default outputs/eval)")
    parser.add_argument("--resolution", type=equirect_resolution, help="evaluate at HxW (default: stored size)")
    parser.add_argument("--split", default="test", help="split of pano_grf / loc360 data (default test)")
    parser.add_argument("--scenes", help="synthetic data: comma list of scene ids to use")
    parser.add_argument("--depth-prior", help="depth prior given to the methods: default (the dataset's; an error where it "
                        "has none), file:NAME (from `cylindersplat data priors`), gt, simulated, constant:METRES, "
                        "exported:NET.pt2, unik3d:WEIGHTS, depth_anything_v2:MODEL, or none (zeros, on request only)")
    parser.add_argument("--pcc-reference", help="reference depth of the PCC column: gt (default) or file:NAME, e.g. "
                        "file:depth_anywhere as in the paper (files from `cylindersplat data priors`)")
    parser.add_argument("--depth-range", type=float, nargs=2, metavar=("NEAR", "FAR"), help="valid reference depth (default 0.45 10 for pano_grf, else 0.05 1000)")
    parser.add_argument("--max-examples", type=int, help="score only the first N examples")
    parser.add_argument("--pictures", type=int, default=4, help="comparison pictures per protocol (default 4)")
    parser.add_argument("--lpips", default="auto", choices=["auto", "on", "off"], help="LPIPS column: auto uses local weights when found")
    parser.add_argument("--lpips-weights", help="LPIPS-VGG weights file (else $CYLINDERSPLAT_LPIPS_WEIGHTS)")
    parser.add_argument("--no-baseline", action="store_true", help="do not score the forward-warp baseline")
    parser.add_argument("--device", type=device, default="auto", help="auto (CUDA when available), cpu, cuda[:N] (default auto)")
    parser.set_defaults(func=run)
