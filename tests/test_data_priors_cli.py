"""`cylindersplat data priors`: a depth network run once over a dataset, stored as files that `file:NAME` reads.

The networks are tiny modules built here and exported with torch.export / TorchScript; the datasets are
the real Matterport3D triplet of the project's fixtures (PanoGRF layout, read-only: written elsewhere
with --out), a tiny synthetic set and an input folder."""

from __future__ import annotations

import hashlib
import json
from datetime import datetime
from pathlib import Path

import numpy as np
import pytest
import torch

from conftest import PANO_GRF_FIXTURE as FIXTURE  # $CYLINDERSPLAT_FIXTURES or ../shared/fixtures
from conftest import fixture_skip_reason
from cylindersplat.cli import main
from cylindersplat.data import PanoGRFDataset, SyntheticDataset
from cylindersplat.data.depth_prior import NoPrior, parse_depth_prior
from cylindersplat.data.io import read_depth_npy, read_depth_png, read_rgb, write_depth_png


class DepthNet(torch.nn.Module):
    """Radial depth 0.5-4.5 m from the image: (B, 3, H, W) -> (B, 1, H, W)."""

    def __init__(self, offset: float = 0.5):
        super().__init__()
        self.offset = offset

    def forward(self, x):
        return self.offset + 4.0 * x.mean(1, keepdim=True) + 0.1 * x[:, :1]


def export_pt2(path: Path, size=(32, 64), offset: float = 0.5) -> Path:
    """torch.export at batch size 1 (static shapes): `data priors` falls back to one image per call."""
    torch.export.save(torch.export.export(DepthNet(offset), (torch.rand(1, 3, *size),)), str(path))
    return path


def export_torchscript(path: Path, offset: float = 0.5) -> Path:
    with pytest.warns(DeprecationWarning):
        torch.jit.save(torch.jit.script(DepthNet(offset)), str(path))
    return path


def expected_depth(rgb: Path, size, offset: float = 0.5) -> torch.Tensor:
    with torch.no_grad():
        return DepthNet(offset)(read_rgb(rgb, size=size)[None])[0, 0]


@pytest.fixture(scope="module")
def synth(tmp_path_factory):
    out = tmp_path_factory.mktemp("synth_priors") / "synth"
    assert main(["data", "synth", "--out", str(out), "--scenes", "2", "--resolution", "16x32", "--frames", "3"]) == 0
    return out


def test_priors_on_the_real_fixture(tmp_path, capsys):
    if fixture_skip_reason():
        pytest.skip(fixture_skip_reason())
    net = export_pt2(tmp_path / "net.pt2")
    tree = tmp_path / "priors" / "mono"
    args = ["data", "priors", "--data", str(FIXTURE), "--net", f"exported:{net}", "--out", str(tree),
            "--resolution", "32x64", "--batch-size", "2", "--device", "cpu"]
    assert main(args) == 0
    assert "3 written, 0 already there" in capsys.readouterr().out
    for frame in ("00", "01", "02"):
        rgb = FIXTURE / "00000007" / frame / "rgb.png"
        stored = read_depth_png(tree / "00000007" / frame / "rgb.png")
        assert stored.shape == (32, 64)
        assert (stored - expected_depth(rgb, (32, 64))).abs().max() <= 5e-4 + 1e-6  # PNG millimetres: within 1 mm
    sidecar = json.loads((tree / "prior.json").read_text())
    assert sidecar["network"] == f"exported:{net}" and sidecar["format"] == "png" and sidecar["resolution"] == [32, 64]
    assert sidecar["identity"]["sha256"] == hashlib.sha256(net.read_bytes()).hexdigest()
    assert sidecar["identity"]["torch"] == torch.__version__ and sidecar["complete"] and sidecar["frames"] == 3
    assert sidecar["layout"] == "pano_grf" and datetime.fromisoformat(sidecar["created"])
    # Second run: nothing to do.
    assert main(args) == 0
    assert "0 written, 3 already there" in capsys.readouterr().out
    # A network exported with fixed shapes at another resolution: one line pointing to --net-size, and the
    # failed attempt does not block the next one.
    big = ["data", "priors", "--data", str(FIXTURE), "--net", f"exported:{net}", "--out", str(tmp_path / "big"),
           "--resolution", "64x128", "--device", "cpu"]
    assert main(big) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--net-size" in err[0]
    assert main(big + ["--net-size", "32x64"]) == 0
    assert "3 written" in capsys.readouterr().out
    assert read_depth_png(tmp_path / "big" / "00000007" / "00" / "rgb.png").shape == (64, 128)
    # file:DIR reads exactly these files; what reaches the model is the network's depth.
    ds = PanoGRFDataset(FIXTURE, resolution=(32, 64), depth_prior=parse_depth_prior(f"file:{tree}"))
    sample = ds[0]
    for k, frame in enumerate(("00", "02")):
        want = expected_depth(FIXTURE / "00000007" / frame / "rgb.png", (32, 64))
        assert (sample.context_priors[k] - want).abs().max() <= 5e-4 + 1e-6


