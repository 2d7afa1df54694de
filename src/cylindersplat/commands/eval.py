"""``cylindersplat eval``: the paper's protocols on a dataset -> Markdown + JSON tables and pictures."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from ..utils.atomic import atomic_write_text

from ._arguments import device, equirect_resolution


def open_eval_dataset(args, protocol: str):
    from ..data import Loc360Dataset, PanoGRFDataset, SyntheticDataset
    from ..data.depth_prior import parse_depth_prior, require_depth_prior

    kwargs = {"resolution": args.resolution}
    if args.depth_prior != "default":
        kwargs["depth_prior"] = parse_depth_prior(args.depth_prior)
    if args.format == "synthetic":
        scenes = args.scenes.split(",") if args.scenes else None
        dataset = SyntheticDataset(args.data, views=protocol, scenes=scenes, **kwargs)
    elif args.format == "pano_grf":
        dataset = PanoGRFDataset(args.data, split=args.split, views=protocol, **kwargs)
    elif protocol != "all_between":
        raise ValueError("360Loc is evaluated with its own protocol; use --protocols all_between")
    else:
        dataset = Loc360Dataset(args.data, split=args.split, **kwargs)
    if args.depth_prior == "default":
        require_depth_prior(dataset, "--depth-prior")  # the methods would score black renders without a word
    return dataset


def run(args: argparse.Namespace) -> int:
    from ..evaluation import METRIC_COLUMNS, VIEW_COUNTS, evaluate, forward_warp_method, model_method, results_to_markdown
    from ..metrics import DepthRange, load_lpips
    from ..model import load_model

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
    for protocol in args.protocols.split(","):
        dataset = open_eval_dataset(args, protocol)
        result = evaluate(dataset, methods, lpips_net, args.max_examples, args.out / "examples" / protocol,
                          num_pictures=args.pictures, depth_range=depth_range)
        key = f"{Path(args.data).name} — {protocol} ({result.num_examples} examples)"
        keys = [column[0] for column in METRIC_COLUMNS] + list(VIEW_COUNTS)
        results[key] = {name: {k: m.get(k) for k in keys} for name, m in result.means.items()}
        details[protocol] = result.rows
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
    parser.add_argument("--format", default="synthetic", choices=["synthetic", "pano_grf", "loc360"], help="dataset layout (default synthetic)")
    parser.add_argument("--checkpoint", help="model .safetensors (from cylindersplat train); omit to score only the baseline")
    parser.add_argument("--protocols", default="two_view", help="comma list of two_view, one_view, n_view, all_between (default two_view)")
    parser.add_argument("--out", type=Path, default=Path("outputs/eval"), help="output folder (default outputs/eval)")
    parser.add_argument("--resolution", type=equirect_resolution, help="evaluate at HxW (default: stored size)")
    parser.add_argument("--split", default="test", help="split of pano_grf / loc360 data (default test)")
    parser.add_argument("--scenes", help="synthetic data: comma list of scene ids to use")
    parser.add_argument("--depth-prior", default="default", help="depth prior given to the methods: default (the dataset's; an error where it has none), none, gt, simulated, "
                        "files, constant:METRES, exported:NET.pt2, unik3d:WEIGHTS_DIR")
    parser.add_argument("--depth-range", type=float, nargs=2, metavar=("NEAR", "FAR"), help="valid reference depth (default 0.45 10 for pano_grf, else 0.05 1000)")
    parser.add_argument("--max-examples", type=int, help="score only the first N examples")
    parser.add_argument("--pictures", type=int, default=4, help="comparison pictures per protocol (default 4)")
    parser.add_argument("--lpips", default="auto", choices=["auto", "on", "off"], help="LPIPS column: auto uses local weights when found")
    parser.add_argument("--lpips-weights", help="LPIPS-VGG weights file (else $CYLINDERSPLAT_LPIPS_WEIGHTS)")
    parser.add_argument("--no-baseline", action="store_true", help="do not score the forward-warp baseline")
    parser.add_argument("--device", type=device, default="auto", help="auto (CUDA when available), cpu, cuda[:N] (default auto)")
    parser.set_defaults(func=run)
