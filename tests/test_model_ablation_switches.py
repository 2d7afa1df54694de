"""Ablation switches of the volume branch (paper Table "Ablation Study" and Table "scale_ablation").

Every switch: forward + backward on the tiny preset at 32x64 with 2 views, a behavioural check, and
the default configuration is unchanged (checksums recorded before the switches existed).
"""

import math

import pytest
import torch

from cylindersplat.geometry import (
    CylindricalCoords,
    camera_to_world,
    make_c2w,
    project_equirect,
    world_to_camera,
)
from cylindersplat.model import from_config, get_config
from cylindersplat.model.gaussian_heads import (
    cell_cartesian_extent,
    local_to_cartesian_scales,
)
from cylindersplat.model.sampling import sample_panorama
from cylindersplat.model.triplane import PLANE_AXES, encode_unit_coordinates
from cylindersplat.model.triplane_attention import TriplaneImageAttention
from cylindersplat.model.volume_branch import central_frame
from model_inputs import make_inputs as shared_make_inputs

H, W = 32, 64
TINY_CELLS = 4 * 16 * 8  # tiny preset grid (4, 16, 8)


def make_inputs(views: int = 2, batch: int = 1, seed: int = 0, height: int = H, width: int = W):
    return shared_make_inputs(views, batch, seed, height, width)


SWITCHES = {
    "decoded_color": {"volume.color": "decoded"},
    "central": {"volume.placement": "central"},
    "central_depth_prune": {"volume.placement": "central", "fusion.strategy": "depth_prune"},
    "cartesian_scale": {"volume.scale_transform": "cartesian"},
    "full_query": {"volume.image_query": "full"},
    "omniscene_like": {
        "volume.placement": "central", "volume.color": "decoded", "volume.image_query": "full",
        "volume.scale_transform": "cartesian",
    },
}


# -- the default is unchanged -------------------------------------------------------------------------
# (abs-sum, sum against linspace(-1, 1)) of every Gaussian tensor of the default tiny model,
# torch.manual_seed(0), make_inputs() at 32x64, 2 views - recorded before the switches were added.
DEFAULT_CHECKSUMS = {
    "means": (25233.769250876037, 1885.0419139781668),
    "scales": (10440.074254319072, 1505.5382009672262),
    "rotations": (6179.22323574312, 215.52193465337245),
    "opacities": (2740.6825951635838, -54.40176724047933),
    "sh": (12318.984811154527, 327.5696843712098),
}


def test_default_configuration_is_unchanged():
    cfg = get_config("tiny_paper")
    vol = cfg.volume
    assert (vol.color, vol.placement, vol.scale_transform, vol.image_query) == ("retrieval", "per_camera", "paper",
                                                                                "coarse")
    torch.manual_seed(0)
    model = from_config("tiny_paper")
    # no new parameters in the default model (checkpoints stay loadable)
    assert sum(p.numel() for p in model.parameters()) == 234746
    assert not any("color_decoder" in name for name, _ in model.named_parameters())
    with torch.no_grad():
        out = model(*make_inputs())
    for name, t in out.gaussians.tensors().items():
        t = t.double().flatten()
        ramp = torch.linspace(-1, 1, t.numel(), dtype=torch.float64)
        got = (float(t.abs().sum()), float(t @ ramp))
        assert got == pytest.approx(DEFAULT_CHECKSUMS[name], rel=1e-5, abs=1e-3), name


