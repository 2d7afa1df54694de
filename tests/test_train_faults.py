"""Issue 37, item 2: `train` under Ctrl-C, kill -9, a second run into the same folder, and other stages on resume.

Ctrl-C saves the step at hand and the messages about the run folder agree (the same command points at
``--resume``, ``--resume`` continues there); a run killed before its first checkpoint is started over by the same
command, in one line; one run per folder, whatever the timing; ``--resume RUN --stages 2`` trains stage 2.
"""

from __future__ import annotations

import json
import multiprocessing
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from cylindersplat.cli import main
from cylindersplat.training import Trainer
from cylindersplat.training.run_lock import RunFolderInUse, lock_run_folder

SRC = str(Path(__file__).resolve().parents[1] / "src")
QUIET = ["train.tensorboard=false", "loss.use_lpips=off", "train.image_every=0", "train.progress=false",
         "train.log_every=1", "data.resolution=[32,64]"]


def _argv(data, run, steps="4", *more):
    return ["train", "--data", str(data), "--out", str(run), "--stages", "1", "--steps", steps, *QUIET, *more]


def _steps(run: Path) -> list[int]:
    return [json.loads(line)["step"] for line in (run / "metrics.jsonl").read_text().splitlines()]


def _weights(run: Path) -> dict[str, torch.Tensor]:
    from safetensors.torch import load_file

    return load_file(run / "model.safetensors")


@pytest.mark.parametrize("where,saved_step", [("compute_loss", 2), ("_update", 3)])
def test_ctrl_c_saves_the_step_at_hand_and_resume_continues_exactly(synth_dataset, tmp_path, monkeypatch, capsys,
                                                                    where, saved_step):
    """Ctrl-C in step 3: during the forward pass the last whole step (2) is saved; during the optimizer update the
    update runs whole first (3). Resuming from that checkpoint ends with the weights of an uninterrupted run."""
    data = synth_dataset(2, seed=5)
    assert main(_argv(data, tmp_path / "full")) == 0
    original = getattr(Trainer, where)
    calls = []

    def interrupted_in_step_3(self, *args, **kwargs):
        calls.append(1)
        if len(calls) == 3:
            os.kill(os.getpid(), signal.SIGINT)  # what Ctrl-C does: main's handler raises KeyboardInterrupt
        return original(self, *args, **kwargs)

    monkeypatch.setattr(Trainer, where, interrupted_in_step_3)
    run = tmp_path / "run"
    capsys.readouterr()
    assert main(_argv(data, run)) == 130
    checkpoint = run / "checkpoints" / f"step_{saved_step:07d}"
    assert capsys.readouterr().err.splitlines()[-2:] == [
        f"interrupted after step {saved_step}: saved {checkpoint}; continue with --resume {run}",
        "cylindersplat train: interrupted"]
    assert (run / "checkpoints" / "latest").read_text() == checkpoint.name + "\n"
    monkeypatch.setattr(Trainer, where, original)

    assert main(_argv(data, run)) == 1  # the same command: the run is there, --resume continues it
    assert capsys.readouterr().err.strip() == (
        f"cylindersplat train: error: {run} already holds a training run (checkpoints, metrics.jsonl, config.yaml...);"
        f" continue it with --resume {run}, start anew with --overwrite, or choose another --out")
    assert main(["train", "--resume", str(run)]) == 0
    assert f"resuming {checkpoint} at step {saved_step}" in capsys.readouterr().out
    full, resumed = _weights(tmp_path / "full"), _weights(run)
    for key in full:
        torch.testing.assert_close(resumed[key], full[key], rtol=0, atol=0, msg=key)


def _what_a_killed_run_leaves(run: Path) -> None:
    """kill -9 after two steps, before the first checkpoint: the config, two log lines, a picture."""
    run.mkdir(parents=True)
    (run / "config.yaml").write_text("name: tiny\n")
    (run / "metrics.jsonl").write_text('{"step": 1}\n{"step": 2}\n')
    (run / "images").mkdir()
    (run / "images" / "stage1_0000002.png").write_bytes(b"png")
    (run / "notes.txt").write_text("the user's own")


