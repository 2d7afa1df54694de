"""``cylindersplat eval``: the paper's protocols on a dataset -> Markdown + JSON tables and pictures."""

from __future__ import annotations

import argparse
from pathlib import Path

from ..dataset_layouts import DATASET_SPECS, dataset_spec
from ..utils.atomic import atomic_write_text, output_set
from ..utils.jsonfile import json_text
from ._arguments import NearFar, device, equirect_resolution, fill_list, memory_advice, nonnegative_int, positive_int

RELEASED_RESOLUTION = (256, 512)  # evaluate_mp3d_double_256.py of the authors' released code
PROTOCOL_TITLES = {
    "released": "released (inputs first+last, all three frames scored: the authors' released scoring, comparable "
                "with the paper's Table 1)",
}


def positive_int_list(text: str) -> list[int]:
    """``"3"`` or ``"2,3,4"`` -> ``[3]`` / ``[2, 3, 4]`` (integers >= 1); an argparse type."""
    try:
        values = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer or a comma list of integers, got {text!r}") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"expected integers >= 1, got {text!r}")
    return values


def eval_runs(args) -> list[tuple[str, str, dict]]:
    """``(label, protocol, loader options)`` per table: one per protocol, and for 360Loc's all_between one per
    ``--views`` x ``--gap`` (label ``all_between_3views_gap3``; plain ``all_between`` when neither is given)."""
    spec = dataset_spec(args.format)  # which of these options its loader takes
    chosen = args.views is not None or args.gap is not None or args.views_layout is not None
    if chosen and not spec.accepts("context_views"):
        raise ValueError(f"--views, --gap and --views-layout choose 360Loc's context frames (--format loc360, protocol "
                         f"all_between); the {args.format} format has fixed protocols: use --protocols")
    if getattr(args, "targets", None):  # a folder of panoramas with held-out frames: one table
        if not spec.accepts("targets"):
            raise ValueError("--targets holds out frames of a folder of panoramas (--format folder), not of "
                             f"{args.format} data")
        return [("held_out", "held_out", {})]
    runs = []
    for protocol in args.protocols.split(","):
        if protocol != "all_between" or not spec.accepts("context_views"):
            runs.append((protocol, protocol, {}))
            continue
        layout = args.views_layout or "spaced"
        for views in args.views or [2]:
            for gap in args.gap or [3]:
                label = protocol
                if chosen:
                    label += f"_{views}views_gap{gap}" + ("_released" if layout == "released" else "")
                runs.append((label, protocol, {"context_views": views, "gap": gap, "context_layout": layout}))
    return runs


def context_spacing(dataset, count: int) -> str | None:
    """One line on the context poses of the first ``count`` examples: mean distance between neighbouring
    contexts and between the outermost ones (metres), or None for a dataset without example references."""
    import torch

    if not hasattr(dataset, "example"):
        return None
    neighbour, outer = [], []
    for index in range(count):
        ref = dataset.example(index)
        centers = torch.stack([ref.frames[i].c2w[:3, 3].double() for i in sorted(ref.views.context)])
        if len(centers) < 2:
            return None
        neighbour.append(float((centers[1:] - centers[:-1]).norm(dim=-1).mean()))
        outer.append(float(torch.cdist(centers, centers).max()))
    if not neighbour:
        return None
    return (f"context baseline: {sum(neighbour) / len(neighbour):.2f} m between neighbouring contexts, "
            f"{sum(outer) / len(outer):.2f} m first to last (mean over {len(outer)} examples)")


def open_eval_dataset(args, protocol: str, loader_options: dict | None = None):
    from ..data.datasets import make_dataset

    spec = dataset_spec(args.format)  # the command's options its loader takes
    options = {"scenes": args.scenes.split(",")} if spec.accepts("scenes") and args.scenes else {}
    if spec.accepts("targets") and getattr(args, "targets", None):
        options["targets"] = [name for name in args.targets.split(",") if name]
    if spec.accepts("allow_outside_paths") and getattr(args, "allow_outside_paths", False):
        options["allow_outside_paths"] = True
    options.update(loader_options or {})
    # The PCC reference: gt is Sample.target_depths; file:NAME arrives as Sample.target_reference_depths.
    reference = "none" if args.pcc_reference == "gt" else args.pcc_reference
    resolution = args.resolution
    if resolution is None and protocol == "released":  # the released scoring's size (paper Table 1 matches it)
        resolution = RELEASED_RESOLUTION
    elif resolution is None:  # a model's own size (set by run), else the stored size
        resolution = getattr(args, "model_resolution", None)
    return make_dataset(args.format, args.data, views=protocol, split=args.split, resolution=resolution,
                        depth_prior=args.depth_prior, reference=reference, prior_option="--depth-prior",
                        reference_option="--pcc-reference", **options)


