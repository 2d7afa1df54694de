"""Issue 27, item 5: gradient sync under DDP. Two CPU (gloo) processes under torchrun, one sample each, reach
the weights of one process on the same global batch of two after a few steps."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

from cylindersplat.model import from_config
from cylindersplat.training import load_config

SRC = str(Path(__file__).resolve().parents[1] / "src")
ATOL = 5e-5  # float32 all-reduce vs one batched sum
SETTINGS = ["train.stages=[1]", "train.steps_per_stage=[3]", "train.lr=1e-3", "train.warmup_steps=0",
            "train.progress=false", "train.tensorboard=false", "train.image_every=0", "train.log_every=1",
            "train.checkpoint_every=3", "loss.use_lpips=off", "data.resolution=[32,64]"]


def _train(launcher: list[str], data: Path, out: Path, batch_size: int) -> dict:
    env = {**os.environ, "PYTHONPATH": SRC, "OMP_NUM_THREADS": "1"}
    env.pop("TRITON_INTERPRET", None)
    command = [*launcher, "-m", "cylindersplat", "train", "--data", str(data), "--out", str(out), "--device", "cpu",
               f"data.batch_size={batch_size}", *SETTINGS]
    proc = subprocess.run(command, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return load_file(str(out / "model.safetensors"))


@pytest.mark.slow
def test_two_gloo_processes_reach_the_weights_of_one_on_the_same_global_batch(synth_dataset, tmp_path):
    data = synth_dataset(2, 0)  # two scenes: one global batch of two
    one = _train([sys.executable], data, tmp_path / "one", batch_size=2)
    two = _train([sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2"], data,
                 tmp_path / "two", batch_size=1)
    assert one.keys() == two.keys()
    gap = max(float((one[name] - two[name]).abs().max()) for name in one)
    torch.manual_seed(0)
    start = from_config(load_config("tiny").model).state_dict()  # the training preset's model (its grid, ...)
    moved = max(float((one[name] - start[name]).abs().max()) for name in one)
    assert gap <= ATOL < moved / 10, (gap, moved)  # the same weights, and three steps moved them well beyond that
    # The checkpoints agree too: the same place in the schedule, the same optimiser moments.
    states = [torch.load(tmp_path / run / "checkpoints" / "step_0000003" / "state.pt", weights_only=True)
              for run in ("one", "two")]
    for key in ("global_step", "stage", "stage_step", "skipped_steps", "stages", "scheduler"):
        assert states[0][key] == states[1][key], key
    assert len(states[0]["optimizer"]["state"]) == len(states[1]["optimizer"]["state"]) > 0
    for moments in zip(*(s["optimizer"]["state"].values() for s in states)):
        for key in ("exp_avg", "exp_avg_sq"):
            torch.testing.assert_close(moments[0][key], moments[1][key], atol=ATOL, rtol=1e-4)
