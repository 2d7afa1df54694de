"""Issue 27, item 1 (options): config overrides and command options are checked by type and range when
they are parsed, each with one line naming the option (no traceback, nothing written)."""

import pytest

from cylindersplat.cli import main


def _error_line(argv, capsys) -> str:
    """The one stderr line of a refused command (argparse exits 2, the commands return 1)."""
    try:
        code = main(argv)
    except SystemExit as exit:
        code = exit.code
    assert code in (1, 2)
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


@pytest.mark.parametrize("override,message", [
    ("epochs_per_stage=3", "unknown config key 'epochs_per_stage'; did you mean train.epochs_per_stage?"),
    ("train.lrr=1", "unknown config key 'train.lrr'; did you mean train.lr?"),
    ("train.amp=banana", "train.amp must be one of auto, bf16, off; got 'banana'"),
    ("loss.rgb_l1=-1", "loss.rgb_l1 must be >= 0, got -1"),
    ("model.attention.dim=-48", "invalid model config: attention.dim must be >= 1, got -48"),
    ("train.epochs_per_stage=-1", "train.epochs_per_stage must be a number > 0 (or null to use "
                                  "steps_per_stage), got -1"),
    ("train.lr=nan", "train.lr must be a finite number, got 'nan'"),
    ("train.steps_per_stage=[abc]", "train.steps_per_stage must be a list of numbers "
                                    "like [1000, 1000, 1000], got ['abc']"),
    ("data.resolution=[10,1]", "data.resolution must be [H, W] with W == 2H and H >= 8, e.g. [128, 256]; got [10, 1]"),
])
def test_config_overrides_are_checked_when_parsed(tmp_path, capsys, override, message):
    argv = ["train", "--data", str(tmp_path), "--out", str(tmp_path / "run"), "--print-config", override]
    assert _error_line(argv, capsys) == f"cylindersplat train: error: {message}"
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("argv,message", [
    (["train", "--steps", "abc"], "argument --steps: expected a whole number >= 0 or a comma list of them (e.g. 100 or "
                                  "100,200,50), got 'abc'"),
    (["train", "--steps", "-5"], "argument --steps: expected a whole number >= 0 or a comma list of them (e.g. 100 or "
                                 "100,200,50), got '-5'"),
    (["train", "--max-steps", "-1"], "argument --max-steps: expected an integer >= 1, got '-1'"),
    (["train", "--stages", "4"], "argument --stages: expected a comma list of the stages 1, 2, 3 (e.g. 1,2,3 or 3), "
                                 "got '4'"),
    (["eval", "--depth-range", "10", "1"], "argument --depth-range: expected NEAR FAR in metres with 0 <= NEAR < FAR "
                                           "(e.g. 0.05 1000), got 10 1"),
    (["eval", "--depth-range", "nan", "10"], "argument --depth-range: expected NEAR FAR in metres with 0 <= NEAR < FAR "
                                             "(e.g. 0.05 1000), got nan 10"),
    (["eval", "--max-examples", "-1"], "argument --max-examples: expected an integer >= 1, got '-1'"),
    (["eval", "--pictures", "-1"], "argument --pictures: expected an integer >= 0, got '-1'"),
    (["data", "synth", "--out", "x", "--scenes", "-1"], "argument --scenes: expected an integer >= 1, got '-1'"),
    (["data", "synth", "--out", "x", "--outdoor-fraction", "2"], "argument --outdoor-fraction: expected a share in "
                                                                 "[0, 1], got '2'"),
    (["data", "info", "--data", "x", "--occlusion", "-1"], "argument --occlusion: expected an integer >= 0, got '-1'"),
    (["bench", "render", "--num", "-5"], "argument --num: expected an integer >= 1, got '-5'"),
    (["bench", "synth", "--threads", "0"], "argument --threads: expected an integer >= 1, got '0'"),
])
def test_command_options_are_checked_when_parsed(capsys, argv, message):
    command = " ".join(a for a in argv[:2] if not a.startswith("-") and a not in ("x",))
    expected = f"cylindersplat {command}: error: {message} (see cylindersplat {command} --help)"
    assert _error_line(argv, capsys) == expected


def test_triton_rendering_without_cuda_is_refused_before_training(tmp_path, monkeypatch, capsys):
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has CUDA: triton is a valid choice here")
    monkeypatch.delenv("TRITON_INTERPRET", raising=False)
    argv = ["train", "--data", str(tmp_path), "--out", str(tmp_path / "run"), "--device", "cpu",
            "train.render_backend=triton"]
    monkeypatch.setattr("cylindersplat.render.api.available_backends", lambda: ["torch", "triton"])
    monkeypatch.setattr("cylindersplat.training.trainer.available_backends", lambda: ["torch", "triton"])
    assert _error_line(argv, capsys) == ("cylindersplat train: error: train.render_backend=triton needs a CUDA GPU, "
                                         "but training runs on cpu; use train.render_backend=auto (or torch), or "
                                         "train.device=cuda")


def test_train_options_are_typed_changes_not_yaml(tmp_path, capsys):
    """`train --data yes`: the folder "yes", not YAML's true (issue 36: options travel as typed changes); an option
    wins over a KEY=VALUE of the same setting, as before."""
    import yaml

    from cylindersplat.cli import main

    assert main(["train", "--data", "yes", "--out", str(tmp_path / "run"), "--stages", "1,2", "--steps", "5,6",
                 "--print-config", "train.steps_per_stage=[9,9]", "data.root=other"]) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    assert printed["data"]["root"] == "yes" and printed["output_dir"] == str(tmp_path / "run")
    assert printed["train"]["stages"] == [1, 2] and printed["train"]["steps_per_stage"] == [5, 6]


def test_checked_numbers_refuse_what_does_not_convert_and_nan_whatever_the_bound():
    import argparse

    from cylindersplat.utils.arguments import checked_number, frame_count, port_number

    anything = checked_number(float, lambda v: True, "a number", "anything")
    assert anything.__name__ == "anything" and anything("-1e300") == -1e300 and anything("inf") == float("inf")
    for text in ("nan", "x", ""):
        with pytest.raises(argparse.ArgumentTypeError, match=f"^expected a number, got '{text}'$"):
            anything(text)
    big = checked_number(int, lambda v: v > 0, "a positive integer", "big")
    assert big("1" * 400) == int("1" * 400)  # no float conversion on the way (a NaN test overflowed here)
    assert [frame_count(t) for t in ("0", "2")] == [0, 2] and port_number("0") == 0
