"""``cylindersplat train``: the three-stage curriculum from a YAML preset plus overrides."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._arguments import check_output, count_list, positive_int, stage_list


def run(args: argparse.Namespace) -> int:
    from ..training import load_config

    # The options are typed changes applied after the KEY=VALUE overrides (an option wins over a KEY=VALUE of the
    # same setting); values are never re-read as YAML (`--data yes` is the folder "yes", not true).
    overrides, resume = list(args.overrides), None
    changes: dict = {}
    if args.data:
        changes["data.root"] = str(args.data)
    if args.stages:
        changes["train.stages"] = [int(s) for s in args.stages.split(",")]
    if args.steps:
        changes["train.steps_per_stage"] = [int(s) for s in args.steps.split(",")]
    if args.init:
        changes["train.init"] = str(args.init)
    if args.device:
        changes["train.device"] = args.device
    if args.resume is None:
        if args.out:
            changes["output_dir"] = str(args.out)
        config = load_config(args.config or "tiny", overrides, changes)
    else:
        resume = _resume_point(args)
        given = any(o.partition("=")[0].strip() == "train.steps_per_stage" for o in overrides)
        if args.stages and not args.steps and not given:  # the run's own steps of the stages asked for
            changes["train.steps_per_stage"] = _steps_of(resume, args.stages)
        # The run keeps writing into its own folder (wherever it lies now) unless --out forks it elsewhere.
        changes["output_dir"] = str(args.out or resume.run_folder)
        config = resume.config(overrides, changes)
    if args.print_config:
        import yaml

        from ..training import config_as_dict

        print(yaml.safe_dump(config_as_dict(config), sort_keys=False))
        return 0
    from ..training.run_lock import run_folder_lock

    check_output(config.output_dir, folder=True)
    with run_folder_lock(config.output_dir):  # before anything is written: one run per folder
        return _train(args, config, resume)


def _train(args: argparse.Namespace, config, resume) -> int:
    from ..training import Trainer

    if resume is None:
        _refuse_to_trample(Path(config.output_dir), args.overwrite)
    else:
        if resume.finished(config):
            print(f"{resume.run_folder}: the run already finished at step {resume.global_step}; nothing to train "
                  "(to train longer, give the last stage more steps, e.g. train.steps_per_stage=[...])")
            return 0
        _say_resume(resume, config)
    trainer = Trainer(config, resume=args.resume)
    summary = trainer.fit(max_steps=args.max_steps)
    state = ("finished" if summary["finished"]
             else f"stopped at step {summary['global_step']} (resume with --resume {config.output_dir})")
    print(f"training {state}; mean step {summary['mean_step_time']:.2f} s; run folder {config.output_dir}")
    if summary["finished"]:
        print(f"weights: {summary['weights']}")
    return 0


def _resume_point(args: argparse.Namespace):
    """The checkpoint ``--resume`` names, with its saved config; ``--config`` may only name the run's own preset."""
    from ..training.config import load_config
    from ..training.resume import find_resume_point

    resume = find_resume_point(args.resume)
    if args.config is not None:
        preset_name = load_config(args.config).name
        if preset_name != resume.saved.get("name"):
            raise ValueError(f"--resume continues {resume.run_folder} with its own config (preset "
                             f"{resume.saved.get('name')!r}), not --config {args.config}; leave out --config and "
                             "change single settings with KEY=VALUE (e.g. train.steps_per_stage=[8])")
    return resume


def _steps_of(resume, stages: str) -> list[int]:
    """``train.steps_per_stage`` for ``stages`` from the run's own schedule (one entry per stage there)."""
    steps = list(resume.saved.get("train", {}).get("steps_per_stage", []))
    if len(steps) == len(resume.saved_stages) > 1:
        by_stage = dict(zip(resume.saved_stages, steps))
        steps = [by_stage.get(int(s), steps[-1]) for s in stages.split(",")]
    return [int(s) for s in steps]


def _say_resume(resume, config) -> None:
    """One line: where the run continues, and every setting the command line changed (e.g. the schedule)."""
    from ..training.resume import config_changes

    changes = [c for c in config_changes(resume.saved, config) if not c.startswith("output_dir ")]
    said = f"; changed on the command line: {'; '.join(changes)}" if changes else " (unchanged)"
    print(f"resuming {resume.checkpoint} at step {resume.global_step} with the run's own config{said}", flush=True)


def _refuse_to_trample(folder: Path, overwrite: bool) -> None:
    """A folder that holds a run is resumed (``--resume``) or replaced on request, never mixed. A run that stopped
    before its first checkpoint has nothing to resume: it starts over, said in one line."""
    from ..training.resume import remove_run_outputs, run_outputs, unresumable_run

    present = run_outputs(folder)
    if not present:
        return
    if unresumable_run(folder) and not overwrite:
        print(f"{folder} holds a run that stopped before its first checkpoint (nothing to resume): starting it over")
        overwrite = True
    if not overwrite:
        raise ValueError(f"{folder} already holds a training run ({', '.join(present[:3])}...); continue it with "
                         f"--resume {folder}, start anew with --overwrite, or choose another --out")
    remove_run_outputs(folder)


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        "train",
        help="train the model (three-stage curriculum, resumable)",
        description=(
            "Train CylinderSplat. A preset (--config, from cylindersplat/configs/ or a YAML path) "
            "is read, then every KEY=VALUE override (e.g. train.lr=3e-4 model.volume.init=isolated "
            "data.resolution=[128,256]) is applied; unknown keys are errors. Stages: 1 pixel branch, "
            "2 volume branch (pixel frozen), 3 joint. Checkpoints (safetensors weights + training "
            "state) go to OUTPUT_DIR/checkpoints; --resume RUN continues a killed run exactly, with the "
            "config it was started with. "
            "Several GPUs: torchrun --nproc_per_node=N -m cylindersplat train ... (see docs/training.md)."
        ),
    )
    parser.add_argument("overrides", nargs="*", metavar="KEY=VALUE", help="config overrides (YAML values)")
    parser.add_argument("--config", help="preset name (tiny, base, paper, finetune_360loc) or YAML path (default tiny; "
                        "with --resume, the run's own config)")
    parser.add_argument("--data", help="dataset folder (same as data.root=...)")
    parser.add_argument("--out", help="run folder for checkpoints, logs, weights (same as output_dir=...)")
    parser.add_argument("--stages", type=stage_list,
                        help="comma list of curriculum stages to run, e.g. 1,2,3 or 3 (same as train.stages)")
    parser.add_argument("--steps", type=count_list,
                        help="optimizer steps per stage: one number or a comma list per stage")
    parser.add_argument("--init", help="model.safetensors to start from (fine-tuning)")
    parser.add_argument("--resume", metavar="RUN",
                        help="run folder or checkpoint to continue, with the run's own config and schedule; "
                             "KEY=VALUE settings given with it change that config (and are reported)")
    parser.add_argument("--overwrite", action="store_true",
                        help="replace the run already in the output folder (its checkpoints, logs and weights)")
    parser.add_argument("--max-steps", type=positive_int,
                        help="stop (with a checkpoint) after this many steps of this call")
    parser.add_argument("--device", help="cpu, cuda, cuda:1 ... (default: cuda when available)")
    parser.add_argument("--print-config", action="store_true", help="print the resolved config as YAML and exit")
    parser.set_defaults(func=run)