def test_priors_on_synthetic_data_npy_batched_resume_overwrite(synth, tmp_path, capsys):
    net = export_torchscript(tmp_path / "net.pt")
    args = ["data", "priors", "--data", str(synth), "--net", f"exported:{net}", "--name", "mono", "--format", "npy",
            "--batch-size", "4", "--device", "cpu"]
    assert main(args) == 0
    assert "6 written" in capsys.readouterr().out
    tree = synth / "priors" / "mono"
    files = sorted(tree.rglob("*.npy"))
    assert len(files) == 6 and all(f.name == "rgb.npy" for f in files)
    for f in files:
        rgb = synth / f.relative_to(tree).with_suffix(".png")
        torch.testing.assert_close(read_depth_npy(f), expected_depth(rgb, None))
    sidecar = json.loads((tree / "prior.json").read_text())
    assert sidecar["format"] == "npy" and sidecar["resolution"] is None and sidecar["name"] == "mono"
    # file:mono finds them (the synthetic loader's own scene listing ignores the priors folder).
    ds = SyntheticDataset(synth, depth_prior=parse_depth_prior("file:mono"))
    sample = ds[1]
    rgb = synth / ds.scenes[1] / "00" / "rgb.png"
    torch.testing.assert_close(sample.context_priors[0], expected_depth(rgb, None))
    # Resume: a half-finished tree is completed, the rest skipped.
    files[0].unlink()
    assert main(args) == 0
    assert "1 written, 5 already there" in capsys.readouterr().out
    # Another network under the same name: refused unless --overwrite.
    other = export_torchscript(tmp_path / "other.pt", offset=1.5)
    other_args = ["data", "priors", "--data", str(synth), "--net", f"exported:{other}", "--name", "mono",
                  "--format", "npy", "--device", "cpu"]
    assert main(other_args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--overwrite" in err[0]
    assert main(other_args + ["--overwrite"]) == 0
    assert "6 written" in capsys.readouterr().out
    torch.testing.assert_close(read_depth_npy(files[1]),
                               expected_depth(synth / files[1].relative_to(tree).with_suffix(".png"), None, 1.5))


@pytest.mark.parametrize("net, fragment", [
    ("exported:{tmp}/missing.pt2", "no exported model"),
    ("unik3d:{tmp}/unik3d-vitl", "pip install"),
    ("depth_anything_v2:depth-anything/Depth-Anything-V2-Small-hf", "pip install transformers"),
    ("constant:2.0", "not a depth network"),
    ("depth_anywhere:{tmp}/net.pt2", "exported:NET.pt2"),
])
def test_priors_errors_are_one_line(synth, tmp_path, capsys, net, fragment):
    import importlib.util

    package = {"unik3d": "unik3d", "depth_anything_v2": "transformers"}.get(net.partition(":")[0])
    if package and importlib.util.find_spec(package) is not None:
        pytest.skip(f"{package} is installed here")
    code = main(["data", "priors", "--data", str(synth), "--net", net.format(tmp=tmp_path), "--name", "x",
                 "--device", "cpu"])
    assert code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0] and "Traceback" not in err[0], err
    assert not (synth / "priors" / "x" / "prior.json").exists()


def test_priors_for_an_input_folder_and_no_silent_zeros(tmp_path, capsys):
    from cylindersplat.inference import load_panorama_folder, write_panorama_folder

    folder = write_panorama_folder(tmp_path / "scene", torch.rand(2, 3, 16, 32), torch.eye(4).expand(2, 4, 4).clone())
    net = export_torchscript(tmp_path / "net.pt")
    assert main(["data", "priors", "--data", str(folder), "--net", f"exported:{net}", "--name", "mono",
                 "--device", "cpu"]) == 0
    capsys.readouterr()
    assert (folder / "priors" / "mono" / "pano_00.png").is_file()
    inputs = load_panorama_folder(folder, (16, 32), depth_prior=parse_depth_prior("file:mono"))
    for i in range(2):
        want = expected_depth(folder / f"pano_{i:02d}.png", None)
        assert (inputs.depths[i] - want).abs().max() <= 5e-4 + 1e-6
    # An all-zero depth file is refused (one line naming it) unless the prior is none, asked for by name.
    write_depth_png(folder / "pano_00_depth.png", torch.zeros(16, 32))
    with pytest.raises(ValueError, match="pano_00_depth.png has no positive depth"):
        load_panorama_folder(folder, (16, 32), depth_prior=parse_depth_prior("file:mono"))
    assert load_panorama_folder(folder, (16, 32), depth_prior=NoPrior()).depths[0].eq(0).all()


def test_all_zero_prior_files_are_refused(synth, tmp_path):
    tree = tmp_path / "zeros"
    for rgb in synth.glob("*/*/rgb.png"):
        write_depth_png(tree / rgb.relative_to(synth), torch.zeros(16, 32))
    ds = SyntheticDataset(synth, depth_prior=parse_depth_prior(f"file:{tree}"))
    with pytest.raises(ValueError, match="has no positive depth"):
        ds[0]
    assert np.isfinite(SyntheticDataset(synth, depth_prior=NoPrior())[0].context_priors.numpy()).all()
