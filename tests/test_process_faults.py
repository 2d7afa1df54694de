"""Issue 27, item 4: process faults end in one line (or none) and leave no partial or stale files."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from cylindersplat import cli
from cylindersplat.cli import main

SRC = str(Path(__file__).resolve().parents[1] / "src")


def test_a_closed_pipe_ends_print_config_quietly():
    """``train --print-config | head -0``: the reader is gone before the config is printed."""
    env = {**os.environ, "PYTHONPATH": SRC, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, "-m", "cylindersplat", "train", "--print-config"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, env=env)
    proc.stdout.close()  # what `head -0` does
    err = proc.stderr.read().decode()
    assert proc.wait(timeout=300) == 141
    assert err == ""


def test_ctrl_c_at_start_up_is_one_line(monkeypatch, capsys):
    """Ctrl-C while the command's modules are still importing (seconds on a busy machine)."""
    def interrupted():
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert main(["export", "--input", "x"]) == 130
    assert capsys.readouterr().err == "cylindersplat export: interrupted\n"


def test_ctrl_c_while_exporting_leaves_no_partial_file(panorama_folder, tiny_checkpoint, tmp_path, monkeypatch, capsys):
    from cylindersplat.gaussians import ply

    class InterruptedPly:  # half a file written, then Ctrl-C
        def __init__(self, elements):
            pass

        def write(self, path):
            Path(path).write_bytes(b"ply\nformat binary_little_endian 1.0\n")
            raise KeyboardInterrupt

    monkeypatch.setattr(ply, "PlyData", InterruptedPly)
    out = tmp_path / "out" / "g.ply"
    assert main(["export", "--input", str(panorama_folder[0]), "--checkpoint", str(tiny_checkpoint), "--resolution",
                 "16x32", "--out", str(out), "--device", "cpu"]) == 130
    assert capsys.readouterr().err == "cylindersplat export: interrupted\n"
    assert list(out.parent.iterdir()) == []  # neither g.ply nor its temporary file


def test_rendering_again_into_a_folder_removes_every_earlier_output(panorama_folder, tiny_checkpoint, tmp_path):
    out = tmp_path / "render"
    base = ["render", "--input", str(panorama_folder[0]), "--checkpoint", str(tiny_checkpoint), "--resolution", "16x32",
            "--out", str(out), "--device", "cpu", "--min-opacity", "0"]
    assert main(base + ["--frames", "2"]) == 0
    assert {"gaussians.ply", "flythrough.gif", "flythrough_poses.json"} <= {p.name for p in out.iterdir()}
    assert main(base + ["--frames", "0", "--no-ply"]) == 0  # writes views only: nothing of the first run stays
    assert sorted(p.name for p in out.iterdir()) == ["views"]
    assert sorted(p.name for p in (out / "views").iterdir()) == ["poses.json", "view_000_depth.png", "view_000_rgb.png"]
