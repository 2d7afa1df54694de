"""A new user's first run on real panoramas, as the docs tell it (issue 37): the real Matterport3D triplet of the
fixtures copied into a folder as a user has it (RGB panoramas and their depth, docs/inference.md "Input folder"), then
`data poses` -> `render` -> `export` -> `view --screenshot`, each in its own process at its defaults.

The README's two commands (`bash scripts/demo.sh`, `bash scripts/test.sh`) install the package this test runs in;
the commands below are those of docs/inference.md, "Unposed panoramas". All sizes are the defaults (on the idle
2-core dev machine, 2026-11-27: data poses ~4 s, render ~6 s, export ~3.5 s, view --screenshot at 480x640 ~2.6 s;
earlier figures of 6 / 17 / 18 / 26 s were taken under the load of other jobs).
"""

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

pytestmark = pytest.mark.slow

COMMAND_TIMEOUT_S = 600  # each command; all four take about a minute together on 2 shared cores


def _hashes(folder: Path) -> dict[str, str]:
    """Relative path -> sha256 of every file under ``folder``."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _cylindersplat(*args: str, cwd: Path) -> str:
    """Run ``python -m cylindersplat ARGS`` as a user would; its stdout + stderr (fails the test unless exit 0)."""
    run = subprocess.run([sys.executable, "-m", "cylindersplat", *args], cwd=cwd, capture_output=True, text=True,
                         timeout=COMMAND_TIMEOUT_S)
    output = run.stdout + run.stderr
    assert run.returncode == 0, f"cylindersplat {' '.join(args)} exited {run.returncode}:\n{output}"
    assert "Traceback" not in output, output
    return output


def test_a_new_user_on_the_real_triplet(pano_grf_fixture, tmp_path):
    pytest.importorskip("pycolmap", reason="data poses needs pycolmap: pip install 'cylindersplat[sfm]'")
    from cylindersplat.gaussians import load_ply

    scene = tmp_path / "my_scene"
    scene.mkdir()
    for frame in ("00", "01", "02"):  # the user's panoramas and depth (16-bit PNG, mm), no poses
        shutil.copy(pano_grf_fixture / "00000007" / frame / "rgb.png", scene / f"pano_{frame}.png")
        shutil.copy(pano_grf_fixture / "00000007" / frame / "depth.png", scene / f"pano_{frame}_depth.png")
    before = _hashes(scene)

    assert "registered 3 of 3 panoramas" in _cylindersplat("data", "poses", "my_scene", cwd=tmp_path)
    _cylindersplat("render", "--input", "my_scene", "--out", "outputs/my_scene", cwd=tmp_path)
    _cylindersplat("export", "--input", "my_scene", "--out", "outputs/my_scene/scene.ply", cwd=tmp_path)
    _cylindersplat("view", "outputs/my_scene/scene.ply", "--screenshot", "outputs/my_scene/shot.png", cwd=tmp_path)

    # Poses: three finite c2w, the first at the origin, in metres (the fixture's cameras are 0.5 m apart on a line).
    frames = json.loads((scene / "poses.json").read_text())["frames"]
    c2w = np.array([f["c2w"] for f in sorted(frames, key=lambda f: f["image"])], dtype=np.float64)
    assert c2w.shape == (3, 4, 4) and np.isfinite(c2w).all()
    np.testing.assert_allclose(c2w[0], np.eye(4), atol=1e-9)
    assert np.linalg.norm(c2w[2, :3, 3] - c2w[0, :3, 3]) == pytest.approx(1.0, rel=0.05)

    # Nothing the user had changed; the only new things are poses.json and the COLMAP model.
    after = _hashes(scene)
    assert {name: after.get(name) for name in before} == before
    new = set(after) - set(before)
    assert "poses.json" in new and all(n == "poses.json" or n.startswith("sparse/") for n in new), sorted(new)

    out = tmp_path / "outputs" / "my_scene"
    views = sorted((out / "views").glob("view_*_rgb.png"))
    assert views and (out / "views" / "poses.json").is_file()
    for png in views + sorted((out / "views").glob("view_*_depth.png")):
        assert np.asarray(Image.open(png)).astype(np.float64).std() > 5.0, png  # a picture, not one colour
    assert (out / "gaussians.ply").is_file() and (out / "flythrough.gif").is_file()

    gaussians = load_ply(out / "scene.ply")
    assert gaussians.means.shape[0] > 1000 and np.isfinite(gaussians.means.numpy()).all()

    shot = np.asarray(Image.open(out / "shot.png")).astype(np.float64)
    assert shot.shape[:2] == (480, 640)  # view's documented default size
    assert shot[..., :3].std() > 15.0  # the scene, not a near-uniform colour (issue 37: beige at 240x320)
