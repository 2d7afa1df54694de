"""Splat formats through PlayCanvas splat-transform (.spz, .compressed.ply, .sog): written, read back and
compared within each format's quantisation; the files' headers checked independently."""

from __future__ import annotations

import gzip
import struct

import numpy as np
import pytest
import torch

from cylindersplat.cli import main
from cylindersplat.gaussians import Gaussians, formats, load_gaussians, save_gaussians
from cylindersplat.gaussians.formats import SPLAT_TRANSFORM_ENV, find_splat_transform, splat_format

needs_tool = pytest.mark.skipif(find_splat_transform() is None, reason="splat-transform is not installed: "
                                "bash scripts/install_optional.sh formats puts it into the "
                                "clone's .tools/ (Node.js >= 20)")

# Largest error each format may make (its quantisation): position (m), DC colour, opacity, log-scale, SH bands 1+
# (None: SOG stores SH as a k-means palette, lossy without a per-value bound).
TOLERANCES = {
    # 12 fractional bits, 8-bit
    ".spz": dict(position=5e-4, rgb=0.005, opacity=0.005, log_scale=1 / 32 + 1e-4, sh_rest=0.04),
    # 11/10-bit in chunk boxes
    ".compressed.ply": dict(position=4e-3, rgb=0.005, opacity=0.005, log_scale=0.01, sh_rest=0.02),
    ".sog": dict(position=1e-3, rgb=0.01, opacity=0.005, log_scale=0.03, sh_rest=None),  # 16-bit positions, codebooks
}


def _scene(n: int = 600, seed: int = 0) -> Gaussians:
    gen = torch.Generator().manual_seed(seed)
    sh = (torch.rand(n, 4, 3, generator=gen) - 0.5) * 0.8  # degree 1, inside SPZ's SH range
    sh[:, 0] = (torch.rand(n, 3, generator=gen) - 0.5) * 0.9 / 0.28209479177387814  # DC colours in (0.05, 0.95)
    return Gaussians(
        means=(torch.rand(n, 3, generator=gen) - 0.5) * torch.tensor([4.0, 3.0, 4.0]),
        scales=torch.empty(n, 3).uniform_(-5, -1, generator=gen).exp(),
        rotations=torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=-1),
        opacities=torch.rand(n, generator=gen) * 0.98 + 0.01,
        sh=sh,
    )


def _match(original: Gaussians, read: Gaussians) -> Gaussians:
    """``original`` reordered like ``read`` (the compressed formats reorder Gaussians spatially)."""
    from scipy.spatial import cKDTree

    _, index = cKDTree(original.means.numpy()).query(read.means.numpy())
    assert len(np.unique(index)) == len(read) == len(original)  # one to one
    return original[torch.from_numpy(index)]


def test_format_names():
    assert splat_format("a/b.compressed.ply") == ".compressed.ply" and splat_format("B.PLY") == ".ply"
    assert splat_format("x.spz") == ".spz" and splat_format("x.sog") == ".sog" and splat_format("x.splat") == ".splat"
    with pytest.raises(ValueError, match="unknown splat format"):
        splat_format("x.obj")


def test_splat_transform_is_found_in_the_clones_tools_folder(tmp_path, monkeypatch):
    """Where scripts/install_optional.sh formats puts it by default: the clone's .tools/bin, after PATH."""
    monkeypatch.delenv(SPLAT_TRANSFORM_ENV, raising=False)
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    tool = tmp_path / ".tools" / "bin" / "splat-transform"
    tool.parent.mkdir(parents=True)
    tool.write_text("#!/bin/sh\n")
    tool.chmod(0o755)
    assert (formats.PROJECT_TOOLS.parent / "pyproject.toml").is_file()  # this clone (an editable install)
    monkeypatch.setattr(formats, "PROJECT_TOOLS", tmp_path / ".tools")
    assert find_splat_transform() == [str(tool)]


