"""A long loop without a terminal says at once that it started (demo --train printed nothing for 150 s: its first
progress line came at a tenth of stage 1)."""

from __future__ import annotations

import io

import pytest

from cylindersplat.cli import main
from cylindersplat.utils.progress import Progress


def test_a_long_loop_says_at_once_that_it_started():
    stream = io.StringIO()  # not a terminal
    Progress(600, "stage 1", "step", lines=10, stream=stream, announce=True)
    Progress(600, "stage 2", "step", initial=120, lines=10, stream=stream, announce=True)
    Progress(600, "quiet", "step", lines=10, stream=stream, announce=True, enabled=False)
    Progress(600, "no announce", "step", lines=10, stream=stream)
    assert stream.getvalue().splitlines() == ["stage 1 started: 600 steps, a line every 60 steps",
                                              "stage 2 resumed at 120/600 steps, a line every 60 steps"]


@pytest.mark.slow  # a real training run: ~50 s on 2 busy cores
def test_training_says_each_stage_started_before_its_first_step(synth_dataset, tmp_path, capsys):
    quiet = ["train.tensorboard=false", "loss.use_lpips=off", "train.image_every=0"]
    assert main(["train", "--data", str(synth_dataset(2, seed=5)), "--out", str(tmp_path / "run"), "--stages", "1",
                 "--steps", "2", *quiet]) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("stage 1")]
    assert lines[0] == "stage 1 started: 2 steps, a line every step"
    assert [line.split(" (")[0] for line in lines[1:]] == ["stage 1: 1/2 steps", "stage 1: 2/2 steps"]
