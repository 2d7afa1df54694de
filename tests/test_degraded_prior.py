"""``degraded:KIND`` depth priors: each kind does what its documentation says, seeded, and specs parse."""

import math

import pytest
import torch

from cylindersplat.data.depth_prior import parse_depth_prior
from cylindersplat.data.depth_prior.base import PriorQuery
from cylindersplat.data.depth_prior.degraded import DEGRADATIONS, DegradedPrior, _low_frequency_field


def _query(depth, key="scene/0"):
    return PriorQuery(image=torch.zeros(3, *depth.shape), gt_depth=depth, rgb_path=None, key=key)


def _room(h=64, w=128):
    depth = torch.full((h, w), 3.0)
    depth[:, 40:70] = 1.5  # a box in front of the wall: two depth edges per row
    depth[:2] = 0.0  # invalid rows stay invalid
    return depth


@pytest.mark.parametrize("kind", list(DEGRADATIONS))
def test_every_kind_is_seeded_keeps_invalid_and_stays_positive(kind):
    depth = _room()
    prior = DegradedPrior(kind, seed=0)
    a, b = prior(_query(depth)), prior(_query(depth))
    assert torch.equal(a, b)
    assert torch.all(a[:2] == 0) and torch.all(a[2:] > 0) and torch.isfinite(a).all()
    others = [DegradedPrior(kind, seed=s)(_query(depth, key=f"scene/{s}")) for s in range(1, 6)]
    if kind != "edge_blur":  # the blur alone has nothing random
        assert any(not torch.equal(a, o) for o in others)


def test_scale_is_thirty_percent_either_way():
    depth = _room()
    seen = set()
    for seed in range(12):
        ratio = DegradedPrior("scale", seed)(_query(depth))[2:] / depth[2:]
        assert torch.allclose(ratio, ratio[0, 0].expand_as(ratio))
        value = float(ratio[0, 0])
        assert math.isclose(value, 1.3, rel_tol=1e-5) or math.isclose(value, 1 / 1.3, rel_tol=1e-5)
        seen.add(round(value, 3))
    assert len(seen) == 2  # both directions occur


def test_noise_has_five_percent_spread_and_no_bias():
    depth = torch.full((256, 512), 2.0)
    ratio = DegradedPrior("noise", 3)(_query(depth)) / depth
    assert abs(float(ratio.std()) - 0.05) < 0.003
    assert abs(float(ratio.mean()) - 1.0) < 0.002


def test_edge_blur_smears_edges_only():
    depth = _room(128, 256)
    depth[:2] = 3.0
    out = DegradedPrior("edge_blur")(_query(depth))
    # far from the edges (columns 40 and 70) the depth is unchanged, beside them it lies between the two surfaces
    assert torch.allclose(out[:, 90:250], depth[:, 90:250], atol=1e-5)
    assert torch.allclose(out[8:, 48:62], depth[8:, 48:62], atol=1e-5)
    row = out[64]
    for col in (39, 40, 69, 70):
        assert 1.5 < float(row[col]) < 3.0


def test_mono_bias_is_smooth_and_continuous_across_the_seam():
    gen = torch.Generator().manual_seed(0)
    field = _low_frequency_field(64, 128, gen)
    assert float(field.abs().max()) <= 1.0 + 1e-6
    # neighbouring columns differ little, and so do the last and the first (the seam)
    step = (field[:, 1:] - field[:, :-1]).abs().max()
    assert float((field[:, 0] - field[:, -1]).abs().max()) <= 2 * float(step) + 1e-6
    depth = torch.full((64, 128), 2.0)
    ratio = DegradedPrior("mono", 1)(_query(depth)) / depth
    scale = float(ratio.median())
    assert 0.5 < scale < 2.0
    assert float((ratio / scale).log().abs().max()) < 0.05 * 1.0 + 0.05  # bias <= 5 % plus noise


def test_specs_parse_and_bad_ones_say_what_to_write():
    prior = parse_depth_prior("degraded:mono,seed=2")
    assert isinstance(prior, DegradedPrior) and prior.kind == "mono" and prior.seed == 2
    assert parse_depth_prior("degraded:scale").seed == 0
    with pytest.raises(ValueError, match="unknown depth degradation 'fog'"):
        parse_depth_prior("degraded:fog")
    with pytest.raises(ValueError, match="only seed=N"):
        parse_depth_prior("degraded:mono,blur=3")
    with pytest.raises(ValueError, match="needs ground-truth depth"):
        DegradedPrior("noise")(PriorQuery(torch.zeros(3, 4, 8), None, None, "k"))


def test_mixed_prior_picks_each_part_per_view_reproducibly():
    from cylindersplat.data.depth_prior.mixed import MixedPrior

    prior = parse_depth_prior("mixed:gt+degraded:scale")
    assert isinstance(prior, MixedPrior) and len(prior.parts) == 2
    depth = _room()
    exact = 0
    for i in range(40):
        query = _query(depth, key=f"scene/{i}")
        out = prior(query)
        assert torch.equal(out, prior(query))
        exact += int(torch.equal(out, depth))
    assert 10 < exact < 30  # both parts are drawn, about half each
    assert parse_depth_prior("mixed:gt+degraded:scale,seed=3").seed == 3
    for spec, message in [("mixed:gt", "at least two"), ("mixed:gt+fog", "unknown depth prior 'fog'"),
                          ("mixed:gt+noise,bins=2", "only seed=N")]:
        with pytest.raises(ValueError, match=message):
            parse_depth_prior(spec)


def test_eval_reads_a_degraded_prior_and_refuses_a_bad_kind(synth_dataset, tmp_path, capsys):
    """`eval --depth-prior degraded:KIND` gives the warp the degraded depth (its scores drop from the true depth's);
    an unknown kind is one line naming the kinds, and nothing is written."""
    import json

    from cylindersplat.cli import main

    root = synth_dataset(2, 0)
    scores = {}
    for prior in ("gt", "degraded:scale"):
        out = tmp_path / prior.replace(":", "_")
        assert main(["eval", "--data", str(root), "--no-model", "--depth-prior", prior, "--fills", "none",
                     "--out", str(out), "--pictures", "0"]) == 0
        means = json.loads((out / "results.json").read_text())["means"]
        scores[prior] = next(iter(next(iter(means.values())).values()))["ws_psnr"]
    assert scores["degraded:scale"] < scores["gt"] - 1.0  # a 30 % scale error misplaces the warped pixels
    capsys.readouterr()
    assert main(["eval", "--data", str(root), "--no-model", "--depth-prior", "degraded:fog",
                 "--out", str(tmp_path / "bad")]) in (1, 2)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown depth degradation 'fog'" in err[0] and "mono" in err[0]
    assert not (tmp_path / "bad").exists()
