"""Gaussian container operations and the standard 3DGS PLY layout."""

import numpy as np
import pytest
import torch
from plyfile import PlyData

from cylindersplat.gaussians import Gaussians, load_ply, save_ply


def random_gaussians(n=10, sh_degree=0, seed=0):
    gen = torch.Generator().manual_seed(seed)
    k = (sh_degree + 1) ** 2
    return Gaussians(
        means=torch.randn(n, 3, generator=gen),
        scales=torch.rand(n, 3, generator=gen) * 0.1 + 0.01,
        rotations=torch.nn.functional.normalize(torch.randn(n, 4, generator=gen), dim=-1),
        opacities=torch.rand(n, generator=gen) * 0.98 + 0.01,
        sh=torch.randn(n, k, 3, generator=gen) * 0.3,
    )


def test_container_cat_select_and_moves():
    a, b = random_gaussians(4), random_gaussians(3, sh_degree=2, seed=1)
    c = Gaussians.cat([a, b])
    assert len(c) == 7 and c.sh_degree == 2
    torch.testing.assert_close(c.sh[:4, 0], a.sh[:, 0])
    assert (c.sh[:4, 1:] == 0).all()
    mask = torch.tensor([True, False, True, False, False, False, True])
    sel = c[mask]
    torch.testing.assert_close(sel.means, c.means[mask])
    assert len(c[torch.tensor([0, 6])]) == 2
    assert c.to(torch.float64).dtype == torch.float64
    rgb = torch.rand(5, 3)
    torch.testing.assert_close(Gaussians.from_rgb(torch.zeros(5, 3), torch.ones(5, 3), torch.randn(5, 4), torch.ones(5),
                                                  rgb).rgb, rgb)


def test_validate_names_the_problem():
    g = random_gaussians(4)
    g.validate()
    with pytest.raises(ValueError, match="opacities"):
        Gaussians(g.means, g.scales, g.rotations, g.opacities + 1.5, g.sh).validate()
    with pytest.raises(ValueError, match="scales must have shape"):
        Gaussians(g.means, g.scales[:3], g.rotations, g.opacities, g.sh).validate()
    bad = g.means.clone()
    bad[0, 0] = float("inf")
    with pytest.raises(ValueError, match="means contains non-finite"):
        Gaussians(bad, g.scales, g.rotations, g.opacities, g.sh).validate()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64, torch.float16, torch.bfloat16])
