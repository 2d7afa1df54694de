"""`train --resume RUN` continues with the run's own config and schedule; progress and notices without a terminal."""

from __future__ import annotations

import io
import sys

import pytest

from cylindersplat.cli import main
from cylindersplat.training.logger import MetricLogger
from cylindersplat.utils import notices
from cylindersplat.utils.progress import Progress

QUIET = ["train.tensorboard=false", "loss.use_lpips=off", "train.image_every=0", "train.progress=false"]


def _train(argv, capsys):
    code = main(["train", *argv])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.mark.slow  # 75 s at load 12 (2 shared cores)
def test_resume_uses_the_runs_config_and_schedule(synth_dataset, tmp_path, capsys):
    run = tmp_path / "run"
    code, out, err = _train(["--data", str(synth_dataset(2, seed=5)), "--out", str(run), "--stages", "1", "--steps",
                             "3",
                             "--max-steps", "1", *QUIET], capsys)
    assert code == 0 and f"resume with --resume {run}" in out
    # No --data, no --out, no --steps: all from the run (before: "data.root is not set", or the preset's schedule).
    code, out, err = _train(["--resume", str(run), "--max-steps", "1"], capsys)
    assert code == 0, err
    assert "at step 1 with the run's own config (unchanged)" in out and "stopped at step 2" in out
    # Changing the schedule on resume is explicit and said.
    code, out, err = _train(["--resume", str(run), "train.steps_per_stage=[4]"], capsys)
    assert code == 0, err
    assert "changed on the command line: train.steps_per_stage [3] -> [4]" in out and "training finished" in out
    weights = (run / "model.safetensors").read_bytes()
    # A finished run stays finished: nothing trained, nothing overwritten.
    code, out, err = _train(["--resume", str(run)], capsys)
    assert code == 0 and "already finished at step 4; nothing to train" in out
    assert (run / "model.safetensors").read_bytes() == weights
    assert (run / "checkpoints" / "latest").read_text().strip() == "step_0000004"


def test_resume_refuses_another_preset(synth_dataset, tmp_path, capsys):
    run = tmp_path / "run"
    assert _train(["--data", str(synth_dataset(2, seed=5)), "--out", str(run), "--stages", "1", "--steps", "2",
                   "--max-steps", "1", *QUIET], capsys)[0] == 0
    code, out, err = _train(["--resume", str(run), "--config", "paper", "--max-steps", "1"], capsys)
    assert code == 1 and "leave out --config" in err and len(err.strip().splitlines()) == 1
    code, out, err = _train(["--resume", str(run), "--config", "tiny", "--max-steps", "1"], capsys)  # its own: fine
    assert code == 0 and "at step 1 with the run's own config (unchanged)" in out and "training finished" in out


def test_training_prints_progress_lines_without_a_terminal(synth_dataset, tmp_path, capsys):
    quiet = [q for q in QUIET if not q.startswith("train.progress")]
    code, out, err = _train(["--data", str(synth_dataset(2, seed=5)), "--out", str(tmp_path / "run"), "--stages", "1",
                             "--steps", "2", *quiet], capsys)
    assert code == 0
    lines = [line for line in err.splitlines() if line.startswith("stage 1:")]
    assert [line.split(" (")[0] for line in lines] == ["stage 1: 1/2 steps", "stage 1: 2/2 steps"], err
    assert "loss " in lines[-1] and "\r" not in err


def test_progress_lines_follow_the_marks_from_a_resumed_start():
    stream = io.StringIO()  # not a terminal
    bar = Progress(10, "stage 3", "step", initial=4, lines=5, stream=stream)
    for _ in range(6):
        bar.update(1, note="loss 0.5")
    bar.close()
    said = [line.split(" (")[0] for line in stream.getvalue().splitlines()]
    assert said == ["stage 3: 6/10 steps", "stage 3: 8/10 steps", "stage 3: 10/10 steps"]
    silent = io.StringIO()
    Progress(3, "x", "step", enabled=False, stream=silent).update(3)
    assert silent.getvalue() == ""


def test_missing_tensorboard_is_said_once(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)  # import fails as if not installed
    monkeypatch.setattr(notices, "_said", set())
    with pytest.warns(notices.Notice, match="TensorBoard logs are skipped") as record:
        for name in ("a", "b"):
            MetricLogger(tmp_path / name, tensorboard=True).close()
    assert len([w for w in record if "TensorBoard" in str(w.message)]) == 1
    assert MetricLogger(tmp_path / "c", tensorboard=True).backends == ["jsonl"]


def test_cli_prints_warnings_as_one_line_notices(synth_dataset, tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)
    monkeypatch.setattr(notices, "_said", set())
    quiet = [q for q in QUIET if not q.startswith("train.tensorboard")]
    code, out, err = _train(["--data", str(synth_dataset(2, seed=5)), "--out", str(tmp_path / "run"), "--stages", "1",
                             "--steps", "1", *quiet], capsys)
    assert code == 0
    said = [line for line in err.splitlines() if "TensorBoard" in line]
    assert said == [said[0]] and said[0].startswith("cylindersplat train: note: TensorBoard logs are skipped"), err
    assert "warnings.warn" not in err and "UserWarning" not in err
