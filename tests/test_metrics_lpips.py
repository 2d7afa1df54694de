"""LPIPS-VGG: weight loading and agreement with an independent re-computation of the formula."""

import importlib
import importlib.util

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from safetensors.torch import save_file

from cylindersplat.metrics import (
    LPIPS,
    LPIPS_WEIGHTS_ENV,
    load_lpips,
    lpips,
    lpips_package_weights,
    lpips_weights_available,
    torchvision_vgg16_weights,
)

LPIPS_MODULE = importlib.import_module("cylindersplat.metrics.lpips")  # the attribute `lpips` is the function


@pytest.fixture(scope="module")
def weights_file(tmp_path_factory):
    torch.manual_seed(0)
    net = LPIPS()
    for conv in net.features.values():  # He init keeps activations alive through 13 layers
        torch.nn.init.kaiming_normal_(conv.weight)
        torch.nn.init.uniform_(conv.bias, -0.1, 0.1)
    for lin in net.lins:
        lin.weight.data.uniform_(0, 1)
    path = tmp_path_factory.mktemp("lpips") / "lpips_vgg.safetensors"
    save_file(net.state_dict_external(), str(path))
    return path


def _reference_lpips(state, a, b):
    """Textbook LPIPS: plain conv loop from the file's tensors, normalisation and heads in numpy."""
    shift = np.array([-0.030, -0.088, -0.188])[None, :, None, None]
    scale = np.array([0.458, 0.448, 0.450])[None, :, None, None]
    plan = [0, 2, "M", 5, 7, "M", 10, 12, 14, "M", 17, 19, 21, "M", 24, 26, 28]
    taps = {2: 0, 7: 1, 14: 2, 21: 3, 28: 4}

    def features(x):
        x = torch.from_numpy((2 * x - 1 - shift) / scale).float()
        out = []
        for step in plan:
            if step == "M":
                x = F.max_pool2d(x, 2)
                continue
            x = F.relu(F.conv2d(x, state[f"features.{step}.weight"], state[f"features.{step}.bias"], padding=1))
            if step in taps:
                out.append(x.double().numpy())
        return out

    total = 0.0
    for k, (fa, fb) in enumerate(zip(features(a), features(b))):
        na = fa / (np.sqrt((fa**2).sum(axis=1, keepdims=True)) + 1e-10)
        nb = fb / (np.sqrt((fb**2).sum(axis=1, keepdims=True)) + 1e-10)
        w = state[f"lin{k}.model.1.weight"].double().numpy().reshape(1, -1, 1, 1)
        total = total + ((na - nb) ** 2 * w).sum(axis=1).mean(axis=(-2, -1))
    return total


def test_lpips_matches_reference(weights_file):
    from safetensors.torch import load_file

    g = torch.Generator().manual_seed(1)
    a = torch.rand(2, 3, 32, 64, generator=g)
    b = (a + 0.2 * torch.randn(2, 3, 32, 64, generator=g)).clamp(0, 1)
    net = load_lpips(weights_file)
    ours = net(a, b)
    ref = _reference_lpips(load_file(str(weights_file)), a.double().numpy(), b.double().numpy())
    assert ours.shape == (2,)
    np.testing.assert_allclose(ours.numpy(), ref, rtol=1e-4)
    assert (ours > 0).all()


def test_lpips_identity_symmetry_env(weights_file, monkeypatch):
    monkeypatch.setenv(LPIPS_WEIGHTS_ENV, str(weights_file))
    g = torch.Generator().manual_seed(2)
    a, b = torch.rand(2, 1, 3, 32, 64, generator=g)
    assert float(lpips(a, a).abs().max()) < 1e-6
    assert torch.allclose(lpips(a, b), lpips(b, a), rtol=1e-5)


def test_lpips_accepts_lpips_package_key_names(weights_file, tmp_path):
    from safetensors.torch import load_file

    state = load_file(str(weights_file))
    renamed = {}
    slices = {0: 1, 2: 1, 5: 2, 7: 2, 10: 3, 12: 3, 14: 3, 17: 4, 19: 4, 21: 4, 24: 5, 26: 5, 28: 5}
    for key, value in state.items():
        if key.startswith("features."):
            index = int(key.split(".")[1])
            key = f"net.slice{slices[index]}.{index}.{key.split('.')[2]}"
        renamed[key] = value
    pth = tmp_path / "w.pth"
    torch.save(renamed, pth)
    a, b = torch.rand(2, 1, 3, 16, 32)
    assert torch.allclose(load_lpips(pth)(a, b), load_lpips(weights_file)(a, b))


def test_lpips_missing_weights_errors(tmp_path, monkeypatch):
    monkeypatch.delenv(LPIPS_WEIGHTS_ENV, raising=False)
    monkeypatch.setattr(LPIPS_MODULE, "lpips_package_weights", lambda: None)  # whatever is installed
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))  # an empty torchvision cache
    assert not lpips_weights_available()
    with pytest.raises(FileNotFoundError, match=LPIPS_WEIGHTS_ENV):
        load_lpips()
    with pytest.raises(FileNotFoundError, match="not found"):
        load_lpips(tmp_path / "nope.safetensors")
    partial = tmp_path / "partial.safetensors"
    save_file({"features.0.weight": torch.zeros(64, 3, 3, 3)}, str(partial))
    with pytest.raises(ValueError, match="missing"):
        load_lpips(partial)


# ---- the lpips package's heads + torchvision's cached trunk ----------------------------------------------------


