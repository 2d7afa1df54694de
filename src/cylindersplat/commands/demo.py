"""``cylindersplat demo``: the main job, end to end on a default that needs no download.

1. generate a small procedural panorama set (``OUT/data``);
2. take the shipped ``tiny-synth`` weights (trained on other procedural scenes: an instant first
   result), or with ``--train`` train the ``tiny`` model on all but the last ``--held-out`` scenes
   (curriculum stages 1-2-3; ``OUT/train/model.safetensors`` is reused once trained), or ``--checkpoint``;
3. score it against ground truth and the forward-warp baseline on the held-out scenes
   (``OUT/results.md``/``.json``, comparison pictures in ``OUT/examples``);
4. reconstruct the first held-out scene from its two outer panoramas, written as a user input folder
   (``OUT/input``), and write the novel middle view (RGB + depth), a comparison picture
   (ground truth / CylinderSplat / baseline), a fly-through GIF and the Gaussians as a PLY.

``--room`` instead renders the built-in Gaussian room (renderer smoke test, seconds).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from ..utils.atomic import atomic_write_text, output_set, written_at_once
from ..utils.jsonfile import json_text
from ._arguments import device, frame_count, model_resolution, positive_float, positive_int

DEFAULT_STEPS = "400,100,100"


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "demo",
        help="the main job: synthetic data -> shipped (or --train: your own) tiny model -> reconstruct a "
             "held-out scene, vs a baseline",
        description="Generate procedural panoramas, take the shipped tiny-synth weights (or, with --train, train the "
        "tiny model for a few minutes on CPU; or --checkpoint), reconstruct a held-out scene from 2 panoramas and "
        "compare the novel view with ground truth and with forward-warping the nearest input panorama. Writes renders, "
        "depth colormaps, a PLY, a fly-through and a metrics table to --out. Needs no download.",
    )
    p.add_argument("--out", type=Path, default=Path("outputs/demo"), help="output folder (default outputs/demo)")
    p.add_argument("--scenes", type=positive_int, default=28, help="procedural scenes to generate (default 28)")
    p.add_argument("--held-out", type=int, default=8,
                   help="last N scenes are not trained on and are scored (default 8)")
    p.add_argument("--resolution", type=model_resolution, default=(64, 128), help="panorama HxW (default 64x128)")
    p.add_argument("--steps", default=DEFAULT_STEPS,
                   help=f"training steps of curriculum stages 1 (pixel), 2 (volume) and 3 (joint); 0 skips a stage "
                   f"(default {DEFAULT_STEPS})")
    p.add_argument("--lr", type=positive_float, default=2e-3,
                   help="peak learning rate of the short CPU schedule (default 2e-3)")
    p.add_argument("--checkpoint", help="use these weights (a .safetensors file, a run folder or a shipped model name)")
    p.add_argument("--train", action="store_true",
                   help="train the tiny model on the demo's scenes (a few minutes on CPU) instead of using the shipped "
                   "weights; a later --train run reuses OUT/train/model.safetensors")
    p.add_argument("--retrain", action="store_true", help="train anew even if OUT/train/model.safetensors exists")
    p.add_argument("--frames", type=frame_count, default=16, help="fly-through frames, 0 = none (default 16)")
    p.add_argument("--device", type=device, default="auto",
                   help="auto (CUDA when available), cpu, cuda[:N] (default auto)")
    p.add_argument("--room", action="store_true", help="only render the built-in Gaussian room (renderer smoke test)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.room:
        return render_room(args)
    if args.held_out < 1 or args.scenes - args.held_out < 1:
        raise ValueError(f"need at least one training and one held-out scene (--scenes {args.scenes}, "
                         f"--held-out {args.held_out})")
    args.steps = _parse_steps(args.steps)  # a bad --steps fails before any work, --train or not
    _check_resolution(args.resolution)
    start = time.perf_counter()
    args.out.mkdir(parents=True, exist_ok=True)
    data = generate_data(args)
    checkpoint = train_or_reuse(args, data)
    # Scores, pictures, PLY and fly-through replace an earlier demo's only when all of them are written.
    planned = [args.out / name for name in ("results.md", "results.json", "novel_view_rgb.png", "comparison.png",
                                            "gaussians.ply")] + ([args.out / "flythrough.gif"] if args.frames else [])
    with output_set(args.out, planned=planned):
        results = score_held_out(args, data, checkpoint)
        reconstruct_held_out(args, data, checkpoint)
    print(results)
    print(f"demo finished in {time.perf_counter() - start:.0f} s; everything is in {args.out}/ "
          "(comparison.png, novel_view_*.png, flythrough.gif, gaussians.ply, results.md)")
    return 0


def _check_resolution(size: tuple[int, int]) -> None:
    """The tiny model (trained here, or shipped) needs a height divisible by its token stride: said before the
    scenes are generated, with the nearest sizes that work."""
    from ..training import load_config

    stride = load_config("tiny").model.backbone.token_stride
    if size[0] % stride:
        low = max(stride, size[0] // stride * stride)
        raise ValueError(f"--resolution {size[0]}x{size[1]}: the tiny model needs a height divisible by {stride}, "
                         f"e.g. {low}x{2 * low} or {low + stride}x{2 * (low + stride)}")


def _parse_steps(text: str) -> list[int]:
    try:
        steps = [int(s) for s in text.split(",")]
    except ValueError:
        raise ValueError(f"--steps must be three integers like {DEFAULT_STEPS}, got {text!r}") from None
    if len(steps) != 3 or min(steps) < 0:
        raise ValueError(f"--steps must be three non-negative integers (stages 1, 2, 3), got {text!r}")
    return steps


def _scene_ids(args) -> tuple[list[str], list[str]]:
    from ..data.synth import scene_id

    ids = [scene_id(i) for i in range(args.scenes)]
    return ids[: args.scenes - args.held_out], ids[args.scenes - args.held_out:]


def generate_data(args) -> Path:
    from ..data.synth import profile_config, write_synthetic_dataset

    # flush: a log file (`> log`) sees each step's line when it starts, not when the buffer fills
    print(f"[1/4] procedural panoramas: {args.scenes} scenes x 3 frames at {args.resolution[0]}x{args.resolution[1]}",
          flush=True)
    root = args.out / "data"
    # Baselines 1-2 m between the outer frames; the target is off their line and occluders stand near the
    # path (the "occlusion" profile), so part of every target is hidden from both inputs: only the volume
    # branch can complete it.
    write_synthetic_dataset(root, args.scenes, args.resolution, profile_config("occlusion"), seed=0)
    return root


def train_or_reuse(args, data: Path) -> Path:
    """The weights file the demo scores: ``--checkpoint``, the shipped model, or its own training run."""
    from ..model.pretrained import DEFAULT_PRETRAINED, PRETRAINED, resolve_weights
    from ..training import Trainer, load_config
    from ..training.resume import has_checkpoint, remove_run_outputs, unresumable_run

    if args.checkpoint:
        weights = resolve_weights(args.checkpoint)  # missing, a pickle, ...: one line, before any work
        print(f"[2/4] using the weights {weights}")
        return weights
    run_dir = args.out / "train"
    weights = run_dir / "model.safetensors"
    if not (args.train or args.retrain):
        shipped = resolve_weights(DEFAULT_PRETRAINED)  # missing from a broken installation: one line, before any work
        print(f"[2/4] using the shipped {DEFAULT_PRETRAINED} weights ({PRETRAINED[DEFAULT_PRETRAINED][1]}; "
              "--train trains your own on these scenes in a few minutes)")
        return shipped
    if weights.is_file() and not args.retrain:
        print(f"[2/4] reusing {weights} (from an earlier --train run; --retrain to train again)")
        return weights
    steps = args.steps
    stages = [s for s, n in zip((1, 2, 3), steps) if n > 0]
    if not stages:
        raise ValueError("--steps 0,0,0 trains nothing; give --checkpoint instead")
    train_ids, _ = _scene_ids(args)
    config = load_config("tiny", changes={
        "data.root": data, "output_dir": run_dir, "data.resolution": list(args.resolution),
        "data.options": {"scenes": train_ids}, "train.stages": stages,
        "train.steps_per_stage": [n for n in steps if n > 0],
        "train.lr": args.lr, "train.warmup_steps": 10, "train.device": str(args.device), "train.checkpoint_every": 100,
        "train.image_every": 50,
    })
    print(f"[2/4] training the tiny model on {len(train_ids)} scenes: stages {stages}, steps {steps} "
          f"(a few minutes on CPU; logs and image grids in {run_dir})", flush=True)
    if has_checkpoint(run_dir) and not args.retrain:
        trainer = Trainer(config, resume=run_dir)  # a killed demo continues where it stopped
    else:
        if unresumable_run(run_dir) and not args.retrain:
            print(f"  {run_dir} holds a training run that stopped before its first checkpoint: starting it over")
        remove_run_outputs(run_dir)  # no log lines or pictures of another run beside this one's
        trainer = Trainer(config)
    summary = trainer.fit()
    return Path(summary["weights"])


def score_held_out(args, data: Path, checkpoint: Path) -> str:
    from ..data import SyntheticDataset
    from ..evaluation import FILLS, evaluate, fill_methods, forward_warp_method, model_method, results_to_markdown
    from ..metrics import DepthRange
    from ..model import load_model

    _, held_out = _scene_ids(args)
    print(f"[3/4] scoring {len(held_out)} held-out scenes (2 panoramas in, the middle one predicted)", flush=True)
    dataset = SyntheticDataset(data, views="two_view", scenes=held_out)
    model = load_model(checkpoint, map_location=args.device)
    methods = [model_method(model, "CylinderSplat (tiny)", device=args.device)]
    if model.mode == "both":  # the same weights with the pixel branch alone, on black and with trivial fills:
        # what the volume branch adds, and what a hole fill alone would give
        pixel_only = load_model(checkpoint, map_location=args.device).set_mode("pixel")
        methods += fill_methods(model_method(pixel_only, "its pixel branch alone", device=args.device), FILLS)
    result = evaluate(dataset, methods + fill_methods(forward_warp_method(), FILLS),
                      example_dir=args.out / "examples", num_pictures=len(held_out),
                      depth_range=DepthRange(0.05, 1000.0))
    results = {f"Held-out synthetic scenes — two_view ({result.num_examples} scenes, "
               f"{args.resolution[0]}x{args.resolution[1]})":
               {name: dict(m) for name, m in result.means.items()}}
    table = results_to_markdown(results, title="Demo: novel views of unseen scenes", backgrounds=result.backgrounds)
    atomic_write_text(args.out / "results.md", table)
    atomic_write_text(args.out / "results.json", json_text({"means": results, "views": result.rows,
                                                            "backgrounds": result.backgrounds}))
    return table


def reconstruct_held_out(args, data: Path, checkpoint: Path) -> None:
    from PIL import Image

    from ..baselines import forward_warp
    from ..data import SyntheticDataset
    from ..evaluation.evaluate import comparison_image
    from ..gaussians import save_ply
    from ..inference import (
        depth_limits,
        load_panorama_folder,
        reconstruct_gaussians,
        render_views,
        write_flythrough,
        write_panorama_folder,
        write_view,
    )
    from ..inference.pipeline import raster_settings
    from ..model import load_model
    from ..utils.atomic import atomic_path

    _, held_out = _scene_ids(args)
    sample = SyntheticDataset(data, views="two_view", scenes=held_out[:1])[0]
    print(f"[4/4] reconstructing held-out scene {held_out[0]} from 2 panoramas "
          f"({sample.metadata.get('baseline', float('nan')):.2f} m apart)", flush=True)
    # The two inputs are written as a user input folder and read back: the same path as `cylindersplat render`.
    with written_at_once():  # read back at once, so not held back with the demo's other outputs
        folder = write_panorama_folder(args.out / "input", sample.context_images, sample.context_poses,
                                       sample.context_priors, names=["left", "right"])
    inputs = load_panorama_folder(folder, args.resolution)
    model = load_model(checkpoint, map_location=args.device)
    gaussians, front = reconstruct_gaussians(model, inputs.images, inputs.depths, inputs.c2w, args.device,
                                             min_opacity=0.005, layers=True)
    h, w = args.resolution
    settings = raster_settings(model.config)  # the model's own drawing (its render_dilation)
    ours = render_views(gaussians, sample.target_poses, h, w, settings=settings, front=front)
    warp = forward_warp(sample.context_images, sample.context_priors, sample.context_poses, sample.target_poses, h, w,
                        background=(0.0, 0.0, 0.0))
    near, far = depth_limits(sample.target_depths)
    write_view(args.out / "novel_view_rgb.png", args.out / "novel_view_depth.png", ours.rgb[0], ours.depth[0],
               ours.alpha[0],
               near, far)
    sheet = comparison_image(sample.target_images[0], sample.target_depths[0], {
        "CylinderSplat": (ours.rgb[0], ours.depth[0], ours.alpha[0]),
        "Forward warp": (warp.rgb[0], warp.depth[0], warp.alpha[0]),
    })
    with atomic_path(args.out / "comparison.png") as tmp:
        Image.fromarray(sheet).resize((sheet.shape[1] * 2, sheet.shape[0] * 2), Image.NEAREST).save(tmp, format="PNG")
    ply = save_ply(gaussians.to("cpu"), args.out / "gaussians.ply")
    print(f"  {len(gaussians):,} Gaussians -> {ply}; comparison (rows: ground truth, CylinderSplat, forward warp; "
          f"RGB | depth) -> {args.out / 'comparison.png'}")
    if args.frames:
        video = write_flythrough(args.out / "flythrough.gif", gaussians, inputs.c2w, h, w, frames=args.frames, fps=8,
                                 near=near, far=far, settings=settings,
                                 front=front)
        print(f"  fly-through -> {video}")


def render_room(args) -> int:
    import torch

    from ..gaussians import save_ply
    from ..geometry import make_c2w
    from ..inference import write_view
    from ..render import render_equirect
    from ..scenes import demo_room

    args.out.mkdir(parents=True, exist_ok=True)
    gaussians = demo_room().to(args.device)
    xs = torch.linspace(-1.0, 1.0, 3)
    poses = torch.stack([make_c2w(translation=torch.tensor([float(x), 0.0, 0.3 * float(x)]))
                         for x in xs]).to(args.device)
    height = 256
    start = time.perf_counter()
    out = render_equirect(gaussians, poses, height, 2 * height, background=(1.0, 1.0, 1.0))
    elapsed = time.perf_counter() - start
    for i in range(len(poses)):
        write_view(args.out / f"room_rgb_{i:02d}.png", args.out / f"room_depth_{i:02d}.png", out.rgb[i], out.depth[i],
                   out.alpha[i])
    ply = save_ply(gaussians.to("cpu"), args.out / "demo_room.ply")
    print(f"rendered {len(gaussians)} Gaussians into {len(poses)} panoramas of {height}x{2 * height} "
          f"in {elapsed:.2f} s on {args.device}\nwrote {args.out}/room_rgb_*.png, room_depth_*.png and {ply}")
    return 0
