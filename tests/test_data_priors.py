"""Depth priors: simulated (seeded degradation), files, registry and foundation-model adapters."""

import numpy as np
import pytest
import torch

from cylindersplat.data.depth_prior import (
    DEPTH_PRIORS,
    FilePrior,
    GroundTruthPrior,
    PriorQuery,
    SimulatedPrior,
    SimulatedPriorConfig,
    UniK3DAdapter,
    make_depth_prior,
)
from cylindersplat.data.io import write_depth_png


def _query(key="ds/scene/00", gt=True, path=None):
    depth = torch.linspace(1.0, 5.0, 64 * 128).view(64, 128)
    depth[:4] = 0.0
    return PriorQuery(torch.rand(3, 64, 128), depth if gt else None, path, key)


def test_simulated_prior_is_seeded_and_degraded():
    prior = SimulatedPrior(SimulatedPriorConfig(scale_sigma=0.1, blur_sigma=1.0, noise_sigma=0.02, hole_fraction=0.05))
    q = _query()
    a, b = prior(q), prior(q)
    assert torch.equal(a, b)
    assert not torch.equal(a, prior(_query(key="ds/scene/01")))
    assert not torch.equal(a, SimulatedPrior(prior.config, seed=1)(q))
    gt = q.gt_depth
    assert (a[:4] == 0).all()  # invalid ground truth stays invalid
    holes = ((a == 0) & (gt > 0)).float().sum() / (gt > 0).sum()
    assert 0.01 < holes < 0.1
    ratio = (a / gt)[(a > 0) & (gt > 0)]
    assert 0.6 < ratio.median() < 1.5 and ratio.std() < 0.1  # mostly a global scale + small noise


def test_simulated_prior_zero_degradation_is_identity():
    cfg = SimulatedPriorConfig(scale_sigma=0.0, blur_sigma=0.0, noise_sigma=0.0, hole_fraction=0.0)
    q = _query()
    assert torch.allclose(SimulatedPrior(cfg)(q), q.gt_depth)
    with pytest.raises(ValueError, match="ground-truth"):
        SimulatedPrior()(_query(gt=False))
    with pytest.raises(ValueError, match="ground-truth"):
        GroundTruthPrior()(_query(gt=False))


def test_file_prior_png_npy_and_mirror(tmp_path):
    frame = tmp_path / "data" / "s1" / "00"
    frame.mkdir(parents=True)
    rgb = frame / "rgb.png"
    prior = FilePrior()
    with pytest.raises(FileNotFoundError, match="depth_prior"):
        prior(_query(path=rgb))
    np.save(frame / "depth_prior.npy", np.full((64, 128), 2.5, np.float32))
    assert torch.allclose(prior(_query(path=rgb)), torch.full((64, 128), 2.5))
    write_depth_png(frame / "depth_prior.png", torch.full((128, 256), 1.25))  # PNG wins, resized to the query
    assert torch.allclose(prior(_query(path=rgb)), torch.full((64, 128), 1.25))
    mirror = tmp_path / "priors" / "s1" / "00"
    mirror.mkdir(parents=True)
    np.save(mirror / "mono.npy", np.full((64, 128), 3.0, np.float32))
    mirrored = FilePrior("mono", root=tmp_path / "priors", dataset_root=tmp_path / "data")
    assert torch.allclose(mirrored(_query(path=rgb)), torch.full((64, 128), 3.0))


def test_registry_and_adapters(tmp_path):
    assert {"none", "gt", "simulated", "file", "unik3d", "depth_anywhere", "unifuse"} <= set(DEPTH_PRIORS)
    assert isinstance(make_depth_prior("simulated", seed=3), SimulatedPrior)
    with pytest.raises(ValueError, match="unknown depth prior"):
        make_depth_prior("midas")
    # Packages are not installed here: a clear ImportError naming the package and how to install it.
    for name in ("unik3d", "depth_anywhere", "unifuse"):
        with pytest.raises(ImportError, match="pip install|install"):
            make_depth_prior(name, weights=tmp_path / "w.pth")


def test_adapter_weight_checks(tmp_path, monkeypatch):
    monkeypatch.setattr(UniK3DAdapter, "package", "json")  # pretend the package is importable
    with pytest.raises(FileNotFoundError, match="local weights"):
        UniK3DAdapter()
    with pytest.raises(FileNotFoundError, match="not found"):
        UniK3DAdapter(weights=tmp_path / "missing.pth")
    (tmp_path / "w.pth").write_bytes(b"")
    adapter = UniK3DAdapter(weights=tmp_path / "w.pth")
    with pytest.raises(NotImplementedError, match="file"):
        adapter(_query())