def _apply_preset(args) -> None:
    """Fill --format, --depth-prior and --pcc-reference the user left out from the preset's data/eval sections."""
    preset = None
    if args.config:
        from ..training import load_config

        preset = load_config(args.config)
    if args.format is None and preset is None:
        args.format = _detect_format(args.data)
    defaults = {"format": ("synthetic", lambda c: c.data.format),
                "depth_prior": ("default", lambda c: c.data.depth_prior),
                "pcc_reference": ("gt", lambda c: c.eval.pcc_reference)}
    for key, (default, from_preset) in defaults.items():
        if getattr(args, key) is None:
            setattr(args, key, from_preset(preset) if preset is not None else default)
    from ..data.datasets import check_reference_spec

    check_reference_spec(args.pcc_reference, "--pcc-reference", allowed=("gt",))


def _detect_format(data) -> str:
    """--format from the folder's layout, by the rule the data commands use (``data info``, ``data priors``)."""
    from ..dataset_layouts import detect_layout

    try:
        chosen = detect_layout(data)
    except ValueError:
        known = ", ".join(dataset_spec(name).what for name in DATASET_SPECS)
        raise ValueError(f"{data}: cannot tell the dataset layout (none of: {known}); name it with --format "
                         f"{'|'.join(DATASET_SPECS)}") from None
    print(f"data layout: {chosen} (detected; --format to choose another)")
    return chosen


