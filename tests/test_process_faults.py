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
    assert proc.wait(timeout=300) == 0  # the reader took what it wanted
    assert err == ""


def test_ctrl_c_at_start_up_is_one_line(monkeypatch, capsys):
    """Ctrl-C while the command's modules are still importing (seconds on a busy machine)."""
    def interrupted(command=None):
        raise KeyboardInterrupt

    monkeypatch.setattr(cli, "build_parser", interrupted)
    assert main(["export", "--input", "x"]) == 130
    assert capsys.readouterr().err == "cylindersplat export: interrupted\n"


def test_ctrl_c_that_a_library_turns_into_its_own_error_is_one_line(monkeypatch, capsys):
    """numpy's C extensions, interrupted while importing, raise an ImportError instead of KeyboardInterrupt."""
    import signal
    import time

    def interrupted_import(command=None):
        try:
            os.kill(os.getpid(), signal.SIGINT)  # main's handler raises KeyboardInterrupt here ...
            time.sleep(5)
        except KeyboardInterrupt:
            raise ImportError('PyCapsule_Import could not import module "datetime"') from None  # ... numpy's error

    monkeypatch.setattr(cli, "build_parser", interrupted_import)
    previous = signal.getsignal(signal.SIGINT)
    assert main(["export", "--input", "x"]) == 130
    assert capsys.readouterr().err == "cylindersplat export: interrupted\n"
    assert signal.getsignal(signal.SIGINT) is previous  # a library caller's handler is given back


def _run_and_interrupt(argv: list[str], when) -> tuple[int, str]:
    """Start ``python argv...``, send SIGINT as soon as ``when(pid)`` holds, -> (exit status, stderr)."""
    import signal
    import time

    env = {**os.environ, "PYTHONPATH": SRC, "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen([sys.executable, *argv], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env)
    deadline = time.monotonic() + 120
    while not when(proc.pid) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.002)
    proc.send_signal(signal.SIGINT)
    err = proc.communicate(timeout=120)[1].decode()
    return proc.returncode, err


def test_ctrl_c_right_after_the_executable_starts_is_one_line():
    """The entry module's first act: from there on Ctrl-C ends in one line, before the CLI's imports."""
    code = ("import sys; sys.argv = ['cylindersplat', 'export', '--input', 'x']; import cylindersplat.console; "
            "import os, signal, time; os.kill(os.getpid(), signal.SIGINT); time.sleep(30)")
    code, err = _run_and_interrupt(["-c", code], lambda pid: False)  # the process interrupts itself
    assert (code, err) == (130, "cylindersplat export: interrupted\n")


@pytest.mark.skipif(not Path("/proc/self/maps").exists(), reason="needs Linux /proc to see the imports happen")
def test_ctrl_c_while_the_command_imports_numpy_and_torch_is_one_line():
    def importing(pid: int) -> bool:  # numpy's C extensions are mapped: its import (then torch's) is under way
        try:
            return "numpy" in Path(f"/proc/{pid}/maps").read_text()
        except OSError:
            return False

    code, err = _run_and_interrupt(["-m", "cylindersplat", "export", "--input", "x"], importing)
    assert (code, err) == (130, "cylindersplat export: interrupted\n")


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
    assert not out.parent.exists()  # neither g.ply nor its temporary file, nor the folder the export made


def test_rendering_again_into_a_folder_removes_every_earlier_output(panorama_folder, tiny_checkpoint, tmp_path):
    out = tmp_path / "render"
    base = ["render", "--input", str(panorama_folder[0]), "--checkpoint", str(tiny_checkpoint), "--resolution", "16x32",
            "--out", str(out), "--device", "cpu", "--min-opacity", "0"]
    assert main(base + ["--frames", "2"]) == 0
    assert {"gaussians.ply", "flythrough.gif", "flythrough_poses.json"} <= {p.name for p in out.iterdir()}
    assert main(base + ["--frames", "0", "--no-ply"]) == 0  # writes views only: nothing of the first run stays
    assert sorted(p.name for p in out.iterdir()) == ["views"]
    assert sorted(p.name for p in (out / "views").iterdir()) == ["poses.json", "view_000_depth.png", "view_000_rgb.png"]
