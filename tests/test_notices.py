"""Warnings reach a command-line user as one-line notices; the viewer says how it stops."""

from __future__ import annotations

import warnings

import pytest

from cylindersplat.cli import main
from cylindersplat.metrics.lpips import LPIPS_WEIGHTS_ENV
from cylindersplat.utils.notices import Notice, one_line_warnings
from cylindersplat.viewer import serving_line


def test_warnings_inside_a_command_are_one_line_notices(capsys):
    with one_line_warnings("cylindersplat x"):
        warnings.warn("first line\n  second line", UserWarning)
        warnings.warn("first line\n  second line", UserWarning)  # the same message: said once
        warnings.warn("other", RuntimeWarning)
    assert capsys.readouterr().err.splitlines() == ["cylindersplat x: note: first line second line",
                                                    "cylindersplat x: note: other"]
    with pytest.warns(UserWarning, match="outside"):  # outside the block: ordinary warnings again
        warnings.warn("outside", UserWarning)


def test_missing_lpips_weights_are_a_notice_in_train(synth_dataset, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv(LPIPS_WEIGHTS_ENV, raising=False)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "no_torch_cache"))
    assert main(["train", "--data", str(synth_dataset(2, seed=5)), "--out", str(tmp_path / "run"), "--stages", "1",
                 "--steps", "1", "loss.use_lpips=auto", "train.tensorboard=false", "train.image_every=0",
                 "train.progress=false"]) == 0
    err = capsys.readouterr().err.splitlines()
    said = [line for line in err if "LPIPS" in line]
    assert said == [said[0]] and said[0].startswith("cylindersplat train: note: LPIPS loss term disabled"), err
    assert not any("UserWarning" in line or "warnings.warn" in line for line in err)
    from cylindersplat.training.losses import LossConfig, RenderLoss

    with pytest.warns(Notice, match="LPIPS loss term disabled"):
        RenderLoss(LossConfig(use_lpips="auto"))


def test_the_viewer_says_how_it_stops():
    assert serving_line("0.0.0.0", 8080, 1234, 2, None).endswith("(1,234 Gaussians, 2 cameras; Ctrl+C stops)")
    timed = serving_line("127.0.0.1", 8080, 5, 1, 30.0)
    assert timed == "viewer: http://127.0.0.1:8080  (5 Gaussians, 1 cameras; stops after 30 s (or Ctrl+C))"
