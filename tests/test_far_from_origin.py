"""Issue 37, 'silent on absurd inputs': a scene 1e7 m from the origin. float32, which every render and
reconstruction computes in, keeps only 1 m steps there (numpy's ``spacing`` is the reference), so each place such a
scene enters says so in one line: pose files (refused by the readers, 10 km; tested in test_library_validation),
`data import-poses` (refused, or moved with --recentre in float64), and splat files in `render --ply` and `view`
(a warning naming the file and the step).
"""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from cylindersplat.cli import main

OFFSET = 1e7


def _tum(tmp_path: Path, x0: float, step: float = 1.5) -> Path:
    path = tmp_path / "traj.txt"
    path.write_text(f"0 {x0!r} 0 0 0 0 0 1\n1 {x0 + step!r} 2 0 0 0 0 1\n")  # TUM: t x y z qx qy qz qw
    return path


def _error_line(capsys) -> str:
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if ": error: " in line]
    assert len(errors) == 1 and err.strip().endswith(errors[0]) and "Traceback" not in err, err
    return errors[0]


def test_import_poses_refuses_georeferenced_cameras_naming_float32(tmp_path, capsys):
    source = _tum(tmp_path, OFFSET)
    out = tmp_path / "poses.json"
    assert main(["data", "import-poses", str(source), "--from", "tum", "--out", str(out)]) == 1
    step = float(np.spacing(np.float32(OFFSET + 1.5)))
    assert step == 1.0
    assert _error_line(capsys) == (
        f"cylindersplat data: error: {source}: the cameras lie up to 1e+07 m from the origin (georeferenced "
        "coordinates?), beyond 10000 m: render and export compute in float32, which keeps only 1 m steps there; "
        "give --recentre to move the first camera to the origin (the offset is kept in poses.json as \"origin\")")
    assert not out.exists()


def test_import_poses_recentre_keeps_the_centimetres_float32_would_lose(tmp_path, capsys):
    x0 = 5_123_456.789  # a UTM northing: float32 rounds it to half metres
    source = _tum(tmp_path, x0, step=0.37)
    out = tmp_path / "poses.json"
    assert main(["data", "import-poses", str(source), "--from", "tum", "--out", str(out), "--recentre"]) == 0
    data = json.loads(out.read_text())
    first, second = (np.array(pose) for pose in data["poses"])
    assert data["origin"] == [x0, 0.0, 0.0]
    np.testing.assert_array_equal(first[:3, 3], [0.0, 0.0, 0.0])
    np.testing.assert_allclose(second[:3, 3], [0.37, 2.0, 0.0], atol=1e-9)  # float64: (x0 + 0.37) - x0
    assert abs(float(np.float32(x0 + 0.37) - np.float32(x0)) - 0.37) > 0.1  # what float32 would have kept
    # The recentred file is one the folder reader takes (no 10 km refusal).
    from cylindersplat.data.folder import read_poses_file

    assert len(read_poses_file(out)) == 2


def _room_ply(tmp_path: Path, offset: float, name: str, sky: int = 0) -> Path:
    from cylindersplat.gaussians import save_ply
    from cylindersplat.scenes import demo_room

    room = demo_room(density=1.0)
    means = room.means + torch.tensor([offset, 0.0, 0.0])
    if sky:  # a few far Gaussians (a sky dome) beside a room at the origin
        means[:sky] = torch.tensor([OFFSET, 0.0, 0.0])
    return save_ply(dataclasses.replace(room, means=means), tmp_path / name)


def _notes(capsys, command: str) -> list[str]:
    return [line for line in capsys.readouterr().err.splitlines() if line.startswith(f"cylindersplat {command}: note:")]


def _far_note(command: str, ply: Path) -> str:
    return (f"cylindersplat {command}: note: {ply}: the Gaussians lie 1e+07 m from the origin (median), beyond "
            "10000 m: float32 keeps only 1 m steps there, so positions and renders are wrong; recentre the scene "
            "(subtract a common origin from the Gaussians and the poses)")


def test_view_and_render_of_a_far_splat_file_say_why_it_looks_wrong(tmp_path, capsys):
    far = _room_ply(tmp_path, OFFSET, "far.ply")
    poses = tmp_path / "poses.json"
    poses.write_text(json.dumps({"poses": [np.eye(4).tolist()]}))
    capsys.readouterr()
    assert main(["view", str(far), "--screenshot", str(tmp_path / "shot.png"), "--screenshot-size", "12x16",
                 "--device", "cpu"]) == 0
    assert _notes(capsys, "view")[0] == _far_note("view", far)
    assert main(["render", "--ply", str(far), "--views", str(poses), "--out", str(tmp_path / "r"), "--frames", "0",
                 "--output-resolution", "8x16", "--device", "cpu", "--no-ply"]) == 0
    assert _far_note("render", far) in _notes(capsys, "render")


@pytest.mark.parametrize("sky", [0, 10])
def test_a_splat_file_near_the_origin_is_not_warned_about(tmp_path, capsys, sky):
    near = _room_ply(tmp_path, 0.0, "near.ply", sky=sky)  # 10 of 1306 Gaussians far away: the median decides
    capsys.readouterr()
    assert main(["view", str(near), "--screenshot", str(tmp_path / "shot.png"), "--screenshot-size", "12x16",
                 "--device", "cpu"]) == 0
    assert not any("from the origin" in line for line in _notes(capsys, "view"))