def test_missing_splat_transform_is_one_line_naming_the_install(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv(SPLAT_TRANSFORM_ENV, raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.setattr(formats, "PROJECT_TOOLS", tmp_path / ".tools")
    with pytest.raises(FileNotFoundError, match="npm install -g @playcanvas/splat-transform"):
        save_gaussians(_scene(10), tmp_path / "x.spz")
    # export checks before reconstructing anything (input and checkpoint need not exist yet)
    assert main(["export", "--input", str(tmp_path), "--checkpoint", str(tmp_path / "m.safetensors"),
                 "--out", str(tmp_path / "x.compressed.ply")]) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "splat-transform" in err and "npm install" in err
    assert not list(tmp_path.glob("*.compressed.ply"))


@needs_tool
@pytest.mark.parametrize("fmt", [".spz", ".compressed.ply", ".sog"])
def test_write_and_read_back_within_quantisation(tmp_path, fmt):
    g = _scene()
    path = save_gaussians(g, tmp_path / f"scene{fmt}")
    assert path.is_file() and sorted(p.name for p in tmp_path.iterdir()) == [path.name]  # nothing else left behind
    read = load_gaussians(path)
    ref = _match(g, read)
    tol = TOLERANCES[fmt]
    assert (read.means - ref.means).abs().max() <= tol["position"]
    assert (read.rgb - ref.rgb).abs().max() <= tol["rgb"]
    assert (read.opacities - ref.opacities).abs().max() <= tol["opacity"]
    assert (read.scales.log() - ref.scales.log()).abs().max() <= tol["log_scale"]
    dots = (torch.nn.functional.normalize(read.rotations, dim=-1) * ref.rotations).sum(-1).abs()
    assert dots.min() >= 0.999  # same rotation (q and -q alike)
    assert read.sh_degree == 1
    if tol["sh_rest"] is not None:
        assert (read.sh[:, 1:] - ref.sh[:, 1:]).abs().max() <= tol["sh_rest"]


def _read_spz_header(path) -> tuple[int, int, int]:
    """(version, number of points, SH degree) from an SPZ file: v4 starts with the plain header, v2/v3 are gzip."""
    data = path.read_bytes()
    if data[:2] == b"\x1f\x8b":
        data = gzip.decompress(data)
    magic, version, points, sh_degree = struct.unpack_from("<IIIB", data)
    assert magic == 0x5053474E  # "NGSP"
    return version, points, sh_degree


@needs_tool
@pytest.mark.parametrize("version", [3, 4])
def test_spz_header_read_independently(tmp_path, version):
    g = _scene(300)
    path = save_gaussians(g, tmp_path / "x.spz", spz_version=version)
    assert _read_spz_header(path) == (version, 300, 1)
    torch.testing.assert_close(load_gaussians(path).means, g.means, atol=5e-4, rtol=0)  # SPZ keeps the order


@needs_tool
def test_compressed_ply_positions_decoded_independently(tmp_path):
    """Decode the PlayCanvas layout with plyfile: chunks of 256 with bounds, 11-10-11 bit positions."""
    from plyfile import PlyData

    g = _scene(700)
    ply = PlyData.read(str(save_gaussians(g, tmp_path / "x.compressed.ply")))
    chunk, vertex = ply["chunk"].data, ply["vertex"].data
    assert len(vertex) == 700 and len(chunk) == 3  # ceil(700 / 256)
    packed = vertex["packed_position"].astype(np.uint64)
    unit = np.stack([(packed >> 21) / 2047.0, ((packed >> 11) & 1023) / 1023.0, (packed & 2047) / 2047.0], axis=-1)
    c = np.arange(700) // 256
    lo = np.stack([chunk["min_x"], chunk["min_y"], chunk["min_z"]], axis=-1)[c]
    hi = np.stack([chunk["max_x"], chunk["max_y"], chunk["max_z"]], axis=-1)[c]
    decoded = Gaussians(torch.from_numpy(lo + unit * (hi - lo)).float(), g.scales, g.rotations, g.opacities, g.sh)
    assert (decoded.means - _match(g, decoded).means).abs().max() <= TOLERANCES[".compressed.ply"]["position"]


@needs_tool
def test_a_compressed_ply_named_ply_is_recognised(tmp_path):
    g = _scene(100)
    path = save_gaussians(g, tmp_path / "x.compressed.ply")
    renamed = path.rename(tmp_path / "plain_name.ply")
    assert len(load_gaussians(renamed)) == 100


@needs_tool
def test_splat_transform_failure_is_reported(tmp_path):
    bad = tmp_path / "bad.spz"
    bad.write_bytes(b"not a splat file")
    with pytest.raises(ValueError, match="splat-transform failed"):
        load_gaussians(bad)


@needs_tool
def test_export_writes_spz(tmp_path, capsys):
    from cylindersplat.geometry import make_c2w
    from cylindersplat.inference import write_panorama_folder
    from cylindersplat.model import from_config, save_model

    torch.manual_seed(0)
    poses = torch.stack([make_c2w(), make_c2w(translation=torch.tensor([0.5, 0.0, 0.2]))])
    folder = write_panorama_folder(tmp_path / "scene", torch.rand(2, 3, 16, 32), poses, torch.rand(2, 16, 32) * 3 + 0.5)
    save_model(from_config("tiny_paper"), tmp_path / "tiny.safetensors")
    common = ["export", "--input", str(folder), "--checkpoint", str(tmp_path / "tiny.safetensors"), "--resolution",
              "16x32",
              "--min-opacity", "0", "--device", "cpu"]
    assert main([*common, "--out", str(tmp_path / "g.spz"), "--spz-version", "3"]) == 0
    assert "Niantic SPZ" in capsys.readouterr().out
    assert main([*common, "--out", str(tmp_path / "g.ply")]) == 0
    n = len(load_gaussians(tmp_path / "g.ply"))
    assert _read_spz_header(tmp_path / "g.spz")[:2] == (3, n)


# --- splat-transform runs with a timeout proportionate to the work ------------------------------------------


def test_the_splat_transform_timeout_grows_with_the_work(monkeypatch):
    from cylindersplat.gaussians.formats import TIMEOUT_ENV, splat_transform_timeout

    monkeypatch.delenv(TIMEOUT_ENV, raising=False)
    assert splat_transform_timeout() == 120  # the floor: Node.js start-up on a busy machine
    assert splat_transform_timeout(gaussians=1_000_000) == pytest.approx(320)
    assert splat_transform_timeout(nbytes=50_000_000) == pytest.approx(620)
    monkeypatch.setenv(TIMEOUT_ENV, "7.5")
    assert splat_transform_timeout(gaussians=10**9) == 7.5
    monkeypatch.setenv(TIMEOUT_ENV, "soon")
    with pytest.raises(ValueError) as info:
        splat_transform_timeout()
    assert str(info.value) == f"{TIMEOUT_ENV}='soon': give splat-transform's timeout in seconds, e.g. 600"


def test_a_hanging_splat_transform_is_stopped_with_one_line(tmp_path, monkeypatch, capsys):
    """A stand-in that never returns, through a child that holds its pipes (as npx's node does)."""
    import sys
    import time

    from cylindersplat.gaussians.formats import TIMEOUT_ENV

    tool = tmp_path / "hanging_splat_transform.py"
    tool.write_text("import subprocess, sys, time\n"
                    "subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)'])\ntime.sleep(600)\n")
    monkeypatch.setenv(SPLAT_TRANSFORM_ENV, f"{sys.executable} {tool}")
    monkeypatch.setenv(TIMEOUT_ENV, "1")
    start = time.monotonic()
    with pytest.raises(ValueError) as info:
        save_gaussians(_scene(10), tmp_path / "g.spz")
    assert time.monotonic() - start < 30  # not the tool's 600 s, nor its child's
    assert str(info.value) == (
        "splat-transform did not finish writing 10 Gaussians to g.spz within 1 s and was stopped; if it is merely "
        f"slow, allow more time ({TIMEOUT_ENV}=SECONDS), else check that `{sys.executable} {tool} --help` answers")
    assert not (tmp_path / "g.spz").exists() and [p.name for p in tmp_path.iterdir()] == [tool.name]
