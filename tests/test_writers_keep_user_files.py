"""Issue 37, item 1, the writers not covered by ``test_no_data_lost``: `data priors`, `view --html` and
`data import-poses`. A run that fails part-way (a file-size limit, a full disk) leaves what the user had as it was
(same files, same bytes, same inodes), and no output may take the place of an input.
"""

import errno
import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cylindersplat.cli import main

SRC = str(Path(__file__).resolve().parents[1] / "src")


def _files(root: Path) -> dict[str, tuple[int, bytes]]:
    """Every file under ``root``: relative path -> (inode, bytes). A replaced file has a new inode."""
    return {str(p.relative_to(root)): (p.stat().st_ino, p.read_bytes()) for p in sorted(root.rglob("*")) if p.is_file()}


def _error_line(capsys) -> str:
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if ": error: " in line]
    assert len(errors) == 1 and err.strip().endswith(errors[0]) and "Traceback" not in err, err
    return errors[0]


def _fails_on_call(number: int, real):
    """``real``, except that call ``number`` (from 1) raises EFBIG as a file-size limit would."""
    calls = []

    def call(*args, **kwargs):
        calls.append(1)
        if len(calls) == number:
            raise OSError(errno.EFBIG, os.strerror(errno.EFBIG))
        return real(*args, **kwargs)

    return call


# data priors ----------------------------------------------------------------------------------------------------

@pytest.fixture()
def synth(tmp_path):
    out = tmp_path / "synth"
    assert main(["data", "synth", "--out", str(out), "--scenes", "2", "--resolution", "16x32", "--frames", "3"]) == 0
    return out


def _priors(data, net, *more):
    return ["data", "priors", "--data", str(data), "--net", f"exported:{net}", "--format", "npy", "--device", "cpu",
            *more]


def test_priors_that_fail_part_way_through_an_overwrite_keep_the_earlier_tree(synth, tmp_path, monkeypatch, capsys):
    from test_data_priors_cli import export_torchscript

    first, second = export_torchscript(tmp_path / "a.pt"), export_torchscript(tmp_path / "b.pt", offset=1.5)
    assert main(_priors(synth, first, "--name", "mono")) == 0
    tree = synth / "priors" / "mono"
    before = _files(tree)
    assert len([name for name in before if name.endswith(".npy")]) == 6
    capsys.readouterr()
    monkeypatch.setattr(np, "save", _fails_on_call(3, np.save))  # two frames of the new network written, then full
    assert main(_priors(synth, second, "--name", "mono", "--overwrite", "--batch-size", "1")) == 1
    assert _error_line(capsys) == (
        f"cylindersplat data: error: file too large while writing {tree}/00000000/02/rgb.npy (a file-size limit: "
        f"ulimit -f, FAT32's 4 GiB): choose another --out; nothing in {tree} was changed (not written: prior.json, "
        "00000000/00/rgb.npy, 00000000/01/rgb.npy, 00000000/02/rgb.npy, 00000001/00/rgb.npy, 00000001/01/rgb.npy "
        "and 1 more)")
    assert _files(tree) == before  # the first network's files and sidecar, untouched; no temporary left

    # Without a failure the overwrite goes through, whole.
    monkeypatch.undo()
    assert main(_priors(synth, second, "--name", "mono", "--overwrite")) == 0
    assert json.loads((tree / "prior.json").read_text())["network"] == f"exported:{second}"
    assert all(inode != before[name][0] for name, (inode, _) in _files(tree).items())


def test_priors_that_fail_while_adding_keep_what_they_finished_and_resume(synth, tmp_path, monkeypatch, capsys):
    """A first run (nothing to replace) keeps the frames it finished: the next run does only the rest."""
    from test_data_priors_cli import export_torchscript

    net = export_torchscript(tmp_path / "a.pt")
    monkeypatch.setattr(np, "save", _fails_on_call(3, np.save))
    assert main(_priors(synth, net, "--name", "mono", "--batch-size", "1")) == 1
    assert "file too large while writing" in _error_line(capsys)
    assert len(list((synth / "priors" / "mono").rglob("*.npy"))) == 2
    monkeypatch.undo()
    assert main(_priors(synth, net, "--name", "mono")) == 0
    assert "4 written, 2 already there" in capsys.readouterr().out