# -- every switch: forward + backward ------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(SWITCHES))
def test_switch_forward_backward(name):
    changes = SWITCHES[name]
    torch.manual_seed(0)
    model = from_config("tiny_paper", **changes)
    images, depth, c2w = make_inputs(2)
    out = model(images, depth, c2w)
    out.gaussians.validate()  # finite, positive scales, opacities in [0, 1]
    central = changes.get("volume.placement") == "central"
    expected_volume = (1 if central else 2) * TINY_CELLS
    assert model.volume_branch.num_gaussians(2) == expected_volume
    assert out.volume_gaussians.num_gaussians == expected_volume
    assert out.gaussians.num_gaussians == 2 * H * W + expected_volume
    assert out.keep_mask.shape == (1, out.gaussians.num_gaussians)
    g = torch.Generator().manual_seed(5)
    loss = sum((t * torch.randn(t.shape, generator=g)).sum() for t in out.gaussians.tensors().values())
    loss.backward()
    for pname, p in model.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, f"no gradient reaches {pname}"
        assert torch.isfinite(p.grad).all(), pname
    if changes.get("volume.color") == "decoded":
        assert any("color_decoder" in n for n, _ in model.named_parameters())
        assert not hasattr(model.volume_branch, "rgb")


def test_switches_validate_with_clear_errors():
    for field, bad in [("color", "rgb"), ("placement", "everywhere"), ("scale_transform", "log"),
                       ("image_query", "half")]:
        with pytest.raises(ValueError, match=f"volume.{field}"):
            get_config("tiny_paper", **{f"volume.{field}": bad})
    with pytest.raises(ValueError, match="central.*shared"):
        get_config("tiny_paper", **{"volume.placement": "central", "volume.init": "isolated"})


def test_switches_are_experiment_overrides():
    import cylindersplat.training as training
    overrides = ["model.volume.color=decoded", "model.volume.placement=central",
                 "model.volume.scale_transform=cartesian", "model.volume.image_query=full"]
    cfg = training.load_config(None, overrides)
    vol = cfg.model.validate().volume
    assert (vol.color, vol.placement, vol.scale_transform, vol.image_query) == ("decoded", "central", "cartesian",
                                                                                "full")


# -- w/o RGB retrieval ---------------------------------------------------------------------------------
def _volume_inputs(views=2, seed=0):
    images, depth, c2w = make_inputs(views, seed=seed)
    g = torch.Generator().manual_seed(seed + 1)
    features = torch.randn(1, views, 16, H, W, generator=g)
    points = camera_to_world(torch.randn(1, views, 200, 3, generator=g) * 2.0, c2w)
    point_features = torch.randn(1, views, 200, 16, generator=g)
    return images, depth, c2w, features, points, point_features


@pytest.mark.parametrize("color", ["retrieval", "decoded"])
def test_decoded_colour_does_not_read_the_images(color):
    torch.manual_seed(0)
    branch = from_config("tiny_paper", **{"volume.color": color}).volume_branch
    images, depth, c2w, features, points, point_features = _volume_inputs()
    other_images, other_depth = torch.rand_like(images), depth + 1.0
    with torch.no_grad():
        a = branch(images, depth, c2w, features, points, point_features).gaussians
        b = branch(other_images, other_depth, c2w, features, points, point_features).gaussians
    torch.testing.assert_close(a.means, b.means, rtol=0, atol=0)  # geometry never reads images/prior
    if color == "decoded":
        torch.testing.assert_close(a.sh, b.sh, rtol=0, atol=0)
    else:
        assert (a.sh - b.sh).abs().max() > 1e-3


