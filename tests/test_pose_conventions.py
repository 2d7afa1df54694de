"""One module owns every pose convention: the same camera written in each convention comes back the same, and
reading poses files needs no module above the data layer."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest
import torch

from cylindersplat.data.poses import POSE_CONVENTIONS, parse_pose_matrix, to_opencv_c2w


def _camera() -> torch.Tensor:
    """An OpenCV c2w: turned 30° about +y and 10° about +x, at (1, -0.5, 2)."""
    a, b = math.radians(30), math.radians(10)
    yaw = torch.tensor([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]], dtype=torch.float64)
    pitch = torch.tensor([[1, 0, 0], [0, math.cos(b), -math.sin(b)], [0, math.sin(b), math.cos(b)]],
                         dtype=torch.float64)
    c2w = torch.eye(4, dtype=torch.float64)
    c2w[:3, :3], c2w[:3, 3] = yaw @ pitch, torch.tensor([1.0, -0.5, 2.0], dtype=torch.float64)
    return c2w


def test_every_convention_gives_back_the_opencv_camera():
    c2w = _camera()
    flip = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))  # OpenGL camera: +y up, +z back
    written = {"opencv_c2w": c2w, "opengl_c2w": c2w @ flip, "blender_c2w": c2w @ flip,
               "opencv_w2c": torch.linalg.inv(c2w), "opengl_w2c": torch.linalg.inv(c2w @ flip)}
    assert set(written) == set(POSE_CONVENTIONS)
    for convention, matrix in written.items():
        back = to_opencv_c2w(parse_pose_matrix(matrix.tolist(), convention), convention)
        torch.testing.assert_close(back, c2w, atol=1e-12, rtol=0, msg=convention)
    # The camera's forward axis (+z in OpenCV) is the world direction it looks along, whatever the file said.
    forward = to_opencv_c2w(written["opengl_w2c"], "opengl_w2c")[:3, 2]
    torch.testing.assert_close(forward, c2w[:3, 2], atol=1e-12, rtol=0)
    with pytest.raises(ValueError, match="unknown pose convention 'colmap'"):
        to_opencv_c2w(c2w, "colmap")
    with pytest.raises(ValueError, match="3x4 or 4x4 list of numbers"):
        parse_pose_matrix([["1", 0, 0, 0]], "x")


def test_reading_poses_files_needs_nothing_above_the_data_layer(tmp_path):
    flip = torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=torch.float64))
    (tmp_path / "transforms.json").write_text(json.dumps({
        "camera_model": "EQUIRECTANGULAR",
        "frames": [{"file_path": "a.png", "transform_matrix": (_camera() @ flip).tolist()}]}))
    code = ("import sys; from cylindersplat.data.folder import read_poses_file; "
            f"entries = read_poses_file({str(tmp_path / 'transforms.json')!r}); "
            "print(sorted(m for m in sys.modules if m.startswith('cylindersplat.inference')), "
            "entries[0][1][0, 3].item())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out[0] == "[]" and float(out[1]) == pytest.approx(1.0)  # read, and no upward import of the inference layer
