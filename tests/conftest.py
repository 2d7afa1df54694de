"""Test-suite set-up and the fixtures shared by several modules.

Helpers that are plain functions (no pytest machinery) live next to this file: ``render_scenes.py``
(small Gaussian scenes and poses) and ``model_inputs.py`` (random model inputs).

Slow tests (over ~8 s on 2 CPU cores) carry ``@pytest.mark.slow``; ``pytest -m "not slow"`` skips them
for a quick local run, CI (``scripts/test.sh``) runs everything.
"""

import os
from pathlib import Path

import pytest
import torch

# Without a GPU the Triton backend's kernels run in Triton's CPU interpreter. The variable must be set
# before the kernels are first imported, i.e. before any test renders with backend="triton".
if not torch.cuda.is_available():
    os.environ.setdefault("TRITON_INTERPRET", "1")

# The first numba render of a run compiles (or loads) the CPU kernels: no timer notice in the middle of whichever test
# that is (tests/test_render_numba.py tests the notice itself).
from cylindersplat.render import numba_backend  # noqa: E402

numba_backend.COMPILE_NOTICE_AFTER_S = None

# The real-data fixtures: $CYLINDERSPLAT_FIXTURES, else <the clone's parent>/shared/fixtures (where this project's
# sessions share them). They hold pano_grf/<sequence folder>/00000007: three real PanoGRF (Matterport3D)
# panoramas at 1024x512, the sample PanSplat ships; the tests that read them skip where it is absent (a fresh clone).
FIXTURES_ENV = "CYLINDERSPLAT_FIXTURES"
FIXTURES_DEFAULT = Path(__file__).resolve().parents[1].parent / "shared" / "fixtures"
FIXTURES = Path(os.environ.get(FIXTURES_ENV) or FIXTURES_DEFAULT).expanduser()
PANO_GRF_SEQUENCE = "pano_grf/png_render_test_1024x512_seq_len_3_m3d_dist_0.5"
PANO_GRF_FIXTURE = FIXTURES / PANO_GRF_SEQUENCE
FIXTURE_SOURCE = f"https://github.com/chengzhag/PanSplat, folder datasets/{PANO_GRF_SEQUENCE}"


def fixture_skip_reason(fixture: Path = PANO_GRF_FIXTURE) -> str | None:
    """One line saying where the real fixture was looked for and how to get it, or None where it is there."""
    if (fixture / "00000007").is_dir():
        return None
    return (f"real fixture missing: {fixture / '00000007'}; copy it from {FIXTURE_SOURCE} and set {FIXTURES_ENV} to "
            "the folder holding pano_grf/")


@pytest.fixture(scope="session")
def pano_grf_fixture() -> Path:
    """The real PanoGRF fixture folder (skips the test where it is missing, saying how to get it)."""
    reason = fixture_skip_reason()
    if reason:
        pytest.skip(reason)
    return PANO_GRF_FIXTURE


@pytest.fixture(scope="session")
def synth_dataset(tmp_path_factory):
    """``synth_dataset(scenes, seed)`` -> the folder of a small procedural dataset (32x64, 3 frames per
    sequence 0.3-0.5 m apart), written once per session for each ``(scenes, seed)``. Read-only for tests."""
    from cylindersplat.data.synth import SequenceConfig, write_synthetic_dataset

    made: dict[tuple[int, int], Path] = {}

    def make(scenes: int, seed: int) -> Path:
        if (scenes, seed) not in made:
            root = tmp_path_factory.mktemp(f"synth_{scenes}_{seed}")
            write_synthetic_dataset(root, scenes, (32, 64), SequenceConfig(frames=3, spacing=(0.3, 0.5)), seed=seed,
                                    progress=False)
            made[scenes, seed] = root
        return made[scenes, seed]

    return make


@pytest.fixture(scope="module")
def tiny_model():
    """An untrained ``tiny_paper`` model (seed 0), one per test module."""
    from cylindersplat.model import from_config

    torch.manual_seed(0)
    return from_config("tiny_paper")


@pytest.fixture()
def panorama_folder(tmp_path):
    """A user input folder (docs/inference.md) of two posed 16x32 panoramas with depth PNGs:
    ``(path, images (2, 3, 16, 32), depths (2, 16, 32), c2w (2, 4, 4))``."""
    from cylindersplat.inference import write_panorama_folder
    from render_scenes import yaw_pose

    torch.manual_seed(0)
    images = torch.rand(2, 3, 16, 32)
    depths = torch.rand(2, 16, 32) * 3 + 0.5
    poses = torch.stack([yaw_pose(0.0, dtype=torch.float32), yaw_pose(0.3, (0.5, 0.0, 0.2), dtype=torch.float32)])
    return write_panorama_folder(tmp_path / "scene", images, poses, depths), images, depths, poses


@pytest.fixture()
def tiny_checkpoint(tmp_path) -> Path:
    """Weights of an untrained ``tiny_paper`` model (seed 0) as written by ``cylindersplat train``."""
    from cylindersplat.model import from_config, save_model

    torch.manual_seed(0)
    path = tmp_path / "tiny.safetensors"
    save_model(from_config("tiny_paper"), path)
    return path