# -- w/o multi triplane (central) ----------------------------------------------------------------------
def test_central_triplane_is_centred_on_the_mean_camera():
    torch.manual_seed(0)
    model = from_config("tiny_paper", **{"volume.placement": "central"})
    last = model.volume_branch.head.mlp[-1]
    with torch.no_grad():  # zero offsets: every Gaussian sits on its cell centre
        last.weight[:3].zero_()
        last.bias[:3].zero_()
    images, depth, c2w = make_inputs(3, batch=2)
    c2w[1] = c2w[1].flip(0)  # a different camera order in the second scene
    with torch.no_grad():
        out = model.set_mode("volume")(images, depth, c2w)
    frame = central_frame(c2w)
    assert frame.shape == (2, 1, 4, 4)
    torch.testing.assert_close(frame[:, 0, :3, 3], c2w[..., :3, 3].mean(dim=1))
    torch.testing.assert_close(frame[:, 0, :3, :3], c2w[:, 0, :3, :3])
    coords = model.volume_branch.coords
    centres = coords.to_cartesian(coords.cell_centers(model.config.volume.grid)).reshape(1, -1, 3)
    expected = camera_to_world(centres, frame[:, 0])
    torch.testing.assert_close(out.volume_gaussians.means, expected, atol=1e-5, rtol=1e-5)
    # in the central frame they fill the cylinder around the mean camera centre, not any camera's
    local = world_to_camera(out.volume_gaussians.means, frame[:, 0])
    assert local.norm(dim=-1).max() <= math.hypot(coords.radius, coords.height / 2) + 1e-4
    torch.testing.assert_close(local.mean(dim=1)[:, [0, 2]], torch.zeros(2, 2), atol=1e-4, rtol=0)


def test_central_triplane_with_one_view_is_the_per_camera_triplane():
    images, depth, c2w = make_inputs(1)
    c2w[..., :3, 3] = torch.tensor([0.3, -0.1, 0.2])
    outs = []
    for placement in ("per_camera", "central"):
        torch.manual_seed(0)
        model = from_config("tiny_paper", **{"volume.placement": placement})
        with torch.no_grad():
            outs.append(model(images, depth, c2w).volume_gaussians)
    for key, t in outs[0].tensors().items():
        torch.testing.assert_close(outs[1].tensors()[key], t, atol=1e-5, rtol=1e-5)


def test_central_depth_prune_uses_view_zero():
    torch.manual_seed(0)
    model = from_config("tiny_paper", **{"volume.placement": "central", "fusion.strategy": "depth_prune"})
    images, depth, c2w, features, points, point_features = _volume_inputs()
    with torch.no_grad():
        vol = model.volume_branch(images, depth, c2w, features, points, point_features)
    assert vol.depth_view == 0 and vol.points_cam.shape == (1, 1, TINY_CELLS, 3)
    torch.testing.assert_close(vol.points_cam[:, 0], world_to_camera(vol.gaussians.means, c2w[:, 0]))
    with torch.no_grad():
        out = model(*make_inputs(2))
    n_pix = out.pixel_gaussians.num_gaussians
    assert out.keep_mask[:, :n_pix].all() and not out.keep_mask[:, n_pix:].all()


def _reference_image_attention(module, planes, features, view_from_plane):
    """Explicit per-cell loop of triplane-to-image attention over all views (query at query_grid)."""
    coords, heads = module.coords, module.heads
    n, v, _, h, w = features.shape
    out = []
    for k, (a, b) in enumerate(PLANE_AXES):
        query_plane = planes[k]  # tests use query_grid == plane resolution
        unit = module.sample_units(k, features.device, features.dtype)
        pts = coords.to_cartesian(coords.from_unit(unit))  # (A, B, M, 3) in the triplane frame
        code = encode_unit_coordinates(unit, coords.periodic)
        result = torch.empty_like(query_plane)
        for i in range(unit.shape[0]):
            for j in range(unit.shape[1]):
                for s in range(n):
                    keys_in = []
                    for view in range(v):
                        rot, trans = view_from_plane[s, view, :3, :3], view_from_plane[s, view, :3, 3]
                        uv, _ = project_equirect(pts[i, j] @ rot.T + trans, h, w)
                        sampled = sample_panorama(features[s, view][None], uv[None])[0]
                        keys_in.append(torch.cat((sampled, code[i, j]), dim=-1))
                    kv = module.kv(module.kv_in(torch.cat(keys_in)))
                    kk, vv = kv.chunk(2, dim=-1)
                    q = module.q(module.norm(query_plane[s, i, j]))
                    d = q.shape[-1] // heads
                    q, kk, vv = q.view(heads, d), kk.view(-1, heads, d), vv.view(-1, heads, d)
                    weights = torch.softmax(torch.einsum("hd,mhd->hm", q, kk) / math.sqrt(d), dim=-1)
                    ctx = torch.einsum("hm,mhd->hd", weights, vv).reshape(-1)
                    result[s, i, j] = query_plane[s, i, j] + module.out(ctx)
        out.append(result)
    return out


