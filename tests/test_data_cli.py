"""`cylindersplat data synth / preview / info` end to end on a tiny dataset, and their input errors."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from cylindersplat.cli import main
from cylindersplat.data import SyntheticDataset
from cylindersplat.data.depth_prior import NoPrior


def test_synth_preview_info_roundtrip(tmp_path, capsys):
    out = tmp_path / "synth"
    assert main(["data", "synth", "--out", str(out), "--scenes", "2", "--resolution", "32x64",
                 "--frames", "3", "--spacing", "0.25:0.5", "--seed", "3"]) == 0
    meta = json.loads((out / "meta.json").read_text())
    assert meta  # the loader's marker file exists and is JSON

    ds = SyntheticDataset(out, views="two_view", depth_prior=NoPrior())
    assert len(ds) == 2
    sample = ds[0]
    assert sample.context_images.shape == (2, 3, 32, 64)
    assert sample.target_images.shape == (1, 3, 32, 64)
    # Frames lie on a line: the target camera sits between the two contexts.
    centres = [sample.context_poses[0, :3, 3], sample.target_poses[0, :3, 3], sample.context_poses[1, :3, 3]]
    a, m, b = (c.double().numpy() for c in centres)
    assert np.allclose(np.linalg.norm(a - m) + np.linalg.norm(m - b), np.linalg.norm(a - b), atol=1e-5)
    assert 0.25 - 1e-6 <= np.linalg.norm(a - m) <= 0.5 + 1e-6

    sheet = tmp_path / "sheet.png"
    assert main(["data", "preview", "--data", str(out), "--out", str(sheet), "--count", "2", "--height", "16"]) == 0
    image = np.asarray(Image.open(sheet))
    # 2 rows of 3 frames x (RGB, depth) tiles of 16x32 with 4-pixel gaps.
    assert image.shape == (2 * 16 + 4, 6 * 32 + 5 * 4, 3)

    assert main(["data", "info", "--data", str(out), "--count", "1"]) == 0
    assert "2 examples" in capsys.readouterr().out


@pytest.mark.parametrize("args, fragment", [
    (["--resolution", "64x64"], "W == 2H"),
    (["--spacing", "1:0.5"], "MIN <= MAX"),
    (["--target-offset", "1:0.5"], "MIN <= MAX"),  # the disocclusion options (test_data_synth_occlusion.py)
    (["--layouts", "room,castle"], "unknown layout"),
    (["--profile", "nope"], "invalid choice"),
])
def test_synth_rejects_bad_arguments(tmp_path, capsys, args, fragment):
    with pytest.raises(SystemExit):
        main(["data", "synth", "--out", str(tmp_path), "--scenes", "1", *args])
    assert fragment in capsys.readouterr().err


def test_preview_of_unknown_folder_is_a_clear_error(tmp_path, capsys):
    assert main(["data", "preview", "--data", str(tmp_path), "--out", str(tmp_path / "x.png")]) == 1
    assert "neither a synthetic dataset" in capsys.readouterr().err