@pytest.mark.parametrize("where", ["dataset", "scene"])
def test_priors_into_the_dataset_itself_are_refused_even_with_overwrite(synth, tmp_path, capsys, where):
    """--out DATA with png files: each prior file would take its panorama's name (rgb.png) and replace it."""
    from test_data_priors_cli import export_torchscript

    net = export_torchscript(tmp_path / "a.pt")
    before = _files(synth)
    out = synth if where == "dataset" else tmp_path / "link"
    if where == "scene":
        out.symlink_to(synth)  # a link to the dataset is the dataset
    argv = ["data", "priors", "--data", str(synth), "--net", f"exported:{net}", "--out", str(out), "--device", "cpu",
            "--overwrite"]
    assert main(argv) == 1
    assert _error_line(capsys) == (
        f"cylindersplat data: error: --out {out} holds the dataset {synth}: prior files named like its "
        "panoramas would replace them; give a folder outside it (default: DATA/priors/NAME with --name)")
    assert _files(synth) == before


# view --html ----------------------------------------------------------------------------------------------------

needs_viser = pytest.mark.skipif(__import__("importlib.util").util.find_spec("viser") is None,
                                 reason="the view extra is not installed (pip install 'cylindersplat[view]')")


def _room(tmp_path: Path) -> Path:
    from cylindersplat.gaussians import save_ply
    from cylindersplat.scenes import demo_room

    return save_ply(demo_room(density=1.0), tmp_path / "room.ply")


@needs_viser
def test_view_html_and_screenshot_that_fail_keep_the_earlier_files(tmp_path, monkeypatch, capsys):
    """--html and --screenshot are one set: the picture failing keeps the earlier page too."""
    from PIL import Image

    ply = _room(tmp_path)
    out = tmp_path / "out"
    out.mkdir()
    argv = ["view", str(ply), "--html", str(out / "room.html"), "--screenshot", str(out / "room.png"),
            "--screenshot-size", "12x16", "--device", "cpu"]
    assert main(argv) == 0
    before = _files(out)
    assert sorted(before) == ["room.html", "room.png"]
    capsys.readouterr()
    real_png = Image.Image.save

    def full(self, fp, *args, **kwargs):
        if str(fp).endswith(".png"):
            raise OSError(errno.EFBIG, os.strerror(errno.EFBIG))
        return real_png(self, fp, *args, **kwargs)

    monkeypatch.setattr(Image.Image, "save", full)
    assert main(argv + ["--frustum-scale", "0.5"]) == 1
    assert _error_line(capsys) == (
        f"cylindersplat view: error: file too large while writing {out / 'room.png'} (a file-size limit: ulimit -f, "
        f"FAT32's 4 GiB): choose another place for --html / --screenshot; nothing in {out} was changed (not written: "
        "room.html, room.png)")
    assert _files(out) == before


@needs_viser
def test_view_html_under_ulimit_f_keeps_the_earlier_page(tmp_path):
    """The real limit: the kernel refuses the write with EFBIG (Python ignores SIGXFSZ)."""
    ply = _room(tmp_path)
    html = tmp_path / "room.html"
    html.write_text("<html>the page I made earlier</html>")
    limit = 20_000  # the page embeds viser's client (megabytes)

    def limited():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = {**os.environ, "PYTHONPATH": SRC, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-m", "cylindersplat", "view", str(ply), "--html", str(html)],
                          capture_output=True, text=True, env=env, preexec_fn=limited, timeout=300)
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        f"cylindersplat view: error: file too large while writing {html} (a file-size limit: ulimit -f, FAT32's "
        "4 GiB): choose another place for --html / --screenshot")  # view has no --out
    assert html.read_text() == "<html>the page I made earlier</html>"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["room.html", "room.ply"]


