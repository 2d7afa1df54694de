"""Issue 27, item 3 (plausibility): scenes whose size says "unit mistake" are warned about in one line that names
the bound, the likely mistake and its fix (the input is still used: outdoor scenes can be 100 m deep)."""

import json
import warnings

import pytest
import torch

from cylindersplat.validation import ScaleWarning, check_scene_scale

FIXES = ('"depth_scale" of poses.json (depth file units per metre; .npy in metres)',
         "cylindersplat data import-poses --scale (metres per unit), or scale the translations in poses.json")
SILENCE = "--skip-plausibility-checks silences this"


def _scene(depth_m: float, spacing_m: float, views: int = 2):
    depths = torch.full((views, 4, 8), depth_m)
    depths[:, 0] = 0.0  # unknown pixels do not count
    c2w = torch.eye(4).repeat(views, 1, 1)
    c2w[1:, 0, 3] = spacing_m
    return depths, c2w


def _warnings(depth_m, spacing_m, views=2) -> list[str]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_scene_scale(*_scene(depth_m, spacing_m, views), "scene")
    assert all(w.category is ScaleWarning for w in caught)
    return [str(w.message) for w in caught]


@pytest.mark.parametrize("depth_m,spacing_m,message", [
    (250.0, 1.0, "scene: median scene depth 250 m is beyond 100 m, deeper than any indoor room; if the scene is "
                 f"indoors, the depth is in the wrong units (fix {FIXES[0]}); {SILENCE}"),
    (0.003 * 10, 0.001, "scene: median scene depth 3 cm is below 5 cm, smaller than any room: a scene scaled by 1e-3 "
                        f"(kilometres read as metres?); give depth in metres (fix {FIXES[0]}) and poses in metres "
                        f"({FIXES[1]}); {SILENCE}"),
    (3.0, 0.002, "scene: the cameras are at most 0.002 m apart around a median depth of 3 m (0.00067x, below 0.001x): "
                 f"poses in kilometres or of arbitrary SfM scale? give them in metres ({FIXES[1]}); {SILENCE}"),
    (3.0, 500.0, "scene: the cameras are up to 500 m apart around a median depth of 3 m (167x, above 100x): poses in "
                 f"millimetres or of arbitrary SfM scale? give them in metres ({FIXES[1]}); {SILENCE}"),
])
def test_an_implausible_scene_scale_is_one_warning(depth_m, spacing_m, message):
    assert _warnings(depth_m, spacing_m) == [message]


@pytest.mark.parametrize("depth_m,spacing_m,views", [(3.0, 1.0, 2), (60.0, 20.0, 2), (0.5, 0.01, 2), (3.0, 0.0, 1),
                                                     (0.0, 1.0, 2)])
def test_plausible_scenes_are_not_warned_about(depth_m, spacing_m, views):
    assert _warnings(depth_m, spacing_m, views) == []


def test_export_says_which_folder_has_depth_in_the_wrong_units(panorama_folder, tiny_checkpoint, tmp_path, capsys):
    """A depth_scale 100 times too small (10 units per metre on millimetre PNGs): 2 m rooms read as 200 m."""
    from cylindersplat.cli import main
    from cylindersplat.inference import load_panorama_folder

    folder = panorama_folder[0]
    poses = json.loads((folder / "poses.json").read_text())
    (folder / "poses.json").write_text(json.dumps({**poses, "depth_scale": 10}))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        depths = load_panorama_folder(folder, (16, 32)).depths
    median = float(depths[depths > 0].median())
    args = ["export", "--input", str(folder), "--checkpoint", str(tiny_checkpoint), "--resolution", "16x32",
            "--out", str(tmp_path / "g.ply"), "--device", "cpu"]
    assert main(args) == 0
    notes = [line for line in capsys.readouterr().err.splitlines() if "note:" in line]
    assert notes == [f"cylindersplat export: note: {folder}: median scene depth {median:.3g} m is beyond 100 m, deeper "
                     "than any indoor room; if the scene is indoors, the depth is in the wrong units (fix "
                     f"{FIXES[0]}); {SILENCE}"]
    assert main(args + ["--skip-plausibility-checks"]) == 0
    assert "note:" not in capsys.readouterr().err