def test_multi_view_image_attention_matches_explicit_loop():
    """The central triplane's Eq. 2: each query attends to the V x N'_c samples, moved into every view."""
    torch.manual_seed(3)
    coords = CylindricalCoords(radius=4.0, height=3.0)
    grid = (2, 6, 3)
    module = TriplaneImageAttention(8, 4, 2, coords, image_grid=grid).double()
    planes = [torch.randn(2, grid[a], grid[b], 8, dtype=torch.float64) for a, b in PLANE_AXES]
    features = torch.randn(2, 3, 4, 8, 16, dtype=torch.float64)
    yaw = torch.rand(2, 3, dtype=torch.float64) * 6.0
    rot = torch.zeros(2, 3, 3, 3, dtype=torch.float64)
    rot[..., 0, 0], rot[..., 0, 2], rot[..., 1, 1] = yaw.cos(), yaw.sin(), 1.0
    rot[..., 2, 0], rot[..., 2, 2] = -yaw.sin(), yaw.cos()
    view_from_plane = make_c2w(rot, torch.randn(2, 3, 3, dtype=torch.float64))
    got = module(planes, features, view_from_plane)
    expected = _reference_image_attention(module, planes, features, view_from_plane)
    for g, e in zip(got, expected):
        torch.testing.assert_close(g, e)
    # every view is read: changing one view's features changes the update
    changed = features.clone()
    changed[:, 2] += 1.0
    assert (module(planes, changed, view_from_plane)[1] - got[1]).abs().max() > 1e-6


def test_identity_relative_pose_is_bit_identical_to_the_own_view():
    torch.manual_seed(4)
    coords = CylindricalCoords()
    module = TriplaneImageAttention(8, 4, 2, coords, image_grid=(2, 8, 4))
    planes = [torch.randn(3, 4, 16, 8), torch.randn(3, 16, 8, 8), torch.randn(3, 8, 4, 8)]
    features = torch.randn(3, 4, 16, 32)
    identity = torch.eye(4).expand(3, 1, 4, 4)
    own = module(planes, features)
    generic = module(planes, features[:, None], identity)
    for a, b in zip(own, generic):
        assert torch.equal(a, b)


# -- Cartesian scale -----------------------------------------------------------------------------------
def test_cartesian_scale_transform_is_the_identity_at_every_radius():
    coords = CylindricalCoords(radius=10.0, height=10.0)
    scales = torch.rand(50, 3) + 0.1
    rotations = torch.nn.functional.normalize(torch.randn(50, 4), dim=-1)
    for radius in (0.3, 2.0, 9.5):
        q = torch.stack((torch.full((50,), radius), torch.rand(50) * 6.28, torch.rand(50) - 0.5), dim=-1)
        s, r = local_to_cartesian_scales(coords, q, scales, rotations, "cartesian")
        assert torch.equal(s, scales) and torch.equal(r, rotations)
        paper, _ = local_to_cartesian_scales(coords, q, scales, rotations, "paper")
        assert not torch.allclose(paper, scales)  # Eq. 4 does depend on the radius


