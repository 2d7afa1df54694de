"""The training loop: three-stage curriculum, AdamW + cosine, checkpoints with exact resume.

Stages (paper Sec. 3.3 / App. "Training and Supervision"): 1 trains the pixel branch and renders
its Gaussians; 2 trains the volume branch with the pixel branch frozen and renders volume Gaussians;
3 trains both and renders the fused set. Each stage gets a fresh AdamW (its trainable parameters
differ) with its own cosine schedule over the stage's steps. ``train.stages`` picks which stages
run, so ``[1, 2, 3]`` is the full curriculum and ``[3]`` the paper's fine-tuning protocol.

Precision: the network forward runs under bf16 autocast on CUDA (``train.amp``); the Gaussians are
cast to fp32 and rasterised, and the loss computed, in fp32. On a CPU everything is fp32.

Non-finite guard: a step whose loss or global gradient norm is NaN/inf is skipped (no optimizer
update, so the weights and AdamW moments stay as they were) with a warning naming its source; the
schedule still advances. ``train.max_nonfinite_steps`` consecutive skips end the run with an error.
"""

from __future__ import annotations

import contextlib
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import torch
import yaml
from torch import Tensor

from .. import interrupt
from ..data import Sample
from ..model import CylinderSplat, load_model, save_model
from ..render import (
    Equirect,
    FrontLayer,
    RasterSettings,
    RenderOutput,
    available_backends,
    render_equirect,
    render_layered,
)
from ..utils.atomic import atomic_write_text
from ..utils.progress import Progress
from .checkpoint import capture_rng, prune_checkpoints, read_state, resolve_checkpoint, restore_rng, save_checkpoint
from .config import ExperimentConfig, config_as_dict
from .data import ResumableBatchSampler, build_dataset, build_loader
from .distributed import cleanup_distributed, init_distributed, unwrap, wrap_ddp
from .logger import MetricLogger
from .losses import LossTerms, RenderLoss
from .objective import Objective
from .resume import curriculum_position
from .schedule import cosine_schedule

__all__ = ["Trainer", "batch_to_device", "select_device"]

GAUSSIAN_FIELDS = ("means", "scales", "rotations", "opacities", "sh")


def select_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def _total_grad_norm(params: list[Tensor]) -> Tensor:
    """Global L2 norm of the parameters' grads (without clipping, so NaN is not spread first)."""
    grads = [p.grad for p in params if p.grad is not None]
    if not grads:
        return torch.zeros(())
    if hasattr(torch.nn.utils, "get_total_norm"):  # torch >= 2.6
        return torch.nn.utils.get_total_norm(grads)
    return torch.linalg.vector_norm(torch.stack([torch.linalg.vector_norm(g).to(grads[0].device) for g in grads]))


def _clip_grads(params: list[Tensor], max_norm: float, total_norm: Tensor) -> None:
    """Same scaling as ``clip_grad_norm_``, reusing the norm already computed."""
    if hasattr(torch.nn.utils, "clip_grads_with_norm_"):  # torch >= 2.6
        torch.nn.utils.clip_grads_with_norm_(params, max_norm, total_norm)
        return
    coef = (max_norm / (total_norm + 1e-6)).clamp(max=1.0)
    for p in params:
        if p.grad is not None:
            p.grad.mul_(coef.to(p.grad.device))


def batch_to_device(batch: Sample, device: torch.device) -> Sample:
    """Move a collated (batched) Sample. ``Sample.to`` re-validates unbatched shapes, so not that."""
    moved = object.__new__(Sample)
    moved.__dict__.update({k: v.to(device) if isinstance(v, Tensor) else v for k, v in batch.__dict__.items()})
    return moved