def test_a_run_killed_before_its_first_checkpoint_starts_over(synth_dataset, tmp_path, capsys):
    run = tmp_path / "run"
    _what_a_killed_run_leaves(run)
    assert main(["train", "--resume", str(run)]) == 1
    assert capsys.readouterr().err.strip() == (
        f"cylindersplat train: error: no training checkpoint at {run}: its run stopped before the first one "
        "(train.checkpoint_every); run the same command without --resume to start it over")
    assert main(_argv(synth_dataset(2, seed=5), run, "2")) == 0
    assert capsys.readouterr().out.splitlines()[0] == (
        f"{run} holds a run that stopped before its first checkpoint (nothing to resume): starting it over")
    assert _steps(run) == [1, 2]  # the new run's log alone
    assert (run / "notes.txt").read_text() == "the user's own"
    assert not (run / "images" / "stage1_0000002.png").exists()


def test_demo_train_says_it_starts_over(tmp_path, monkeypatch, capsys):
    import argparse

    from cylindersplat import training
    from cylindersplat.commands import demo

    run = tmp_path / "train"
    _what_a_killed_run_leaves(run)
    started = []

    class Recorder:
        def __init__(self, config, resume=None):
            started.append(resume)

        def fit(self):
            return {"weights": str(run / "model.safetensors")}

    monkeypatch.setattr(training, "Trainer", Recorder)
    args = argparse.Namespace(checkpoint=None, out=tmp_path, train=True, retrain=False, steps=[2, 0, 0], scenes=2,
                              held_out=1, resolution=(16, 32), lr=1e-3, device="cpu")
    demo.train_or_reuse(args, tmp_path / "data")
    assert f"  {run} holds a training run that stopped before its first checkpoint: starting it over" in \
        capsys.readouterr().out.splitlines()
    assert started == [None] and sorted(p.name for p in run.iterdir()) == ["notes.txt"]


@pytest.mark.slow  # 64 s at load 14 (2 shared cores)
def test_resume_with_other_stages_trains_them(synth_dataset, tmp_path, capsys):
    run = tmp_path / "run"
    assert main(_argv(synth_dataset(2, seed=5), run, "2")) == 0
    capsys.readouterr()
    assert main(["train", "--resume", str(run), "--stages", "2"]) == 0
    out = capsys.readouterr().out
    assert "changed on the command line: train.stages [1] -> [2]" in out and "training finished" in out, out
    assert (run / "model_stage2.safetensors").is_file()
    assert _steps(run) == [1, 2, 3, 4]  # stage 2's steps follow stage 1's
    assert main(["train", "--resume", str(run), "--stages", "2"]) == 0  # now that one is done too
    assert "the run already finished at step 4" in capsys.readouterr().out


def test_a_folder_in_use_is_refused_in_one_line(synth_dataset, tmp_path, capsys):
    run = tmp_path / "run"
    fd = lock_run_folder(run)  # another train holds it
    try:
        assert main(_argv(synth_dataset(2, seed=5), run, "2")) == 1
    finally:
        os.close(fd)
    assert capsys.readouterr().err.strip() == (
        f"cylindersplat train: error: {run} is in use by another `cylindersplat train` (process {os.getpid()}); "
        "wait for it to end, or choose another --out")
    assert sorted(p.name for p in run.iterdir()) == [".train.lock"]  # nothing written


def _take_lock(folder, barrier, results):
    barrier.wait()
    try:
        lock_run_folder(folder)
        results.put("locked")
        time.sleep(1)  # held while the others try
    except RunFolderInUse:
        results.put("refused")


def test_runs_started_at_the_same_instant_get_one_lock(tmp_path):
    context = multiprocessing.get_context("fork")
    barrier, results = context.Barrier(6), context.Queue()
    workers = [context.Process(target=_take_lock, args=(tmp_path / "run", barrier, results)) for _ in range(6)]
    for worker in workers:
        worker.start()
    for worker in workers:
        worker.join(timeout=60)
    assert sorted(results.get(timeout=5) for _ in workers) == ["locked"] + ["refused"] * 5