def test_cell_cartesian_extent_is_the_cells_bounding_box():
    coords = CylindricalCoords(radius=8.0, height=4.0)
    cell = torch.tensor([0.5, 0.1, 0.25])
    r = torch.tensor([1.0, 3.0])
    q = torch.stack((r, torch.zeros(2), torch.zeros(2)), dim=-1)  # theta = 0: looking along -z
    expected = torch.stack((r * 0.1, torch.full((2,), 0.25), torch.full((2,), 0.5)), dim=-1)
    torch.testing.assert_close(cell_cartesian_extent(coords, q, cell), expected)
    q[:, 1] = math.pi / 2  # theta = pi / 2: radial along -x, tangential along z
    expected = torch.stack((torch.full((2,), 0.5), torch.full((2,), 0.25), r * 0.1), dim=-1)
    torch.testing.assert_close(cell_cartesian_extent(coords, q, cell), expected, atol=1e-6, rtol=1e-6)


def test_cartesian_scales_are_the_bounded_head_output():
    torch.manual_seed(0)
    model = from_config("tiny_paper", **{"volume.scale_transform": "cartesian"})
    branch = model.volume_branch
    captured = {}
    branch.head.register_forward_hook(lambda module, args, output: captured.update(output))
    images, depth, c2w, features, points, point_features = _volume_inputs()
    with torch.no_grad():
        vol = branch(images, depth, c2w, features, points, point_features)
    scales = vol.gaussians.scales.view(2, -1, 3)
    torch.testing.assert_close(scales, captured["local_scales"].view(2, -1, 3), rtol=0, atol=0)
    cfg = model.config.volume
    coords = branch.coords
    centres = coords.cell_centers(cfg.grid).reshape(-1, 3)
    extent = cell_cartesian_extent(coords, centres, torch.tensor(coords.cell_size(cfg.grid)))
    assert (scales >= cfg.min_scale_cells * extent * (1 - 1e-5)).all()
    assert (scales <= cfg.max_scale_cells * extent * (1 + 1e-5)).all()
    # rotations: the head's quaternion composed with the camera rotation only (no cell frame)
    paper = from_config("tiny_paper", **{"volume.scale_transform": "paper"}).volume_branch
    paper.load_state_dict(branch.state_dict())
    with torch.no_grad():
        ref = paper(images, depth, c2w, features, points, point_features).gaussians
    torch.testing.assert_close(vol.gaussians.rotations, ref.rotations, rtol=0, atol=0)


# -- full-resolution Eq. 2 queries ----------------------------------------------------------------------
def test_full_queries_sample_every_plane_cell():
    coords = CylindricalCoords()
    module = TriplaneImageAttention(8, 4, 2, coords, image_grid=(2, 8, 4), query_grid=(4, 16, 8))
    for k, (a, b) in enumerate(PLANE_AXES):
        c = 3 - a - b
        unit = module.sample_units(k, None, torch.float32)
        assert unit.shape == ((4, 16, 8)[a], (4, 16, 8)[b], (2, 8, 4)[c], 3)


def test_full_queries_match_explicit_loop():
    torch.manual_seed(6)
    coords = CylindricalCoords(radius=4.0, height=3.0)
    grid, image_grid = (3, 8, 4), (2, 4, 2)
    module = TriplaneImageAttention(8, 4, 2, coords, image_grid=image_grid, query_grid=grid).double()
    planes = [torch.randn(1, grid[a], grid[b], 8, dtype=torch.float64) for a, b in PLANE_AXES]
    features = torch.randn(1, 4, 8, 16, dtype=torch.float64)
    got = module(planes, features)
    expected = _reference_image_attention(module, planes, features[:, None],
                                          torch.eye(4, dtype=torch.float64).expand(1, 1, 4, 4))
    for g, e in zip(got, expected):
        torch.testing.assert_close(g, e)


def test_full_queries_equal_coarse_queries_when_image_grid_is_grid():
    images, depth, c2w = make_inputs(2)
    outs = []
    for query in ("coarse", "full"):
        torch.manual_seed(0)
        model = from_config("tiny_paper", **{"volume.image_grid": (4, 16, 8), "volume.image_query": query})
        with torch.no_grad():
            outs.append(model(images, depth, c2w).gaussians)
    for key, t in outs[0].tensors().items():
        assert torch.equal(outs[1].tensors()[key], t), key
