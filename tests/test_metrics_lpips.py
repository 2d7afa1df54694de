"""LPIPS-VGG: weight loading and agreement with an independent re-computation of the formula."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from safetensors.torch import save_file

from cylindersplat.metrics import LPIPS, LPIPS_WEIGHTS_ENV, load_lpips, lpips


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
    with pytest.raises(FileNotFoundError, match=LPIPS_WEIGHTS_ENV):
        load_lpips()
    with pytest.raises(FileNotFoundError, match="not found"):
        load_lpips(tmp_path / "nope.safetensors")
    partial = tmp_path / "partial.safetensors"
    save_file({"features.0.weight": torch.zeros(64, 3, 3, 3)}, str(partial))
    with pytest.raises(ValueError, match="missing"):
        load_lpips(partial)