def test_ranks_of_one_torchrun_job_share_the_lock_and_other_jobs_are_refused(tmp_path, monkeypatch):
    job = {"WORLD_SIZE": "2", "TORCHELASTIC_RUN_ID": "none", "MASTER_ADDR": "127.0.0.1", "MASTER_PORT": "29500"}
    for name, value in job.items():
        monkeypatch.setenv(name, value)
    fd = lock_run_folder(tmp_path / "run")  # rank 0 takes it
    try:
        assert fd is not None and lock_run_folder(tmp_path / "run") is None  # rank 1 of the same job goes on
        monkeypatch.setenv("MASTER_PORT", "29501")  # another job, with the same default rendezvous id
        with pytest.raises(RunFolderInUse, match=f"process {os.getpid()}"):
            lock_run_folder(tmp_path / "run")
        monkeypatch.setenv("WORLD_SIZE", "1")  # a plain run
        with pytest.raises(RunFolderInUse):
            lock_run_folder(tmp_path / "run")
    finally:
        os.close(fd)


@pytest.mark.slow
def test_two_trains_into_one_folder_at_once_one_runs(synth_dataset, tmp_path):
    run = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": SRC, "OMP_NUM_THREADS": "1"}
    argv = [sys.executable, "-m", "cylindersplat", *_argv(synth_dataset(2, seed=5), run, "3")]
    procs = [subprocess.Popen(argv, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    results = sorted((p.wait(timeout=600), p.stderr.read().strip().splitlines()[-1:]) for p in procs)
    assert [code for code, _ in results] == [0, 1], results
    assert results[1][1][0].startswith(f"cylindersplat train: error: {run} is in use by another `cylindersplat "
                                       "train` (process "), results
    assert _steps(run) == [1, 2, 3]


@pytest.mark.slow
def test_kill_9_before_the_first_checkpoint_then_the_same_command(synth_dataset, tmp_path):
    run = tmp_path / "run"
    env = {**os.environ, "PYTHONPATH": SRC, "OMP_NUM_THREADS": "1"}
    argv = [sys.executable, "-m", "cylindersplat", *_argv(synth_dataset(2, seed=5), run, "200")]
    proc = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while not ((run / "metrics.jsonl").is_file() and (run / "metrics.jsonl").read_text().count("\n") >= 2):
        assert time.monotonic() < deadline and proc.poll() is None
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    again = subprocess.run(argv[:argv.index("200")] + ["2"] + argv[argv.index("200") + 1:], env=env,
                           capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    assert again.stdout.splitlines()[0] == (
        f"{run} holds a run that stopped before its first checkpoint (nothing to resume): starting it over")
    assert _steps(run) == [1, 2]


@pytest.mark.slow
def test_export_with_stdout_closed_writes_its_file_and_says_nothing(panorama_folder, tiny_checkpoint, tmp_path):
    """``export ... >&-``: Python has no sys.stdout; the command still works (and its errors still reach stderr)."""
    env = {**os.environ, "PYTHONPATH": SRC, "OMP_NUM_THREADS": "1"}
    out = tmp_path / "g.ply"
    argv = [sys.executable, "-m", "cylindersplat", "export", "--input", str(panorama_folder[0]), "--checkpoint",
            str(tiny_checkpoint), "--resolution", "16x32", "--device", "cpu", "--out", str(out)]
    closed = subprocess.run(argv, stdout=None, stderr=subprocess.PIPE, text=True, env=env, timeout=300,
                            preexec_fn=lambda: os.close(1))
    assert closed.returncode == 0 and closed.stderr == "" and out.is_file(), closed.stderr
    argv[argv.index("--input") + 1] = "/nonexistent"
    closed = subprocess.run(argv, stdout=None, stderr=subprocess.PIPE, text=True, env=env, timeout=300,
                            preexec_fn=lambda: os.close(1))
    assert closed.returncode == 1 and closed.stderr.strip().splitlines() == [
        "cylindersplat export: error: input folder not found: /nonexistent"], closed.stderr