class Trainer:
    """``Trainer(cfg).fit()`` runs the configured curriculum; ``resume=`` continues a checkpoint.

    Args:
        config: the experiment.
        dataset: a ready dataset (else built from ``config.data``).
        resume: checkpoint folder / run folder to continue from, or None.
    """

    def __init__(self, config: ExperimentConfig, dataset=None, resume: str | Path | None = None) -> None:
        self.config = config
        tcfg = config.train
        if tcfg.render_backend != "auto" and tcfg.render_backend not in available_backends():  # fail before any work
            raise ValueError(
                f"train.render_backend={tcfg.render_backend!r} is not available here; "
                f"choose 'auto' or one of {available_backends()}"
            )
        self.dist, self.device = init_distributed(select_device(tcfg.device))
        if tcfg.render_backend == "triton" and self.device.type != "cuda" and os.environ.get("TRITON_INTERPRET") != "1":
            raise ValueError(f"train.render_backend=triton needs a CUDA GPU, but training runs on {self.device.type}; "
                             "use train.render_backend=auto (or torch), or train.device=cuda")
        torch.manual_seed(tcfg.seed + self.dist.rank)
        self.output_dir = Path(config.output_dir)
        self.model = CylinderSplat(config.model).to(self.device)
        self.loss_fn = RenderLoss(config.loss, self.device)
        self.objective = Objective(config.loss, self.loss_fn, config.train.stages)
        self.dataset = dataset if dataset is not None else build_dataset(config.data, config.loss)
        if len(self.dataset) == 0:
            raise ValueError("the training dataset is empty")
        self.use_bf16 = self._autocast_enabled()

        # Curriculum position: index into train.stages, optimizer steps done in that stage, total.
        self.stage_index = 0
        self.stage_step = 0
        self.global_step = 0
        self.optimizer: torch.optim.Optimizer | None = None
        self.scheduler = None
        self._pending_optim_state: dict[str, Any] | None = None
        # Non-finite guard: skipped steps in this run (total, and the current streak).
        self.skipped_steps = 0
        self.consecutive_skips = 0
        self._gaussian_grad_ok: dict[str, Tensor] = {}  # filled by backward hooks, read only on a bad step
        self._saved_step: int | None = None  # global step of the last checkpoint written or resumed from
        self._rng_after_step: dict[str, Any] | None = None  # RNG states after the last whole step (Ctrl-C's checkpoint)
        if resume is not None:
            self._load(resolve_checkpoint(resume))
        elif tcfg.init:
            self.model.load_state_dict(load_model(tcfg.init, map_location=self.device).state_dict())
        self._last_render = None
        self.logger = MetricLogger(self.output_dir, tcfg.tensorboard, enabled=self.dist.is_main)

    # -- setup --------------------------------------------------------------------------------
    def _autocast_enabled(self) -> bool:
        amp = self.config.train.amp
        if amp == "off":
            return False
        if self.device.type != "cuda":
            if amp == "bf16":
                warnings.warn("train.amp=bf16 is only used on CUDA; running fp32 on the CPU", stacklevel=3)
            return False
        return True

    @property
    def stage(self) -> int:
        return self.config.train.stages[self.stage_index]

    def batches_per_epoch(self) -> int:
        return max(1, len(self.dataset) // (self.config.data.batch_size * self.dist.world_size))

    def stage_steps(self, stage: int | None = None) -> int:
        return self.config.steps_for(self.stage if stage is None else stage, self.batches_per_epoch())

    def _begin_stage(self) -> None:
        """Set the model's branch mode/freezing and a fresh optimizer + schedule for this stage."""
        tcfg = self.config.train
        self.model.configure_stage(self.stage, tcfg.stage2_render)
        self.train_model = wrap_ddp(self.model, self.dist, self.device)
        volume = {id(p) for p in self.model.branch_parameters("volume")}
        groups = [
            {"params": [p for p in self.model.parameters() if p.requires_grad and id(p) not in volume], "lr": tcfg.lr},
            {"params": [p for p in self.model.parameters() if p.requires_grad and id(p) in volume],
             "lr": tcfg.lr * tcfg.volume_lr_scale},
        ]
        groups = [g for g in groups if g["params"]]  # stage 1 trains no volume parameters, stage 2 no pixel ones
        if tcfg.volume_lr_scale == 1.0:  # one group, as checkpoints of earlier versions have
            groups = [{"params": [p for g in groups for p in g["params"]], "lr": tcfg.lr}]
        self.optimizer = torch.optim.AdamW(groups, lr=tcfg.lr, betas=tuple(tcfg.betas), weight_decay=tcfg.weight_decay)
        self.scheduler = cosine_schedule(self.optimizer, self.stage_steps(), tcfg.warmup_steps, tcfg.min_lr_ratio)
        if self._pending_optim_state is not None:
            self.optimizer.load_state_dict(self._pending_optim_state["optimizer"])
            self.scheduler.load_state_dict(self._pending_optim_state["scheduler"])
            self._pending_optim_state = None

    # -- one step -----------------------------------------------------------------------------
    def compute_loss(self, batch: Sample) -> LossTerms:
        """Forward the contexts, render the targets, score them (:class:`~.objective.Objective`). Batch tensors
        ``(B, V|T, ...)``."""
        autocast = (
            torch.autocast("cuda", dtype=torch.bfloat16) if self.use_bf16 else contextlib.nullcontext()
        )
        with autocast:
            out = self.train_model(batch.context_images, batch.context_priors, batch.context_poses)
        gaussians = out.gaussians.to(torch.float32)
        self._watch_gaussian_grads(gaussians)
        with torch.autocast(self.device.type, enabled=False):
            front = unwrap(self.train_model).front_layer(out) if self.config.train.render_drawing == "model" else None
            render = self._render(gaussians, batch, front)
            self._last_render = (render, batch)
            volume_render = None
            if out.pixel_gaussians is not None and out.volume_gaussians is not None:  # a fused set: its volume part

                def volume_render():
                    return self._render(out.volume_gaussians.to(torch.float32), batch)

            return self.objective(batch, render, self.stage, volume_render)

    def _render(self, gaussians, batch: Sample, front: FrontLayer | None = None):
        """fp32 render of the batch's target views: one depth-sorted pass, or with ``front`` the leading Gaussians
        as a layer over the rest (``train.render_drawing=model``: the drawing inference uses)."""
        height, width = batch.target_images.shape[-2:]
        poses, background = batch.target_poses.float(), tuple(self.config.train.background)
        backend, settings = self.config.train.render_backend, RasterSettings(dilation=self.model.config.render_dilation)
        if front is None:
            return render_equirect(gaussians, poses, height, width, background=background, backend=backend,
                                   settings=settings)
        camera = Equirect(height, width)
        parts = []
        for b in range(len(poses)):  # render_layered takes one scene's Gaussians
            scene = gaussians.batch(b)
            parts.append(render_layered(scene[:front.count], scene[front.count:], poses[b], camera,
                                        background=background, backend=backend, settings=settings, cover=front.cover,
                                        blend=front.blend))
        return RenderOutput(*(torch.stack([getattr(p, k) for p in parts]) for k in ("rgb", "depth", "alpha")))

    def _watch_gaussian_grads(self, gaussians) -> None:
        """Record per Gaussian tensor whether its grad is finite; a device-side flag, no sync."""
        self._gaussian_grad_ok = {}
        for name in GAUSSIAN_FIELDS:
            tensor = getattr(gaussians, name)
            if tensor.requires_grad:
                def hook(grad: Tensor, name: str = name) -> None:
                    self._gaussian_grad_ok[name] = torch.isfinite(grad).all()
                tensor.register_hook(hook)

    def _nonfinite_source(self) -> str:
        """Which rendered Gaussian tensors and (up to 5) parameters got non-finite grads."""
        ok = self._gaussian_grad_ok
        fields = [f"gaussians.{k}" for k in GAUSSIAN_FIELDS if k in ok and not bool(ok[k])]
        params = [
            name for name, p in self.model.named_parameters()
            if p.grad is not None and not bool(torch.isfinite(p.grad).all())
        ]
        shown = params[:5] + ([f"(+{len(params) - 5} more)"] if len(params) > 5 else [])
        return (
            f"gaussian grads: {', '.join(fields) or 'all finite'}; "
            f"parameter grads: {', '.join(shown) or 'all finite'}"
        )

    def train_step(self, batch: Sample) -> dict[str, float]:
        self.model.train()
        terms = self.compute_loss(batch_to_device(batch, self.device))
        self.optimizer.zero_grad(set_to_none=True)
        # Backward even for a NaN loss: under DDP every rank must join the gradient all-reduce.
        terms.total.backward()
        params = [p for group in self.optimizer.param_groups for p in group["params"]]
        grad_norm = _total_grad_norm(params)
        loss_ok = torch.isfinite(terms.total.detach())
        bad = (~(loss_ok & torch.isfinite(grad_norm).to(loss_ok.device))).float()
        if self.dist.enabled:  # the loss is per rank: all ranks must agree on skipping
            torch.distributed.all_reduce(bad, op=torch.distributed.ReduceOp.MAX)
        skip = bool(bad)
        terms.parts["grad_norm"] = float(grad_norm)
        terms.parts["lr"] = self.optimizer.param_groups[0]["lr"]
        terms.parts["skipped"] = float(skip)
        with interrupt.held():  # the update runs whole: a checkpoint after Ctrl-C holds the state of one step
            self._update(skip, params, grad_norm, loss_ok)
        return terms.parts

    def _update(self, skip: bool, params: list[Tensor], grad_norm: Tensor, loss_ok: Tensor) -> None:
        """The optimizer and schedule step (or the skip of a non-finite step) and the step counters."""
        tcfg = self.config.train
        if skip:
            source = self._nonfinite_source()  # before zeroing: it reads the grads
            self.optimizer.zero_grad(set_to_none=True)
            self.skipped_steps += 1
            self.consecutive_skips += 1
            step = self.global_step + 1
            warnings.warn(
                f"step {step} (stage {self.stage}) skipped: loss {'finite' if bool(loss_ok) else 'non-finite'}, "
                f"grad norm {float(grad_norm)}; {source}", RuntimeWarning, stacklevel=3,
            )
            if 0 < tcfg.max_nonfinite_steps < self.consecutive_skips:
                raise RuntimeError(
                    f"training diverged: {self.consecutive_skips} consecutive steps with non-finite loss/gradients "
                    f"(last at step {step}, source {source}); lower train.lr, or try train.render_backend=torch "
                    "to rule out the fast renderer"
                )
            with warnings.catch_warnings():  # the schedule advances on purpose without an optimizer step
                warnings.filterwarnings("ignore", message="Detected call of `lr_scheduler.step\\(\\)` before")
                self.scheduler.step()
        else:
            self.consecutive_skips = 0
            if tcfg.grad_clip > 0:
                _clip_grads(params, tcfg.grad_clip, grad_norm)
            self.optimizer.step()
            self.scheduler.step()
        self.stage_step += 1
        self.global_step += 1

    # -- loop ---------------------------------------------------------------------------------
    def fit(self, max_steps: int | None = None) -> dict[str, Any]:
        """Run the remaining curriculum (or ``max_steps`` more optimizer steps, then checkpoint).

        Returns a summary: per-step losses of this call, mean step time, skipped (non-finite) steps of
        the run, final paths.
        """
        tcfg = self.config.train
        if self.dist.is_main:
            self.output_dir.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.output_dir / "config.yaml",
                              yaml.safe_dump(config_as_dict(self.config), sort_keys=False))
        history: list[dict[str, float]] = []
        step_times: list[float] = []
        budget = max_steps
        self._rng_after_step = capture_rng()
        try:
            while self.stage_index < len(tcfg.stages):
                total = self.stage_steps()
                if self.stage_step >= total:  # resumed from the end-of-stage checkpoint
                    self._pending_optim_state = None
                    self._next_stage()
                    continue
                self._begin_stage()
                todo = total - self.stage_step if budget is None else min(budget, total - self.stage_step)
                sampler = ResumableBatchSampler(
                    len(self.dataset), self.config.data.batch_size, seed=tcfg.seed, stage=self.stage,
                    start_step=self.stage_step, num_steps=todo, rank=self.dist.rank, world_size=self.dist.world_size,
                )
                # A bar on a terminal, ten plain lines per stage in a log file or pipe.
                bar = Progress(total, f"stage {self.stage}", "step", tcfg.progress and self.dist.is_main,
                               initial=self.stage_step, lines=10, announce=True)
                for batch in build_loader(self.dataset, sampler, self.config.data.num_workers):
                    start = time.perf_counter()
                    parts = self.train_step(batch)
                    step_times.append(time.perf_counter() - start)
                    parts["step_time"] = step_times[-1]
                    history.append({"stage": self.stage, **parts})
                    bar.update(1, note=f"loss {parts['total']:.4f}")
                    if self.global_step % tcfg.log_every == 0 or self.stage_step == total or parts["skipped"]:
                        self.logger.log(self.global_step, {f"train/{k}": v for k, v in parts.items()}, stage=self.stage)
                    if tcfg.image_every > 0 and self.global_step % tcfg.image_every == 0:
                        self.log_images()
                    checkpoint_due = tcfg.checkpoint_every > 0 and self.global_step % tcfg.checkpoint_every == 0
                    if checkpoint_due and self.stage_step < total:
                        self.save_checkpoint()
                    self._rng_after_step = capture_rng()
                bar.close()
                if budget is not None:
                    budget -= todo
                if self.stage_step >= total:
                    self.save_checkpoint()
                    if self.dist.is_main:
                        save_model(self.model, self.output_dir / f"model_stage{self.stage}.safetensors")
                    self._next_stage()
                if budget is not None and budget <= 0:
                    if self.stage_step > 0:
                        self.save_checkpoint()
                    break
            finished = self.stage_index >= len(tcfg.stages)
            if finished and self.dist.is_main:
                save_model(self.model, self.output_dir / "model.safetensors")
        except BaseException as exc:
            # Ctrl-C, or what a library made of it (a DataLoader whose workers the same Ctrl-C ended)
            if isinstance(exc, KeyboardInterrupt) or interrupt.received():
                self._save_interrupted()
            raise
        finally:
            self.logger.close()
            cleanup_distributed()
        return {
            "history": history,
            "mean_step_time": sum(step_times) / len(step_times) if step_times else float("nan"),
            "global_step": self.global_step,
            "skipped_steps": self.skipped_steps,
            "finished": self.stage_index >= len(tcfg.stages),
            "weights": str(self.output_dir / "model.safetensors"),
        }

    def log_images(self) -> None:
        """Grid of the last step's first target: rendered | ground truth, RGB over depth."""
        if self._last_render is None or not self.dist.is_main:
            return
        from ..utils.colormap import colorize_depth

        render, batch = self._last_render
        rgb = render.rgb[0, 0].detach().clamp(0, 1).cpu()
        depth = (render.depth[0, 0] / render.alpha[0, 0].clamp_min(1e-4)).detach().cpu()
        target = batch.target_images[0, 0].cpu()
        ref = batch.target_depths[0, 0].cpu() if batch.target_depths is not None else torch.zeros_like(depth)
        valid = ref > 0
        near, far = (float(ref[valid].min()), float(ref[valid].max())) if valid.any() else (None, None)
        top = torch.cat((rgb, target), dim=-1)
        bottom = torch.cat((colorize_depth(depth, near, far), colorize_depth(ref, near, far)), dim=-1)
        self.logger.log_image(self.global_step, f"stage{self.stage}", torch.cat((top, bottom), dim=-2))

    def _next_stage(self) -> None:
        self.stage_index += 1
        self.stage_step = 0
        self.optimizer = self.scheduler = None

    # -- checkpoints --------------------------------------------------------------------------
    def _save_interrupted(self) -> None:
        """Ctrl-C: checkpoint the last whole step (unless one was just written), and say how to continue."""
        if not self.dist.is_main or self.global_step == 0 or self._saved_step == self.global_step:
            return
        if self.stage_index < len(self.config.train.stages) and self.stage_step == 0:
            return  # between stages: the end-of-stage checkpoint is the latest state
        path = self.save_checkpoint(rng=self._rng_after_step)
        print(f"interrupted after step {self.global_step}: saved {path}; continue with --resume {self.output_dir}",
              file=sys.stderr, flush=True)

    def state_dict(self, rng: dict[str, Any] | None = None) -> dict[str, Any]:
        return {
            "global_step": self.global_step,
            "stage_index": self.stage_index,
            "stage": self.stage if self.stage_index < len(self.config.train.stages) else None,
            "stage_step": self.stage_step,
            "skipped_steps": self.skipped_steps,
            "consecutive_skips": self.consecutive_skips,
            "stages": list(self.config.train.stages),
            "optimizer": self.optimizer.state_dict() if self.optimizer is not None else None,
            "scheduler": self.scheduler.state_dict() if self.scheduler is not None else None,
            "rng": rng if rng is not None else capture_rng(),
            "config": config_as_dict(self.config),
        }

    def save_checkpoint(self, rng: dict[str, Any] | None = None) -> Path | None:
        if not self.dist.is_main:
            return None
        folder = self.output_dir / "checkpoints"
        path = save_checkpoint(folder, unwrap(self.model), self.state_dict(rng))
        self._saved_step = self.global_step
        prune_checkpoints(folder, self.config.train.keep_checkpoints)
        return path

    def _load(self, folder: Path) -> None:
        state = read_state(folder)
        weights = load_model(folder / "model.safetensors", map_location=self.device)
        self.model.load_state_dict(weights.state_dict())
        self.global_step = self._saved_step = state["global_step"]
        # Other train.stages than the run's (e.g. --stages 2 after a stage-1 run) continue from these weights
        # with the first stage the run has not finished.
        self.stage_index, self.stage_step = curriculum_position(state["stages"], state["stage_index"],
                                                                state["stage_step"], self.config.train.stages)
        self.skipped_steps = state.get("skipped_steps", 0)  # absent in older checkpoints
        self.consecutive_skips = state.get("consecutive_skips", 0)
        if state["optimizer"] is not None and self.stage_step > 0:
            self._pending_optim_state = {"optimizer": state["optimizer"], "scheduler": state["scheduler"]}
        restore_rng(state["rng"])
