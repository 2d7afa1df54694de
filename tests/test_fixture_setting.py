"""Where the real-data tests look for the Matterport3D fixture: $CYLINDERSPLAT_FIXTURES, else ../shared/fixtures."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def _conftest_says(env: dict[str, str]) -> list[str]:
    """conftest's fixture folder and its skip line, as a fresh interpreter with ``env`` sees them."""
    code = "import conftest; print(conftest.PANO_GRF_FIXTURE); print(conftest.fixture_skip_reason())"
    environment = {k: v for k, v in os.environ.items() if k != "CYLINDERSPLAT_FIXTURES"} | env
    out = subprocess.run([sys.executable, "-c", code], cwd=TESTS, env=environment, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return out.stdout.splitlines()


def test_the_setting_points_the_real_data_tests_at_a_folder(tmp_path):
    sequence = tmp_path / "pano_grf" / "png_render_test_1024x512_seq_len_3_m3d_dist_0.5"
    (sequence / "00000007").mkdir(parents=True)
    assert _conftest_says({"CYLINDERSPLAT_FIXTURES": str(tmp_path)}) == [str(sequence), "None"]


def test_a_missing_fixture_is_skipped_with_one_line_saying_where_to_get_it(tmp_path):
    missing = tmp_path / "nothing"
    sequence = missing / "pano_grf" / "png_render_test_1024x512_seq_len_3_m3d_dist_0.5"
    assert _conftest_says({"CYLINDERSPLAT_FIXTURES": str(missing)}) == [
        str(sequence),
        f"real fixture missing: {sequence}/00000007; copy it from https://github.com/chengzhag/PanSplat, folder "
        "datasets/pano_grf/png_render_test_1024x512_seq_len_3_m3d_dist_0.5 and set CYLINDERSPLAT_FIXTURES to the "
        "folder holding pano_grf/"]


def test_without_the_setting_the_clones_neighbour_is_used():
    default = TESTS.parents[1] / "shared" / "fixtures" / "pano_grf" / "png_render_test_1024x512_seq_len_3_m3d_dist_0.5"
    assert _conftest_says({})[0] == str(default)