@memory_advice("use a smaller --resolution (the size everything is scored at), or a GPU (--device cuda)")
def run(args: argparse.Namespace) -> int:
    from ..evaluation import (
        METRIC_COLUMNS,
        VIEW_COUNTS,
        evaluate,
        fill_methods,
        forward_warp_method,
        model_method,
        results_to_markdown,
    )
    from ..metrics import DepthRange, load_lpips

    _apply_preset(args)
    protocols = args.protocols.split(",")
    if args.resolution is None and not args.no_model and protocols != ["released"]:
        # the model's size, not the stored one (read from its header); the released protocol keeps its own 256x512
        from ..model.pretrained import DEFAULT_PRETRAINED, weights_config
        from ._inference import model_size

        args.model_resolution = model_size(weights_config(args.checkpoint or DEFAULT_PRETRAINED), None)
    # Every dataset first: a missing prior or reference fails before any model is loaded.
    runs = eval_runs(args)
    datasets = {label: (protocol, options, open_eval_dataset(args, protocol, options))
                for label, protocol, options in runs}
    methods = []
    if not args.no_model:
        from ..model.pretrained import DEFAULT_PRETRAINED, from_pretrained

        if args.checkpoint is None:
            print(f"using the shipped {DEFAULT_PRETRAINED} weights (--checkpoint for your own, "
                  "--no-model for the baseline only)")
        model = from_pretrained(args.checkpoint or DEFAULT_PRETRAINED, map_location=args.device)
        if model.mode == "pixel":  # a pixel-only model leaves holes: its fill rows beside it
            methods += fill_methods(model_method(model, "CylinderSplat (pixel only)", device=args.device), args.fills)
        else:
            methods.append(model_method(model, "CylinderSplat", device=args.device))
        if model.mode == "both" and args.fills:  # what the volume branch must beat: its pixel branch with a fill
            pixel = from_pretrained(args.checkpoint or DEFAULT_PRETRAINED, map_location=args.device).set_mode("pixel")
            methods += fill_methods(model_method(pixel, "its pixel branch", device=args.device), args.fills)
    if not args.no_baseline:
        methods += fill_methods(forward_warp_method(), args.fills)
    if not methods:
        raise ValueError("nothing to evaluate: drop --no-model or --no-baseline")
    lpips_net = None
    if args.lpips_weights or args.lpips == "on":
        lpips_net = load_lpips(args.lpips_weights)
    else:
        try:
            lpips_net = load_lpips(None) if args.lpips == "auto" else None
        except FileNotFoundError:
            print("LPIPS: no local weights (--lpips-weights, $CYLINDERSPLAT_LPIPS_WEIGHTS, or the lpips package with "
                  "torchvision's cached VGG16 weights; docs/evaluation.md); column shown as n/a")
    if lpips_net is not None and getattr(lpips_net, "sources", None):
        print(f"LPIPS: VGG trunk from {lpips_net.sources['trunk']}, linear layers from {lpips_net.sources['linear']}")
    depth_range = DepthRange(*(args.depth_range or dataset_spec(args.format).depth_range))
    args.out.mkdir(parents=True, exist_ok=True)
    results, details, settings, notes = {}, {}, {}, []
    for label, (protocol, options, dataset) in datasets.items():
        result = evaluate(dataset, methods, lpips_net, args.max_examples, args.out / "examples" / label,
                          num_pictures=args.pictures, depth_range=depth_range,
                          pcc_reference="gt" if args.pcc_reference == "gt" else "reference")
        title = PROTOCOL_TITLES.get(protocol, protocol)
        if protocol == "released" and args.resolution is None:  # its own size, whatever the other tables use
            title += f", {RELEASED_RESOLUTION[0]}x{RELEASED_RESOLUTION[1]}"
        if options:
            title += f", {options['context_views']} views, gap {options['gap']}"
            title += ", released layout" if options["context_layout"] == "released" else ""
        key = f"{Path(args.data).name} — {title} ({result.num_examples} examples)"
        keys = [column[0] for column in METRIC_COLUMNS] + list(VIEW_COUNTS)
        results[key] = {name: {k: m.get(k) for k in keys} for name, m in result.means.items()}
        details[label] = result.rows
        settings[label] = {"protocol": protocol, **options}
        if options:
            spacing = context_spacing(dataset, result.num_examples)
            if spacing:
                result.notes.append(spacing)
        if args.pcc_reference != "gt":
            result.notes.append(f"PCC against {args.pcc_reference} (AbsRel, RMSE, δ1 against the ground "
                                "truth, where there is one)")
        for note in result.notes:
            print(f"{label}: {note}")
            notes.append(f"{label}: {note}")
    backgrounds = {m.name: m.background for m in methods}
    table = results_to_markdown(results, title="Evaluation", backgrounds=backgrounds)
    if notes:  # the table's file carries what the run printed about it
        table += "\nNotes:\n" + "".join(f"- {note}\n" for note in notes)
    write_tables(args.out, table, {"means": results, "views": details, "settings": settings, "notes": notes,
                                   "backgrounds": backgrounds})
    print(table)
    print(f"wrote {args.out}/results.md, results.json and examples/")
    return 0


