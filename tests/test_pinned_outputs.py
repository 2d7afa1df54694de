"""Byte pins: a seeded forward, a few seeded training steps, one small evaluation and one small study give the
same bytes as the code gave before issue 36's reorganisation (research out of the package, one dataset registry,
the training objective out of the trainer). Any change of behaviour, however small, changes a digest.

The digests were recorded with one torch thread on the project's x86 CPU machine (torch 2.13 CPU build, AVX512);
float sums depend on the torch build and the CPU's vector unit, so elsewhere (another torch version or CPU
capability) the pins skip rather than fail. Record new ones with ``PIN_RECORD=1 pytest tests/test_pinned_outputs.py
-s`` only for a deliberate change.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os

import pytest
import torch

from model_inputs import make_inputs

# where the digests below were recorded: torch version and CPU capability
RECORDED_ON = ("2.13.0+cpu", "AVX512")
PINS = {
    "forward_model_preset_tiny": "11db63ba4e8e6aceb981f3336ce4b247b42259903c6eef93f078f20813a3e783",
    "forward_training_preset_tiny": "0a45e2e3cf409eb3a33bca3ba43551a73e59a66677af892fc30d71e7e347b240",
    "train_steps_released_volume_loss": "d28be6b6d86b5d3f1b7455edb98ea9f4b2d718ff7f1709659537141b7758f735",
    "train_steps_scaled_volume_loss_occluded_weights":
        "bf90e1b51aabba1f6ec660faeac0d023a45d4bcd8eeba3cd5f077a4f5c6e57ff",
    "eval_results_json": "50243c473ffffbcacbbd86c9274464ded7f0de46455fbe30982c4e9d7e9084f7",
    "study_ablation_json": "1af5e3fd5758d0700c95f77d4efb93ca2e14f84f60123d7a09a2f2b4e42c9d30",
}
VOLATILE_KEYS = {"time_s", "train_s", "study_s", "step_time", "data"}  # wall times and tmp paths


@pytest.fixture(autouse=True)
def _reference_renderer(monkeypatch):
    """Every render through the PyTorch reference, the backend ``auto`` chose on the CPU when the pins were
    recorded (fast backends have their own tests against it)."""
    from cylindersplat.render import api

    monkeypatch.setattr(api, "_AUTO_ORDER", {})


def _where() -> tuple[str, str]:
    return torch.__version__, torch.backends.cpu.get_cpu_capability()


def _check(name: str, digest: str) -> None:
    if os.environ.get("PIN_RECORD"):
        print(f'PIN "{name}": "{digest}",')
        return
    if _where() != RECORDED_ON:
        pytest.skip(f"pins recorded with torch {RECORDED_ON[0]} on {RECORDED_ON[1]}; this is {_where()}")
    assert digest == PINS[name], f"{name}: the bytes changed (digest {digest})"


@contextlib.contextmanager
def _one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _tensor_digest(tensors: dict[str, torch.Tensor]) -> str:
    sha = hashlib.sha256()
    for key in sorted(tensors):
        value = tensors[key].detach().cpu().contiguous()
        sha.update(f"{key}:{value.dtype}:{tuple(value.shape)}".encode())
        sha.update(value.numpy().tobytes())
    return sha.hexdigest()


def _without_volatile(value):
    if isinstance(value, dict):
        return {k: _without_volatile(v) for k, v in value.items() if k not in VOLATILE_KEYS}
    if isinstance(value, list):
        return [_without_volatile(v) for v in value]
    return value


def _json_digest(value) -> str:
    return hashlib.sha256(json.dumps(_without_volatile(value), sort_keys=True).encode()).hexdigest()


def _gaussian_tensors(gaussians, prefix: str) -> dict[str, torch.Tensor]:
    fields = ("means", "scales", "rotations", "opacities", "sh")
    return {f"{prefix}.{f}": getattr(gaussians, f) for f in fields} if gaussians is not None else {}


@pytest.mark.parametrize("preset", ["model_preset_tiny", "training_preset_tiny"])
def test_seeded_forward_is_pinned(preset):
    from cylindersplat.model import CylinderSplat, from_config
    from cylindersplat.training import load_config

    with _one_thread(), torch.no_grad():
        torch.manual_seed(0)
        model = from_config("tiny_paper") if preset == "model_preset_tiny" else CylinderSplat(load_config("tiny").model)
        images, depth, c2w = make_inputs(views=2, height=32, width=64)
        out = model.eval()(images, depth, c2w)
    tensors = {**_gaussian_tensors(out.gaussians, "fused"), **_gaussian_tensors(out.pixel_gaussians, "pixel"),
               **_gaussian_tensors(out.volume_gaussians, "volume")}
    _check(f"forward_{preset}", _tensor_digest(tensors))


@pytest.fixture(scope="module")
def occlusion_data(tmp_path_factory):
    from cylindersplat.data.synth import profile_config, write_synthetic_dataset

    root = tmp_path_factory.mktemp("pins") / "data"
    write_synthetic_dataset(root, 3, (32, 64), profile_config("occlusion"), seed=4, progress=False)
    return root


@pytest.mark.slow
@pytest.mark.parametrize("recipe", ["released_volume_loss", "scaled_volume_loss_occluded_weights"])
def test_seeded_training_steps_are_pinned(recipe, occlusion_data, tmp_path):
    """One step of each curriculum stage: the loss parts of every step and the weights after the last."""
    from cylindersplat.training import Trainer, load_config

    extra = {"released_volume_loss": [],  # the tiny preset's own: the released code's stage-3 volume loss
             "scaled_volume_loss_occluded_weights": ["loss.volume_loss=scaled", "loss.occluded_weight=4",
                                                     "loss.pixel_stage_hidden=leave", "loss.depth_reference=prior"]}
    config = load_config("tiny", [
        f"data.root={occlusion_data}", f"output_dir={tmp_path / 'run'}", "data.resolution=[32,64]",
        "train.stages=[1,2,3]", "train.steps_per_stage=[1,1,1]", "train.progress=false", "train.tensorboard=false",
        "loss.use_lpips=off", "train.image_every=0", "train.device=cpu", "train.lr=1e-3", "train.warmup_steps=0",
        *extra[recipe]])
    with _one_thread():
        summary = Trainer(config).fit()
    history = [{k: v for k, v in step.items() if k != "step_time"} for step in summary["history"]]
    assert len(history) == 3 and all(step["skipped"] == 0 for step in history)
    from cylindersplat.model import load_model

    weights = load_model(tmp_path / "run" / "model.safetensors").state_dict()
    digest = hashlib.sha256((_json_digest(history) + _tensor_digest(weights)).encode()).hexdigest()
    _check(f"train_steps_{recipe}", digest)


@pytest.mark.slow
def test_small_evaluation_is_pinned(occlusion_data, tmp_path, tiny_checkpoint):
    from cylindersplat.cli import main

    out = tmp_path / "eval"
    with _one_thread():
        code = main(["eval", "--data", str(occlusion_data), "--checkpoint", str(tiny_checkpoint), "--out", str(out),
                     "--lpips", "off", "--pictures", "0", "--device", "cpu", "--resolution", "32x64",
                     "--protocols", "two_view,n_view"])
    assert code == 0
    _check("eval_results_json", _json_digest(json.loads((out / "results.json").read_text())))


@pytest.mark.slow
def test_small_study_is_pinned(occlusion_data, tmp_path):
    from cylindersplat.study import Schedule, Variant, run_study

    variants = [Variant("full", "both branches"), Variant("pixel_only", "pixel", kind="pixel"),
                Variant("volume_only", "volume", ("model.fusion.strategy=concat", "train.stage2_render=volume"),
                        kind="volume")]
    run_study(occlusion_data, tmp_path / "study", variants, seeds=(0,), schedule=Schedule(1, 1, 1), held_out=1,
              resolution=(32, 64), device="cpu", log=lambda *_: None, fills=("mean",), threads=1)
    report = json.loads((tmp_path / "study" / "ablation.json").read_text())
    _check("study_ablation_json", _json_digest(report))