def test_value_checks_agree_with_elementwise_checks(dtype):
    """The checks come from each tensor's min and max: against ``isfinite`` and comparisons element by element, for
    every bad value in every place of every tensor, the extremes of the type (finite: no alarm), batched and strided
    tensors, and no Gaussians at all."""
    big = torch.finfo(dtype).max

    def expected(g):
        for name, t in g.tensors().items():
            if not torch.isfinite(t).all():
                return f"{name} contains non-finite"
        if (g.scales < 0).any():
            return "scales must be non-negative"
        if ((g.opacities < 0) | (g.opacities > 1)).any():
            return "opacities must lie in"
        return None

    base = random_gaussians(6, sh_degree=1).to(dtype)
    base = Gaussians(**{k: torch.stack((v, v.flip(0))) for k, v in base.tensors().items()})  # batched (2, 6, ...)
    cases = [base, Gaussians(**{k: v[:, :0] for k, v in base.tensors().items()})]
    for name, t in base.tensors().items():
        for value in (float("nan"), float("inf"), -float("inf"), big, -big, -1e-3, 1.5):
            for place in (0, t.numel() // 2, t.numel() - 1):
                tensors = {k: v.clone() for k, v in base.tensors().items()}
                tensors[name].view(-1)[place] = value
                cases.append(Gaussians(**tensors))
    strided = {k: v.clone() for k, v in base.tensors().items()}
    strided["means"] = torch.cat((strided["means"], strided["means"]), -1)[..., ::2]  # a strided view
    strided["means"][1, 3, 2] = float("nan")
    cases.append(Gaussians(**strided))
    assert not strided["means"].is_contiguous()
    for g in cases:
        want = expected(g)
        if want is None:
            assert g.validate() is g and not g.problem_flags().any()
        else:
            with pytest.raises(ValueError, match=want):
                g.validate()


@pytest.mark.parametrize("sh_degree", [0, 3])
def test_ply_round_trip_is_lossless(tmp_path, sh_degree):
    g = random_gaussians(50, sh_degree=sh_degree)
    path = save_ply(g, tmp_path / "scene.ply")
    back = load_ply(path)
    for name, t in g.tensors().items():
        torch.testing.assert_close(getattr(back, name), t, rtol=2e-6, atol=2e-7, msg=name)


def test_ply_uses_the_standard_3dgs_layout(tmp_path):
    g = random_gaussians(5, sh_degree=1)
    save_ply(g, tmp_path / "s.ply")
    vertex = PlyData.read(str(tmp_path / "s.ply"))["vertex"]
    names = [p.name for p in vertex.properties]
    expected = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + [f"f_rest_{i}" for i in range(9)]
    expected += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    assert names == expected
    # logit opacity, log scale, channel-major f_rest (R coefficients first), zero normals.
    np.testing.assert_allclose(vertex["opacity"], torch.logit(g.opacities.double()).numpy(), rtol=1e-5)
    np.testing.assert_allclose(vertex["scale_1"], g.scales[:, 1].log().numpy(), rtol=1e-5)
    np.testing.assert_allclose(vertex["f_rest_0"], g.sh[:, 1, 0].numpy())
    np.testing.assert_allclose(vertex["f_rest_3"], g.sh[:, 1, 1].numpy())
    np.testing.assert_allclose(vertex["f_rest_1"], g.sh[:, 2, 0].numpy())
    assert (vertex["nx"] == 0).all()


def test_ply_errors_are_clear(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.ply"):
        load_ply(tmp_path / "missing.ply")
    corrupt = tmp_path / "corrupt.ply"
    corrupt.write_bytes(b"ply\nformat nonsense\n")
    with pytest.raises(ValueError, match="corrupt.ply"):
        load_ply(corrupt)


def test_splat_export_byte_layout(tmp_path):
    """Parse the .splat bytes by hand (struct layout of the web viewers) and compare with the Gaussians."""
    import struct

    import numpy as np

    from cylindersplat.gaussians import Gaussians, save_splat

    gen = torch.Generator().manual_seed(3)
    n = 6
    g = Gaussians.from_rgb(torch.randn(n, 3, generator=gen), 0.01 + torch.rand(n, 3, generator=gen),
                           torch.randn(n, 4, generator=gen), torch.rand(n, generator=gen),
                           torch.rand(n, 3, generator=gen))
    path = save_splat(g, tmp_path / "scene.splat")
    raw = path.read_bytes()
    assert len(raw) == 32 * n
    rows = [struct.unpack("<3f3f4B4B", raw[32 * i: 32 * (i + 1)]) for i in range(n)]
    # each row is one of the Gaussians (order: decreasing opacity x volume)
    key = [r[9] / 255 * r[3] * r[4] * r[5] for r in rows]
    assert all(a >= b * 0.98 for a, b in zip(key, key[1:]))  # decreasing opacity x volume (alpha is quantised)
    for row in rows:
        i = int(np.argmin(np.linalg.norm(g.means.numpy() - np.array(row[0:3]), axis=1)))
        np.testing.assert_allclose(row[0:3], g.means[i].numpy(), rtol=1e-6)
        np.testing.assert_allclose(row[3:6], g.scales[i].numpy(), rtol=1e-6)
        rgb = (0.5 + 0.28209479177387814 * g.sh[i, 0]).clamp(0, 1).numpy()
        np.testing.assert_allclose(np.array(row[6:9]) / 255, rgb, atol=1 / 255)
        assert abs(row[9] / 255 - float(g.opacities[i])) <= 1 / 255
        q = torch.nn.functional.normalize(g.rotations[i], dim=0).numpy()
        np.testing.assert_allclose((np.array(row[10:14]) - 128) / 128, q, atol=1 / 128)