def write_tables(out: Path, table: str, data: dict) -> None:
    """``out/results.md`` and ``results.json``: both replace the earlier ones, or neither does."""
    with output_set(out, planned=[out / "results.md", out / "results.json"]):
        atomic_write_text(out / "results.md", table)
        atomic_write_text(out / "results.json", json_text(data))


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "eval", help="evaluate a checkpoint (and the forward-warp baseline) on a dataset",
        description=(
            "Run the paper's protocols (two_view: first+last frame in, middle out; one_view: middle "
            "in, outer out; n_view: all but the middle in; all_between: 360Loc, with --views and --gap) and "
            "write a table "
            "(PCC, WS-PSNR, SSIM, LPIPS, AbsRel, RMSE, delta1, LRCE, time, then WS-PSNR, PSNR, L1 and AbsRel "
            "on the occluded pixels -- those no input view sees, found with the ground-truth depth of targets "
            "and inputs -- and their share) as Markdown and JSON plus comparison pictures (ground truth / "
            "methods; RGB | depth). See docs/evaluation.md."
        ),
    )
    parser.add_argument("--data", required=True, help="dataset folder (synthetic output, png_render_* folder, 360Loc "
                                                      "root or a folder of posed panoramas)")
    parser.add_argument("--format", "--layout", dest="format", choices=list(DATASET_SPECS),
                        help="dataset layout (default: the --config preset's, else detected from --data as the data "
                        "commands do); folder: posed panoramas in the input format of docs/inference.md (one folder, "
                        "or a folder of them), frames held out with --targets or by --protocols "
                        "two_view/one_view/n_view in poses-file order")
    parser.add_argument("--config", help="training preset or YAML (e.g. paper) whose data.format, data.depth_prior and "
                        "eval.pcc_reference are the defaults of --format, --depth-prior and --pcc-reference")
    parser.add_argument("--checkpoint", help="model .safetensors (from cylindersplat train), a run folder or a shipped "
                        "model name (default: the shipped tiny-synth weights)")
    parser.add_argument("--no-model", action="store_true", help="score only the forward-warp baseline")
    parser.add_argument("--protocols", default="two_view", help="comma list of two_view, one_view, n_view, "
                        "all_between, released (default two_view). released: the authors' released scoring (first+last "
                        "frame in, all three frames scored, the inputs included; 256x512 unless --resolution), the one "
                        "to put beside the paper's Table 1; two_view scores only the novel middle frame")
    parser.add_argument("--fills", type=fill_list, default=["mean", "inpaint"], metavar="FILL[,FILL...]",
                        help="fill rows: the forward warp (and a model's pixel branch) again with mean (the inputs' "
                        "mean colour) or inpaint (a 2-D inpaint) behind the pixels it leaves uncovered; none for no "
                        "fill rows (default mean,inpaint)")
    parser.add_argument("--views", type=positive_int_list, metavar="N[,N...]",
                        help="360Loc (all_between): context views per example, e.g. 3 or 2,3,4 for the paper's "
                        "multi-view table (default 2); one table each")
    parser.add_argument("--gap", type=positive_int_list, metavar="G[,G...]",
                        help="360Loc (all_between): frames between neighbouring contexts (default 3, ~1.4 m; frames "
                        "are ~0.46 m apart, so wider baselines need larger gaps); one table each")
    parser.add_argument("--views-layout", choices=["spaced", "released"],
                        help="360Loc with 3 or 4 views: spaced (contexts every --gap frames, all frames from first to "
                        "last scored; default) or released (the released code's three_sample/four_sample: the pair "
                        "--gap apart plus adjacent frames); see docs/evaluation.md")
    parser.add_argument("--out", type=Path, default=Path("outputs/eval"), help="output folder (default outputs/eval)")
    parser.add_argument("--resolution", type=equirect_resolution, help="evaluate at HxW (default: the model's own "
                        "resolution; with --no-model the stored size; the released protocol: 256x512)")
    parser.add_argument("--split", default="test", help="split of pano_grf / loc360 data (default test)")
    parser.add_argument("--scenes", help="synthetic data: comma list of scene ids to use")
    parser.add_argument("--targets", help="--format folder: comma list of frames (image names or stems) held out as "
                        "targets, the other frames being the inputs (instead of --protocols)")
    parser.add_argument("--depth-prior", help="depth prior given to the methods: default (the dataset's; an error "
                        "where it has none), file:NAME (from `cylindersplat data priors`), gt, simulated, "
                        "constant:METRES, exported:NET.pt2, unik3d:WEIGHTS, depth_anything_v2:MODEL, or none "
                        "(zeros, on request only)")
    parser.add_argument("--pcc-reference", help="reference depth of the PCC column: gt (default) or file:NAME, e.g. "
                        "file:depth_anywhere as in the paper (files from `cylindersplat data priors`)")
    parser.add_argument("--depth-range", nargs=2, action=NearFar, metavar=("NEAR", "FAR"),
                        help="valid reference depth (default 0.45 10 for pano_grf, else 0.05 1000)")
    parser.add_argument("--allow-outside-paths", action="store_true",
                        help="--format folder: read image/depth files its poses files name outside their folder "
                        "(absolute or ../ paths); refused by default")
    parser.add_argument("--max-examples", type=positive_int, help="score only the first N examples")
    parser.add_argument("--pictures", type=nonnegative_int, default=4,
                        help="comparison pictures per protocol (default 4)")
    parser.add_argument("--lpips", default="auto", choices=["auto", "on", "off"],
                        help="LPIPS column: auto uses local weights when found")
    parser.add_argument("--lpips-weights", help="LPIPS-VGG weights file (else $CYLINDERSPLAT_LPIPS_WEIGHTS)")
    parser.add_argument("--no-baseline", action="store_true", help="do not score the forward-warp baseline")
    parser.add_argument("--device", type=device, default="auto",
                        help="auto (CUDA when available), cpu, cuda[:N] (default auto)")
    parser.set_defaults(func=run)