@pytest.fixture()
def split_weights(weights_file, tmp_path, monkeypatch):
    """A fake installed ``lpips`` package (only ``weights/v0.1/vgg.pth``, heads of distinct values; importing it
    fails, so it must only be located) and a fake torchvision cache holding the trunk as torchvision saves it."""
    from safetensors.torch import load_file

    state = load_file(str(weights_file))
    trunk = {k: v for k, v in state.items() if k.startswith("features.")}
    trunk["classifier.0.weight"] = torch.zeros(4, 3)  # the rest of torchvision's vgg16 file is ignored
    g = torch.Generator().manual_seed(5)
    heads = {f"lin{k}.model.1.weight": torch.rand(1, c, 1, 1, generator=g) + k
             for k, c in enumerate((64, 128, 256, 512, 512))}
    package = tmp_path / "site" / "lpips"
    (package / "weights" / "v0.1").mkdir(parents=True)
    (package / "__init__.py").write_text("raise ImportError('the lpips package must be located, not imported')\n")
    torch.save(heads, package / "weights" / "v0.1" / "vgg.pth")
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "torch"))
    monkeypatch.delenv(LPIPS_WEIGHTS_ENV, raising=False)
    cache = tmp_path / "torch" / "hub" / "checkpoints" / "vgg16-397923af.pth"
    cache.parent.mkdir(parents=True)
    torch.save(trunk, cache)
    return trunk, heads, package / "weights" / "v0.1" / "vgg.pth", cache


def _assert_loaded(net, trunk, heads):
    for k, lin in enumerate(net.lins):
        assert torch.equal(lin.weight, heads[f"lin{k}.model.1.weight"])
    for index, conv in net.features.items():
        assert torch.equal(conv.weight, trunk[f"features.{index}.weight"])
        assert torch.equal(conv.bias, trunk[f"features.{index}.bias"])


def test_lpips_from_package_heads_and_torchvision_cache(split_weights, tmp_path):
    trunk, heads, package_file, cache = split_weights
    assert lpips_package_weights() == package_file and torchvision_vgg16_weights() == cache
    assert lpips_weights_available()
    net = load_lpips()
    _assert_loaded(net, trunk, heads)
    assert net.sources == {"trunk": str(cache), "linear": str(package_file)}
    # the same numbers as one merged file of those tensors
    merged = tmp_path / "merged.pth"
    torch.save({**trunk, **heads}, merged)
    a, b = torch.rand(2, 1, 3, 16, 32)
    assert torch.equal(net(a, b), load_lpips(merged)(a, b))


def test_lpips_file_parts_completed_from_package_or_cache(split_weights, tmp_path):
    trunk, heads, package_file, cache = split_weights
    trunk_only = tmp_path / "vgg16_features.pth"
    torch.save({k: v for k, v in trunk.items() if k.startswith("features.")}, trunk_only)
    cache.unlink()  # the trunk must come from the file now
    net = load_lpips(trunk_only)
    _assert_loaded(net, trunk, heads)
    assert net.sources == {"trunk": str(trunk_only), "linear": str(package_file)}
    with pytest.raises(FileNotFoundError, match="VGG16 trunk"):  # heads only: the trunk is looked for in the cache
        load_lpips(package_file)
    torch.save(trunk, cache)
    assert load_lpips(package_file).sources == {"trunk": str(cache), "linear": str(package_file)}


def test_lpips_file_without_heads_and_no_package(weights_file, tmp_path, monkeypatch):
    from safetensors.torch import load_file

    monkeypatch.setattr(LPIPS_MODULE, "lpips_package_weights", lambda: None)
    trunk_only = tmp_path / "vgg16_features.safetensors"
    save_file({k: v for k, v in load_file(str(weights_file)).items() if k.startswith("features.")}, str(trunk_only))
    with pytest.raises(FileNotFoundError, match=r"has no linear heads.*pip install lpips"):
        load_lpips(trunk_only)
    bad = tmp_path / "bad_heads.pth"  # heads of the wrong size are refused, not reshaped
    torch.save({**load_file(str(trunk_only)), **{f"lin{k}.model.1.weight": torch.ones(1, 3, 1, 1) for k in range(5)}},
               bad)
    with pytest.raises(ValueError, match="lin0 has shape"):
        load_lpips(bad)


@pytest.mark.skipif(importlib.util.find_spec("lpips") is None, reason="the lpips package is not installed")
def test_real_lpips_package_heads():
    heads = torch.load(lpips_package_weights(), map_location="cpu", weights_only=True)
    assert {k: tuple(v.shape) for k, v in heads.items()} == {
        f"lin{k}.model.1.weight": (1, c, 1, 1) for k, c in enumerate((64, 128, 256, 512, 512))}


def test_training_loss_auto_uses_the_same_lookup(split_weights, tmp_path, monkeypatch):
    from cylindersplat.training.losses import LossConfig, RenderLoss

    trunk, heads, _, _ = split_weights
    loss = RenderLoss(LossConfig(use_lpips="auto"))
    assert loss.uses_lpips
    _assert_loaded(loss.lpips_net, trunk, heads)
    monkeypatch.setenv("TORCH_HOME", str(tmp_path / "empty"))  # no trunk anywhere: auto drops the term
    with pytest.warns(UserWarning, match="LPIPS loss term disabled"):
        assert not RenderLoss(LossConfig(use_lpips="auto")).uses_lpips
