"""Fault cases of the pose wing (issue 37): every bad input is one line naming the file and what to do, no pose file
is written from it, and `data poses` never loses what the user had.

pycolmap is needed only where a test says so (``importorskip``); the refusals come before SfM runs.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from cylindersplat.cli import main
from cylindersplat.data.poses import read_colmap, read_metashape_xml, read_openmvg, write_colmap
from cylindersplat.data.poses.conventions import PoseRecord
from cylindersplat.data.poses.poses_json import SFM_UNITS, warn_if_not_metric, write_poses_json
from cylindersplat.data.poses.sfm import check_panoramas, check_room
from cylindersplat.validation import ScaleWarning

DATA = Path(__file__).parent / "data"


def _image(path, height, width, seed=0):
    rng = np.random.default_rng(seed)
    Image.fromarray(rng.integers(0, 255, (height, width, 3), dtype=np.uint8)).save(path)


def _one_line(capsys, args, text, code=1) -> str:
    """``main(args)`` fails with ``code`` and one stderr line (besides progress lines) that contains ``text``."""
    assert main(args) == code
    lines = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in lines if "error:" in line]
    assert len(errors) == 1 and text in errors[0] and lines[-1] == errors[0] and "Traceback" not in lines[0], lines
    return errors[0]


def _import(source, fmt, out) -> list[str]:
    return ["data", "import-poses", str(source), "--from", fmt, "--out", str(out)]


# --- COLMAP -------------------------------------------------------------------------------------------


def _colmap_text(folder: Path, pose: str) -> Path:
    folder.mkdir()
    (folder / "cameras.txt").write_text("1 EQUIRECTANGULAR 64 32 64 32\n")
    (folder / "images.txt").write_text(f"# comment\n1 1 0 0 0 0 0 0 1 a.jpg\n\n2 {pose} 1 b.jpg\n\n")
    return folder


@pytest.mark.parametrize("pose, shown", [("inf 0 0 0 0 0 0", "(inf 0.0 0.0 0.0 0.0 0.0 0.0)"),
                                         ("1 0 0 0 nan 0 0", "(1.0 0.0 0.0 0.0 nan 0.0 0.0)"),
                                         ("1 0 0 0 0 -inf 0", "(1.0 0.0 0.0 0.0 0.0 -inf 0.0)")])
def test_colmap_non_finite_pose_names_file_line_and_image(tmp_path, capsys, pose, shown):
    model = _colmap_text(tmp_path / "model", pose)
    out = tmp_path / "poses.json"
    _one_line(capsys, _import(model, "colmap", out),
              f"{model / 'images.txt'} line 4 (image 'b.jpg'): the pose QW QX QY QZ TX TY TZ holds a non-finite "
              f"number {shown}; fix or remove this image")
    assert not out.exists()


def test_colmap_zero_quaternion_is_refused(tmp_path, capsys):
    model = _colmap_text(tmp_path / "model", "0 0 0 0 1 2 3")
    _one_line(capsys, _import(model, "colmap", tmp_path / "poses.json"),
              "line 4 (image 'b.jpg'): the quaternion QW QX QY QZ is zero, not a rotation")


def _colmap_bin(folder: Path) -> Path:
    import torch

    records = [PoseRecord(name, torch.eye(4, dtype=torch.float64)) for name in ("a.jpg", "b.jpg")]
    return write_colmap(folder, records, 64, 32, kind="bin")


def test_colmap_bin_absurd_keypoint_count_is_checked_against_the_file_size(tmp_path, capsys):
    model = _colmap_bin(tmp_path / "model")
    data = bytearray((model / "images.bin").read_bytes())
    at = 8 + struct.calcsize("<idddddddi") + len(b"a.jpg\0")  # the first image's keypoint count
    assert struct.unpack_from("<Q", data, at) == (0,)
    struct.pack_into("<Q", data, at, 2**64 - 1)
    (model / "images.bin").write_bytes(bytes(data))
    _one_line(capsys, _import(model, "colmap", tmp_path / "poses.json"),
              f"{model / 'images.bin'}: truncated or corrupt COLMAP binary model: 18446744073709551615 keypoints of "
              "image 'a.jpg' of at least 24 bytes each do not fit in the")


def test_colmap_bin_absurd_image_count_and_nan_pose(tmp_path, capsys):
    model = _colmap_bin(tmp_path / "model")
    good = (model / "images.bin").read_bytes()
    data = bytearray(good)
    struct.pack_into("<Q", data, 0, 2**40)
    (model / "images.bin").write_bytes(bytes(data))
    _one_line(capsys, _import(model, "colmap", tmp_path / "p.json"), "1099511627776 images of at least")
    data = bytearray(good)
    struct.pack_into("<d", data, 8 + 4 + 4 * 8, float("nan"))  # the first image's TX
    (model / "images.bin").write_bytes(bytes(data))
    _one_line(capsys, _import(model, "colmap", tmp_path / "p.json"),
              f"{model / 'images.bin'} image 1 ('a.jpg'): the pose QW QX QY QZ TX TY TZ holds a non-finite number")
    assert not (tmp_path / "p.json").exists()


# --- Metashape ----------------------------------------------------------------------------------------


def _metashape(tmp_path: Path, edit) -> Path:
    tree = ET.parse(DATA / "metashape_spherical.xml")
    edit(tree.getroot())
    path = tmp_path / "cameras.xml"
    tree.write(path)
    return path


def _camera(root, label="R0010002"):
    return next(c for c in root.iter("camera") if c.get("label") == label)


@pytest.mark.parametrize("transform, text", [
    ("1 0.2 0 1.5 0 1 0 0 0 0 1 0.25 0 0 0 1", "camera 'R0010002' <transform> is not a rotation (sheared: "
     "max |R R^T - I| = 0.2"),
    ("2 0 0 0 0 2 0 0 0 0 2 0 0 0 0 1", "camera 'R0010002' <transform> is not a rotation (scaled by 2"),
    ("1 0 0 0 0 1 0 0 0 0 1 0 0.1 0 0 1", "camera 'R0010002' <transform>: the last row is 0.1 0 0 1, not 0 0 0 1 "
     "(a projective transform, not a camera pose)"),
    ("-1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", "camera 'R0010002' <transform> is not a rotation (determinant -1"),
])
def test_metashape_camera_transform_must_be_rigid(tmp_path, capsys, transform, text):
    def edit(root):
        _camera(root).find("transform").text = transform

    out = tmp_path / "poses.json"
    _one_line(capsys, _import(_metashape(tmp_path, edit), "metashape", out), text)
    assert not out.exists()


def test_metashape_component_rotation_is_a_rotation_up_to_scale(tmp_path):
    def folded(root):  # the component's scale 2 folded into its rotation: the same similarity
        transform = root.find(".//component/transform")
        transform.find("rotation").text = "0 -2 0 2 0 0 0 0 2"
        transform.remove(transform.find("scale"))

    reference = read_metashape_xml(DATA / "metashape_spherical.xml")
    for a, b in zip(reference, read_metashape_xml(_metashape(tmp_path, folded))):
        assert a.image == b.image
        np.testing.assert_allclose(a.c2w.numpy(), b.c2w.numpy(), atol=1e-12)

    def sheared(root):
        root.find(".//component/transform/rotation").text = "0 -1 0.3 1 0 0 0 0 1"

    with pytest.raises(ValueError, match=r"component 0 <rotation> is not a rotation up to scale \(sheared"):
        read_metashape_xml(_metashape(tmp_path, sheared))

    def negative(root):
        root.find(".//component/transform/scale").text = "-2"

    with pytest.raises(ValueError, match="component 0 <scale> must be positive, got -2"):
        read_metashape_xml(_metashape(tmp_path, negative))


def test_metashape_camera_without_label_is_one_line(tmp_path, capsys):
    def edit(root):
        del _camera(root).attrib["label"]

    _one_line(capsys, _import(_metashape(tmp_path, edit), "metashape", tmp_path / "p.json"),
              "camera id='1': no label (the photo's file name), so its pose names no panorama")


# --- OpenMVG ------------------------------------------------------------------------------------------


def _mvg(tmp_path: Path, edit) -> Path:
    data = json.loads((DATA / "openmvg_spherical_sfm_data.json").read_text())
    edit(data)
    path = tmp_path / "sfm_data.json"
    path.write_text(json.dumps(data))
    return path


def _view(data, i=1):
    return data["views"][i]["value"]["ptr_wrapper"]["data"]


@pytest.mark.parametrize("edit, text", [
    (lambda d: d["views"].__setitem__(0, "00000.jpg"), None),  # a view that is no object: no pose, skipped
    (lambda d: d["extrinsics"].__setitem__(0, "pose"), '"extrinsics" entry 0: expected {"key": <integer>, "value"'),
    (lambda d: d["extrinsics"][0].__setitem__("key", [0]), '"extrinsics" entry 0: expected {"key": <integer>'),
    (lambda d: d["extrinsics"][0].__setitem__("value", [1, 2]), '"extrinsics" entry 0: expected'),
    (lambda d: d["intrinsics"].__setitem__(0, 7), '"intrinsics" entry 0: expected'),
    (lambda d: d["intrinsics"][0]["value"].__setitem__("polymorphic_name", ["spherical"]), "is None; cylindersplat"),
    (lambda d: _view(d).__setitem__("id_pose", [1]), None),  # not an id: no pose, skipped
    (lambda d: _view(d).pop("filename"), "view 1: has a pose but no \"filename\" (got None)"),
    (lambda d: _view(d).__setitem__("filename", 5), "view 1: has a pose but no \"filename\" (got 5)"),
    (lambda d: d["extrinsics"][1]["value"].__setitem__("rotation", "R"), 'extrinsic 1: needs "rotation" (3x3)'),
    (lambda d: d["extrinsics"][1]["value"].__setitem__("center", [0, "a", 1]), 'extrinsic 1: needs "rotation"'),
    (lambda d: d["extrinsics"][1]["value"].__setitem__("rotation", [[1, 0.3, 0], [0, 1, 0], [0, 0, 1]]),
     "view '00001.jpg' rotation part is not orthonormal"),
])
def test_openmvg_malformed_files_are_one_line(tmp_path, capsys, edit, text):
    path = _mvg(tmp_path, edit)
    out = tmp_path / "poses.json"
    if text is None:  # still read: the other views
        assert main(_import(path, "openmvg", out)) == 0
        assert len(json.loads(out.read_text())["frames"]) == 1
        return
    _one_line(capsys, _import(path, "openmvg", out), text)
    assert not out.exists()


def test_openmvg_reader_never_raises_anything_but_value_error(tmp_path):
    """Every node of the file replaced by each wrong JSON type in turn: a ValueError (one line) or poses."""
    original = json.loads((DATA / "openmvg_spherical_sfm_data.json").read_text())
    paths = []

    def walk(node, path):
        paths.append(path)
        children = node.items() if isinstance(node, dict) else enumerate(node) if isinstance(node, list) else ()
        for key, child in children:
            walk(child, path + (key,))

    walk(original, ())
    for path in paths[1:]:
        for wrong in (None, "x", 3.5, True, [], {}, [[1]]):
            data = json.loads(json.dumps(original))
            node = data
            for key in path[:-1]:
                node = node[key]
            node[path[-1]] = wrong
            file = tmp_path / "sfm_data.json"
            file.write_text(json.dumps(data))
            try:
                read_openmvg(file)
            except ValueError:
                pass


def test_colmap_text_reader_never_raises_anything_but_value_error(tmp_path):
    model = _colmap_text(tmp_path / "model", "1 0 0 0 0 0 0")
    lines = (model / "images.txt").read_text().splitlines()
    for i, line in enumerate(lines):
        for cut in range(0, len(line) + 1, 3):
            edited = lines[:i] + [line[:cut] + "x"] + lines[i + 1:]
            (model / "images.txt").write_text("\n".join(edited) + "\n")
            try:
                read_colmap(model)
            except ValueError:
                pass


# --- what is written ----------------------------------------------------------------------------------


def test_import_poses_keeps_an_existing_out_unless_overwrite(tmp_path, capsys):
    out = tmp_path / "poses.json"
    out.write_text('{"frames": "hand-written"}')
    args = _import(DATA / "metashape_spherical.xml", "metashape", out)
    _one_line(capsys, args, f"{out} already exists (poses imported earlier, or written by hand) and is kept: give "
              "--overwrite to replace it, or --out another file")
    assert out.read_text() == '{"frames": "hand-written"}'
    assert main([*args, "--overwrite"]) == 0
    assert len(json.loads(out.read_text())["frames"]) == 2


def test_write_poses_json_refuses_bad_poses(tmp_path):
    import torch

    bad = torch.eye(4, dtype=torch.float64)
    bad[0, 3] = float("nan")
    with pytest.raises(ValueError, match=r"pose 1 \(b.png\) contains non-finite values"):
        write_poses_json(tmp_path / "poses.json", [PoseRecord("a.png", torch.eye(4)), PoseRecord("b.png", bad)])
    sheared = torch.eye(4, dtype=torch.float64)
    sheared[0, 1] = 0.5
    with pytest.raises(ValueError, match="pose 0 rotation part is not orthonormal"):
        write_poses_json(tmp_path / "poses.json", [PoseRecord(None, sheared)])
    assert not (tmp_path / "poses.json").exists()


# --- data poses: never lose what the user had ----------------------------------------------------------


@pytest.fixture
def pano(tmp_path) -> Path:
    folder = tmp_path / "pano"
    folder.mkdir()
    _image(folder / "a.png", 16, 32)
    _image(folder / "b.png", 16, 32, seed=1)
    (folder / "a_depth.npy").write_bytes(b"user depth")
    return folder


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_sparse_dir_holding_the_panoramas_is_refused(pano, capsys):
    before = _snapshot(pano)
    for extra in ([], ["--overwrite"]):
        _one_line(capsys, ["data", "poses", str(pano), "--sparse-dir", str(pano), *extra],
                  f"--sparse-dir {pano} holds the input panoramas ({pano}), and the COLMAP model replaces that folder "
                  "as a whole: give a new folder")
        _one_line(capsys, ["data", "poses", str(pano), "--sparse-dir", str(pano.parent), *extra],
                  "holds the input panoramas")
    assert _snapshot(pano) == before


def test_existing_poses_json_is_kept_without_overwrite(pano, capsys):
    (pano / "poses.json").write_text('{"frames": "hand-written"}')
    before = _snapshot(pano)
    _one_line(capsys, ["data", "poses", str(pano)],
              f"{pano / 'poses.json'} already exists (poses of an earlier run, imported or written by hand) and is "
              "kept: give --overwrite to replace it and its COLMAP model, or --out another file")
    assert _snapshot(pano) == before
    (pano / "poses.json").unlink()
    (pano / "sparse" / "0").mkdir(parents=True)
    (pano / "sparse" / "0" / "cameras.txt").write_text("# an earlier model\n")
    _one_line(capsys, ["data", "poses", str(pano)], "sparse/0 already holds a COLMAP model and is kept: give "
              "--overwrite to replace it, or --sparse-dir another folder")


def test_sparse_dir_that_is_a_file_or_holds_foreign_files_is_refused(pano, capsys, tmp_path):
    (pano / "poses.json").write_text('{"frames": "hand-written"}')
    target = tmp_path / "notes.txt"
    target.write_text("mine")
    before = _snapshot(tmp_path)
    _one_line(capsys, ["data", "poses", str(pano), "--sparse-dir", str(target), "--overwrite"],
              f"--sparse-dir {target} is a file, not a folder: give a new folder for the COLMAP model")
    other = tmp_path / "work"
    other.mkdir()
    (other / "cameras.txt").write_text("model")
    (other / "thesis.tex").write_text("mine")
    _one_line(capsys, ["data", "poses", str(pano), "--sparse-dir", str(other), "--overwrite"],
              f"--sparse-dir {other} holds files that are not a COLMAP model (thesis.tex), and the model replaces "
              "that folder as a whole: give a new or empty folder")
    _one_line(capsys, ["data", "poses", str(pano), "--out", str(other / "sub" / "poses.json"), "--sparse-dir",
                       str(other), "--overwrite"], "would hold the poses file")
    before.update({"work/cameras.txt": b"model", "work/thesis.tex": b"mine"})
    assert _snapshot(tmp_path) == before


def test_write_outputs_swaps_in_whole_or_keeps_the_earlier_set(tmp_path):
    from cylindersplat.commands._sfm_poses import _write_outputs

    out, sparse = tmp_path / "poses.json", tmp_path / "sparse" / "0"
    sparse.mkdir(parents=True)
    (sparse / "cameras.txt").write_text("old model")
    out.write_text("old poses")

    def model(folder):
        Path(folder, "cameras.txt").write_text("new model")

    def fail(path):
        raise OSError(27, "File too large", str(path))

    with pytest.raises(OSError, match="File too large"):
        _write_outputs(out, sparse, model, fail)
    assert out.read_text() == "old poses" and (sparse / "cameras.txt").read_text() == "old model"
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["0", "cameras.txt", "poses.json", "sparse"]

    old = os.umask(0o022)
    try:
        _write_outputs(out, sparse, model, lambda path: Path(path).write_text("new poses"))
    finally:
        os.umask(old)
    assert out.read_text() == "new poses" and (sparse / "cameras.txt").read_text() == "new model"
    assert sparse.stat().st_mode & 0o777 == 0o755 and out.stat().st_mode & 0o777 == 0o644
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["0", "cameras.txt", "poses.json", "sparse"]


# --- data poses: panoramas COLMAP cannot read ----------------------------------------------------------


def test_fifo_among_the_panoramas_is_refused_not_waited_on(pano, capsys):
    os.mkfifo(pano / "c.png")
    _one_line(capsys, ["data", "poses", str(pano)], f"{pano / 'c.png'} is not a regular file (a FIFO, device or "
              "folder named like an image): remove it from the folder")


def test_truncated_and_empty_png_are_refused(pano, capsys):
    data = (pano / "b.png").read_bytes()
    (pano / "b.png").write_bytes(data[: len(data) // 2])
    _one_line(capsys, ["data", "poses", str(pano)], f"{pano / 'b.png'} is damaged or truncated (")
    (pano / "b.png").write_bytes(b"")
    _one_line(capsys, ["data", "poses", str(pano)],
              f"{pano / 'b.png'} is not an image file (0 bytes): fix or remove it from the folder")


def test_symlink_loop_and_non_utf8_name_are_refused(pano, capsys):
    os.symlink("c.png", pano / "c.png")
    _one_line(capsys, ["data", "poses", str(pano)], f"{pano / 'c.png'} is a symlink loop: fix or remove it")
    (pano / "c.png").unlink()
    name = os.path.join(os.fsencode(pano), b"\xff.png")
    shutil.copy(pano / "a.png", name)
    _one_line(capsys, ["data", "poses", str(pano)], "the file name '\\udcff.png' is not valid UTF-8, which COLMAP "
              "needs: rename it")


def test_too_little_room_is_refused_before_colmap_starts(tmp_path, monkeypatch):
    import collections

    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(10 * 2**20, 9 * 2**20, 2**20))
    with pytest.raises(ValueError, match=r"has 1 MB free; structure from motion on 3 panoramas needs about 22 MB "
                       "there: free space or set TMPDIR"):
        check_room(3, str(tmp_path))


@pytest.mark.slow  # two fresh interpreters (about 13 s)
def test_file_size_limit_is_one_line_and_leaves_no_temporary(pano, tmp_path):
    """Under ``ulimit -f``: refused before COLMAP starts; and where COLMAP itself hits the limit (the check
    bypassed), its abort is one line too and ``cylindersplat-sfm-*`` is removed."""
    pytest.importorskip("pycolmap")
    temp = tmp_path / "tmp"
    temp.mkdir()
    script = ("import resource, sys; resource.setrlimit(resource.RLIMIT_FSIZE, (200 * 1024, resource.RLIM_INFINITY))\n"
              "import cylindersplat.data.poses.sfm as sfm\n"
              "if sys.argv[2] == 'bypass': sfm.check_room = lambda *a: None\n"
              "from cylindersplat.cli import main\n"
              "sys.exit(main(['data', 'poses', sys.argv[1]]))\n")
    env = {**os.environ, "TMPDIR": str(temp)}
    for mode, text in (("check", "the file-size limit (ulimit -f) is 0.2 MB"),
                       ("bypass", "structure from motion failed while")):
        run = subprocess.run([sys.executable, "-c", script, str(pano), mode], env=env, capture_output=True,
                             text=True, timeout=120)
        lines = run.stderr.strip().splitlines()
        assert run.returncode == 1 and text in lines[-1] and "Traceback" not in run.stderr, run.stderr
        assert list(temp.iterdir()) == []
        assert not (pano / "poses.json").exists() and not (pano / "sparse").exists()


def test_mixed_sizes_get_one_camera_each_and_the_message_names_the_mix(tmp_path, capsys):
    pytest.importorskip("pycolmap")
    _image(tmp_path / "a.png", 32, 64)
    _image(tmp_path / "b.png", 16, 32, seed=1)
    _image(tmp_path / "c.png", 32, 64, seed=2)
    _one_line(capsys, ["data", "poses", str(tmp_path)], "they come in 2 sizes (2 of 64x32, 1 of 32x16), and "
              "panoramas of different sizes match poorly: resize them to one size")


def test_check_panoramas_accepts_mixed_sizes(tmp_path):
    _image(tmp_path / "a.png", 32, 64)
    _image(tmp_path / "b.png", 16, 32, seed=1)
    assert check_panoramas([tmp_path / "a.png", tmp_path / "b.png"], tmp_path) == (32, 64)


# --- render on poses in SfM units ---------------------------------------------------------------------


def test_poses_in_sfm_units_warn_once(tmp_path, recwarn):
    import torch

    from cylindersplat.inference import load_panorama_folder, write_panorama_folder

    c2w = torch.eye(4).repeat(2, 1, 1)
    c2w[1, 0, 3] = 0.5
    write_panorama_folder(tmp_path, torch.rand(2, 3, 16, 32), c2w, torch.full((2, 16, 32), 2.0))
    data = json.loads((tmp_path / "poses.json").read_text())
    load_panorama_folder(tmp_path, (16, 32))
    assert not [w for w in recwarn if issubclass(w.category, ScaleWarning)]
    data["sfm"] = {"scale": SFM_UNITS}
    (tmp_path / "poses.json").write_text(json.dumps(data))
    with pytest.warns(ScaleWarning) as caught:
        load_panorama_folder(tmp_path, (16, 32))
    messages = [str(w.message) for w in caught if "SfM units" in str(w.message)]
    assert messages == [f"{tmp_path / 'poses.json'}: the poses are in SfM units, not metres (data poses found no "
                        "depth, --depth-prior, --camera-height or --scale to fix the scale), so renders and the "
                        "depth-scale search from them are unreliable: run data poses again with one of those (and "
                        "--overwrite)"]
    warn_if_not_metric(tmp_path / "missing.json")  # unreadable: left to the reader


@pytest.mark.slow  # SfM on the real triplet (about 12 s)
def test_real_triplet_with_one_panorama_at_half_size_registers(pano_grf_fixture, tmp_path, capsys):
    """Issue 37: all panoramas on one camera left even the two same-size ones unplaced; one camera per size places
    all three, as close to the dataset's poses as at one size."""
    pytest.importorskip("pycolmap")
    from cylindersplat.data.pano_grf import panogrf_c2w
    from cylindersplat.data.poses.alignment import pose_errors

    fixture = pano_grf_fixture / "00000007"
    folder = tmp_path / "scene"
    folder.mkdir()
    for f in ("00", "01", "02"):
        with Image.open(fixture / f / "rgb.png") as image:
            (image.resize((512, 256), Image.LANCZOS) if f == "01" else image).save(folder / f"pano_{f}.png")
    assert main(["data", "poses", str(folder), "--scale", "none", "--threads", "2"]) == 0
    out = capsys.readouterr()
    assert "one camera per size: 2 of 1024x512, 1 of 512x256" in out.err and "registered 3 of 3 panoramas" in out.out
    frames = sorted(json.loads((folder / "poses.json").read_text())["frames"], key=lambda f: f["image"])
    truth = np.stack([panogrf_c2w(np.loadtxt(fixture / f / "rot.txt"), np.loadtxt(fixture / f / "tran.txt")).double()
                      .numpy() for f in ("00", "01", "02")])
    errors = pose_errors(np.array([f["c2w"] for f in frames]), truth)
    assert max(errors.rotation_deg) < 1.0 and errors.centre_over_baseline < 0.02
    before = _snapshot(folder)
    _one_line(capsys, ["data", "poses", str(folder)], "already exists (poses of an earlier run, imported or written "
              "by hand) and is kept: give --overwrite")
    assert _snapshot(folder) == before


@pytest.mark.parametrize("content", [b"", b"user depth"])
def test_unreadable_depth_file_for_the_scale_is_one_line(pano, content):
    import argparse

    from cylindersplat.commands._sfm_poses import _depth_maps

    (pano / "a_depth.npy").write_bytes(content)
    args = argparse.Namespace(depth_prior=None, depth_scale=1000.0)
    with pytest.raises(ValueError, match="a_depth.npy"):
        _depth_maps(args, pano, ["a.png", "b.png"])


def test_fps_applies_to_trajectories_only(tmp_path, capsys):
    (tmp_path / "kitti.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0\n")
    (tmp_path / "images").mkdir()
    _image(tmp_path / "images" / "f0.png", 4, 8)
    _one_line(capsys, [*_import(DATA / "metashape_spherical.xml", "metashape", tmp_path / "a.json"), "--fps", "30"],
              "--fps matches trajectory timestamps to frame numbers; it does not apply to --from metashape")
    _one_line(capsys, [*_import(tmp_path / "kitti.txt", "kitti", tmp_path / "b.json"), "--fps", "30", "--images",
                       str(tmp_path / "images")], "kitti.txt: --fps needs timestamps (a TUM trajectory)")
