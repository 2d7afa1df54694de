"""The CLI's error boundary: expected failures are one line (exit 1) and lose nothing; bugs keep tracebacks."""

import errno

import pytest
import torch

from cylindersplat.cli import expected_failure, main


@pytest.mark.parametrize("override,message", [
    ("train.seed=abc", "train.seed must be an integer"),
    ("train.lr=[", "not valid YAML"),
    ("data.batch_size=0", "data.batch_size must be >= 1"),
    ("train.keep_checkpoints=abc", "train.keep_checkpoints must be an integer"),
    ("train.stages=3", "must be a list"),
    ("train.nope=1", "unknown config key"),
])
def test_bad_config_values_are_one_line(tmp_path, capsys, override, message):
    assert main(["train", "--data", str(tmp_path), "--out", str(tmp_path / "run"), override]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "run").exists()


def test_malformed_yaml_names_the_file(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("train: {lr: [1, 2\n")
    assert main(["train", "--config", str(bad)]) == 1
    assert "bad.yaml: malformed YAML" in capsys.readouterr().err


def test_corrupt_checkpoint_is_one_line(tmp_path, capsys):
    weights = tmp_path / "model.safetensors"
    weights.write_bytes(b"\x00" * 64)
    folder = tmp_path / "inputs"
    folder.mkdir()
    code = main(["export", "--input", str(folder), "--checkpoint", str(weights), "--out", str(tmp_path / "g.ply")])
    assert code == 1
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


@pytest.mark.parametrize("exc,expected", [
    (OSError(errno.ENOSPC, "No space left on device", "out/g.ply"), "disk full (out/g.ply)"),
    (PermissionError(errno.EACCES, "Permission denied", "/root/x"), "permission denied (/root/x)"),
    (torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 20 GiB"), "out of memory"),
    (RuntimeError("Torch not compiled with CUDA enabled"), "--device cpu"),
    (ModuleNotFoundError("No module named 'unik3d'", name="unik3d"), "'unik3d' is not installed"),
])
def test_expected_failures_get_a_message(exc, expected):
    assert expected in expected_failure(exc)


@pytest.mark.parametrize("exc", [TypeError("unsupported operand"), KeyError("x"), RuntimeError("shape mismatch")])
def test_bugs_keep_their_traceback(exc):
    assert expected_failure(exc) is None


def test_debug_flag_shows_the_traceback(tmp_path):
    with pytest.raises(ValueError, match="train.seed"):
        main(["--debug", "train", "--data", str(tmp_path), "train.seed=abc"])


def test_weights_with_nan_are_refused_by_name(tmp_path):
    from cylindersplat.model import from_config, load_model, save_model

    model = from_config("tiny")
    with torch.no_grad():
        next(model.parameters()).fill_(float("nan"))
    save_model(model, tmp_path / "diverged.safetensors")
    with pytest.raises(ValueError, match="NaN/inf.*diverged"):
        load_model(tmp_path / "diverged.safetensors")


def test_device_option_resolves_auto_and_refuses_missing_cuda():
    import argparse

    from cylindersplat.commands._arguments import device

    assert device("auto") == ("cuda" if torch.cuda.is_available() else "cpu")
    assert device("CPU") == "cpu"
    with pytest.raises(argparse.ArgumentTypeError, match="not a torch device"):
        device("gpu please")
    if not torch.cuda.is_available():
        with pytest.raises(argparse.ArgumentTypeError, match="no usable CUDA"):
            device("cuda:0")