@pytest.mark.parametrize("option", ["--html", "--screenshot"])
def test_view_refuses_to_write_over_its_own_inputs(tmp_path, capsys, option):
    ply = _room(tmp_path)
    poses = tmp_path / "poses.json"
    poses.write_text(json.dumps({"poses": [np.eye(4).tolist()]}))
    before = _files(tmp_path)
    for target, what in ((ply, "the splat file"), (poses, "the poses file")):
        assert main(["view", str(ply), "--poses-file", str(poses), option, str(target), "--device", "cpu"]) == 1
        assert _error_line(capsys) == (f"cylindersplat view: error: {option} {target} is {what} this command reads: "
                                       f"give another {option}")
    assert _files(tmp_path) == before


@pytest.mark.parametrize("name, what", [
    ("pano_01.png", "is a file of the --input folder {folder} (a panorama or depth the folder reader takes)"),
    ("pano_00_depth.png", "is a file of the --input folder {folder} (a panorama or depth the folder reader takes)"),
    ("poses.json", "is the poses file this command reads"),
])
def test_view_of_an_input_folder_refuses_to_write_over_its_files(panorama_folder, tiny_checkpoint, tmp_path, capsys,
                                                                 name, what):
    folder = panorama_folder[0]
    before = _files(folder)
    target = folder / name
    assert main(["view", "--input", str(folder), "--checkpoint", str(tiny_checkpoint), "--screenshot", str(target),
                 "--resolution", "16x32", "--device", "cpu"]) == 1
    assert _error_line(capsys) == (f"cylindersplat view: error: --screenshot {target} {what.format(folder=folder)}: "
                                   "give another --screenshot")
    assert _files(folder) == before


# data import-poses ----------------------------------------------------------------------------------------------

def _trajectory(tmp_path: Path, x0: float = 0.0) -> Path:
    path = tmp_path / "traj.txt"
    path.write_text(f"0 {x0!r} 0 0 0 0 0 1\n1 {x0 + 1.0!r} 0 0 0 0 0 1\n")  # TUM: t x y z qx qy qz qw
    return path


def test_import_poses_that_fails_to_write_keeps_the_earlier_poses_file(tmp_path, monkeypatch, capsys):
    folder = tmp_path / "scene"
    folder.mkdir()
    out = folder / "poses.json"
    out.write_text('{"poses": [[[1, 0, 0, 5], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]]}\n')  # written by hand
    before = _files(folder)
    argv = ["data", "import-poses", str(_trajectory(tmp_path)), "--from", "tum", "--out", str(out), "--overwrite"]
    monkeypatch.setattr(Path, "write_text", _fails_on_call(1, Path.write_text))  # the new poses.json's bytes
    assert main(argv) == 1
    assert _error_line(capsys) == (
        f"cylindersplat data: error: file too large while writing {out} (a file-size limit: ulimit -f, "
        f"FAT32's 4 GiB): choose another --out; nothing in {folder} was changed (not written: poses.json)")
    assert _files(folder) == before
    monkeypatch.undo()
    assert main(argv) == 0 and json.loads(out.read_text())["poses"][1][0][3] == 1.0


def test_import_poses_refuses_to_write_over_its_source(tmp_path, capsys):
    source = tmp_path / "transforms.json"
    source.write_text(json.dumps({"camera_model": "EQUIRECTANGULAR", "frames": [
        {"file_path": "a.png", "transform_matrix": np.eye(4).tolist()}]}))
    before = _files(tmp_path)
    assert main(["data", "import-poses", str(source), "--from", "nerfstudio", "--out", str(source),
                 "--overwrite"]) == 1
    assert _error_line(capsys) == (f"cylindersplat data: error: --out {source} is the source file it "
                                   "reads: give another --out (e.g. poses.json beside it)")
    assert _files(tmp_path) == before
