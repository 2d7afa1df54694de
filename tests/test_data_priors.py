"""Depth priors: simulated (seeded degradation), files, registry and foundation-model adapters."""

import importlib.util
import sys

import numpy as np
import pytest
import torch

from cylindersplat.data.depth_prior import (
    DEPTH_PRIORS,
    ExportedDepthPrior,
    FilePrior,
    GroundTruthPrior,
    PriorQuery,
    SimulatedPrior,
    SimulatedPriorConfig,
    UniK3DAdapter,
    make_depth_prior,
    parse_depth_prior,
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
    assert set(DEPTH_PRIORS) == {"none", "gt", "simulated", "file", "constant", "exported", "unik3d",
                                 "depth_anything_v2",
                                 "degraded", "mixed"}  # degraded:KIND and mixed: issue 34's detail diagnosis
    assert isinstance(make_depth_prior("simulated", seed=3), SimulatedPrior)
    with pytest.raises(ValueError, match="unknown depth prior"):
        make_depth_prior("midas")
    for hollow in ("depth_anywhere", "unifuse"):  # no inference API: they are exported networks (exported:NET.pt2)
        with pytest.raises(ValueError, match="unknown depth prior"):
            parse_depth_prior(f"{hollow}:w.pth")
    # Packages are not installed here: a clear ImportError naming the package and how to install it.
    for name, package in (("unik3d", "unik3d"), ("depth_anything_v2", "transformers")):
        if importlib.util.find_spec(package) is not None:
            continue
        with pytest.raises(ModuleNotFoundError, match=f"pip install.*{package}|{package}.*pip install|install"):
            make_depth_prior(name, weights=tmp_path / "w.pth")


def test_adapter_weight_checks(tmp_path, monkeypatch):
    monkeypatch.setattr(UniK3DAdapter, "package", "json")  # pretend the package is importable
    with pytest.raises(FileNotFoundError, match="needs weights"):
        UniK3DAdapter()
    with pytest.raises(FileNotFoundError, match="not found"):
        UniK3DAdapter(weights=tmp_path / "missing.pth")
    with pytest.raises(FileNotFoundError, match="needs its weights"):
        parse_depth_prior("unik3d")
    (tmp_path / "w.pth").write_bytes(b"")
    assert UniK3DAdapter(weights=tmp_path / "w.pth").weights == tmp_path / "w.pth"
    (tmp_path / "hub" / "models--lpiccinelli--unik3d-vitl" / "snapshots" / "abc").mkdir(parents=True)
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hub"))  # cached: usable offline (tests/test_data_items.py)
    hub = UniK3DAdapter(weights="lpiccinelli/unik3d-vitl")  # a hub id: loaded by the package itself
    assert hub.weights is None and hub.source == "lpiccinelli/unik3d-vitl"


_FAKE_UNIK3D = {
    "unik3d/__init__.py": "",
    "unik3d/utils/__init__.py": "",
    "unik3d/utils/camera.py": (
        "class Spherical:\n"
        "    def __init__(self, params):\n"
        "        self.params = params\n"
    ),
    "unik3d/models.py": (
        "import torch\n"
        "class UniK3D(torch.nn.Module):\n"
        "    loaded_from = None\n"
        "    @classmethod\n"
        "    def from_pretrained(cls, path):\n"
        "        model = cls(); model.loaded_from = path; return model\n"
        "    def infer(self, rgb, camera, normalize=True):\n"
        "        assert rgb.dtype == torch.uint8 and rgb.ndim == 3 and normalize\n"
        "        self.params = camera.params\n"
        "        # half resolution, like a network with a fixed internal size; distance = 1 + mean/100\n"
        "        x = rgb.float().mean(0)[::2, ::2]\n"
        "        return {'distance': (1 + x / 100)[None, None], 'depth': -torch.ones(1, 1, 1, 1)}\n"
    ),
}


def install_fakes(tmp_path, monkeypatch, request, files: dict[str, str]) -> None:
    """Make the stand-in packages in ``files`` importable for one test, and forget them afterwards (so later
    tests see the real environment, e.g. that the package is not installed)."""
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    packages = {rel.split("/")[0] for rel in files}
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in [m for m in sys.modules if m.split(".")[0] in packages]:
        monkeypatch.delitem(sys.modules, name)

    def forget():
        for name in [m for m in sys.modules if m.split(".")[0] in packages]:
            del sys.modules[name]

    request.addfinalizer(forget)


def test_unik3d_adapter_calls_the_documented_api(tmp_path, monkeypatch, request):
    # A stand-in package with UniK3D's inference API (from_pretrained, Spherical camera, infer()["distance"]).
    install_fakes(tmp_path, monkeypatch, request, _FAKE_UNIK3D)
    weights = tmp_path / "unik3d-vitl"
    weights.mkdir()
    prior = parse_depth_prior(f"unik3d:{weights}")
    assert isinstance(prior, UniK3DAdapter)
    query = _query()
    depth = prior(query)
    assert prior._model.loaded_from == str(weights)
    params = prior._model.params
    assert params[4:6].tolist() == [128.0, 64.0] and params[6:].tolist() == pytest.approx([np.pi, np.pi / 2])
    rgb8 = (query.image * 255 + 0.5).to(torch.uint8).float().mean(0)
    expected = (1 + rgb8[::2, ::2] / 100).repeat_interleave(2, 0).repeat_interleave(2, 1)  # nearest up-sampling
    torch.testing.assert_close(depth, expected)


class _InverseDepthNet(torch.nn.Module):
    def forward(self, x):
        return (0.25 + x.mean(1, keepdim=True))  # "inverse depth", (1, 1, h, w)


def test_exported_prior_torchscript(tmp_path):
    path = tmp_path / "net.pt"
    with pytest.warns(DeprecationWarning):
        torch.jit.save(torch.jit.script(_InverseDepthNet()), str(path))
    query = _query()
    prior = parse_depth_prior(f"exported:{path}", output="inverse_depth", scale=2.0)
    torch.testing.assert_close(prior(query), 2.0 / (0.25 + query.image.mean(0)))
    # Run at a lower size: the image is resized first, the output comes back at the query size.
    small = ExportedDepthPrior(path, input_size=(32, 64))
    out = small(query)
    assert out.shape == (64, 128) and torch.isfinite(out).all()
    expected = 0.25 + torch.nn.functional.interpolate(query.image[None], size=(32, 64), mode="bilinear",
                                                      antialias=True).mean(1)[0]
    torch.testing.assert_close(out[::2, ::2], expected)
    with pytest.raises(FileNotFoundError, match="no exported model"):
        ExportedDepthPrior(tmp_path / "missing.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a model")
    with pytest.raises(ValueError, match="junk.pt"):
        ExportedDepthPrior(tmp_path / "junk.pt")


def test_exported_prior_torch_export(tmp_path):
    path = tmp_path / "net.pt2"
    torch.export.save(torch.export.export(_InverseDepthNet(), (torch.rand(1, 3, 32, 64),)), str(path))
    query = _query()
    out = ExportedDepthPrior(path, input_size=(32, 64), output="inverse_depth")(query)
    small = torch.nn.functional.interpolate(query.image[None], size=(32, 64), mode="bilinear", antialias=True)
    torch.testing.assert_close(out[::2, ::2], 1 / (0.25 + small.mean(1)[0]))
    (tmp_path / "junk.pt2").write_bytes(b"not a model")
    with pytest.raises(ValueError, match="junk.pt2"):
        ExportedDepthPrior(tmp_path / "junk.pt2")


def test_depth_prior_specs():
    assert parse_depth_prior("constant:2.5")(_query()).eq(2.5).all()
    assert isinstance(parse_depth_prior("simulated:4"), SimulatedPrior)
    with pytest.raises(ValueError, match="not a valid depth"):
        parse_depth_prior("constant:far")
    with pytest.raises(ValueError, match="positive"):
        parse_depth_prior("constant:-1")
    with pytest.raises(ValueError, match="takes no"):
        parse_depth_prior("gt:1")


def test_simulated_prior_spec_sets_its_degradation():
    """``simulated:key=value,...`` sets the SimulatedPriorConfig fields and the seed: the spec's prior equals
    the one built directly, and zero degradation through the spec is the ground truth."""
    q = _query()
    prior = parse_depth_prior("simulated:blur_sigma=0.5,seed=2")
    assert prior.seed == 2 and prior.config == SimulatedPriorConfig(blur_sigma=0.5)
    assert torch.equal(prior(q), SimulatedPrior(SimulatedPriorConfig(blur_sigma=0.5), seed=2)(q))
    assert not torch.equal(prior(q), SimulatedPrior(seed=2)(q))  # the default 1.5 px blur differs
    off = parse_depth_prior("simulated:scale_sigma=0,blur_sigma=0,noise_sigma=0,hole_fraction=0")
    assert torch.allclose(off(q), q.gt_depth)
    assert parse_depth_prior("simulated:4").seed == 4
    for spec, message in (("simulated:blur=1", "unknown setting 'blur'"), ("simulated:blur_sigma=-1", ">= 0"),
                          ("simulated:blur_sigma=abc", "not a number"), ("simulated:noise_sigma=nan", ">= 0")):
        with pytest.raises(ValueError, match=message):
            parse_depth_prior(spec)
