"""The photometric scale search of the depth priors (model/prior_alignment.py), against known scale errors."""

from __future__ import annotations

import pytest
import torch

from cylindersplat.data import SyntheticDataset
from cylindersplat.geometry import make_c2w
from cylindersplat.model import from_config
from cylindersplat.model.prior_alignment import ScaleSearch, photometric_prior_scales, scale_costs


@pytest.fixture(scope="module")
def wide_sample(tmp_path_factory):
    """A procedural two-view sample at 64x128 whose views are 1-1.5 m apart (enough parallax to see the scale)."""
    from cylindersplat.data.synth import SequenceConfig, write_synthetic_dataset

    root = tmp_path_factory.mktemp("align")
    write_synthetic_dataset(root, 1, (64, 128), SequenceConfig(frames=3, spacing=(1.0, 1.5)), seed=3, progress=False)
    return SyntheticDataset(root, views="two_view")[0]



def _inputs(sample):
    """The sample's context images, true depths and poses as a batch of one."""
    return sample.context_images[None], sample.context_gt_depths[None], sample.context_poses[None]

def test_recovers_known_scale_errors_of_the_true_depth(wide_sample):
    """The true depth shrunk by 0.8 in one view and stretched by 1.25 in the other: the search undoes both."""
    images, depth, c2w = _inputs(wide_sample)
    errors = torch.tensor([0.8, 1.25])
    found = photometric_prior_scales(images, depth * errors[:, None, None], c2w)[0]
    torch.testing.assert_close(found * errors, torch.ones(2), atol=0.03, rtol=0)


def test_true_depth_is_left_at_scale_one(wide_sample):
    images, depth, c2w = _inputs(wide_sample)
    torch.testing.assert_close(photometric_prior_scales(images, depth, c2w)[0], torch.ones(2), atol=0.03, rtol=0)


def test_cost_is_lowest_at_the_true_scale(wide_sample):
    images, depth, c2w = _inputs(wide_sample)
    candidates = torch.tensor([[0.6, 0.8, 1.0, 1.25, 1.6]])
    for view in (0, 1):
        costs = scale_costs(images, depth, c2w, view, candidates)[0][0]
        assert int(costs.argmin()) == 2, costs


def test_no_parallax_keeps_the_prior(wide_sample):
    """Both views at one centre (a rotation apart): every scale lifts to the same colours; nothing is changed."""
    images, depth = wide_sample.context_images[None], wide_sample.context_gt_depths[None]
    turn = torch.tensor([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    c2w = torch.stack([make_c2w(), make_c2w(rotation=turn)])[None]
    found = photometric_prior_scales(images, depth * 0.7, c2w)[0]
    assert torch.equal(found, torch.ones(2))


def test_single_view_and_missing_prior_are_left_alone(wide_sample):
    images, depth, c2w = _inputs(wide_sample)
    assert torch.equal(photometric_prior_scales(images[:, :1], depth[:, :1], c2w[:, :1]), torch.ones(1, 1))
    missing = depth.clone()
    missing[:, 1] = 0
    assert float(photometric_prior_scales(images, missing, c2w)[0, 1]) == 1.0


def test_search_at_pooled_resolution_matches(wide_sample):
    """Searching on images pooled to 32 rows finds the same scale as at the full 64 rows (to the fine step)."""
    images, depth, c2w = _inputs(wide_sample)
    scaled = depth * torch.tensor([0.8, 1.25])[:, None, None]
    full = photometric_prior_scales(images, scaled, c2w)
    pooled = photometric_prior_scales(images, scaled, c2w, ScaleSearch(max_rows=32))
    torch.testing.assert_close(pooled, full, atol=0.04, rtol=0)


def test_model_applies_the_scales_before_both_branches(wide_sample):
    """With prior_alignment=photometric the model's output equals the plain model's on the rescaled prior."""
    images, c2w = wide_sample.context_images[None], wide_sample.context_poses[None]
    prior = wide_sample.context_gt_depths[None] * torch.tensor([0.8, 1.25])[:, None, None]
    torch.manual_seed(0)
    aligned = from_config("tiny_paper", prior_alignment="photometric").eval()
    plain = from_config("tiny_paper").eval()
    plain.load_state_dict(aligned.state_dict())
    with torch.no_grad():
        out = aligned(images, prior, c2w)
        reference = plain(images, prior * out.prior_scales[..., None, None], c2w)
    assert out.prior_scales.shape == (1, 2)
    torch.testing.assert_close(out.refined_depth, reference.refined_depth)
    torch.testing.assert_close(out.gaussians.sh, reference.gaussians.sh)
    torch.testing.assert_close(out.gaussians.means, reference.gaussians.means)
    assert plain(images, prior, c2w).prior_scales is None


def test_unknown_alignment_is_rejected():
    with pytest.raises(ValueError, match="prior_alignment must be one of none, photometric"):
        from_config("tiny_paper", prior_alignment="median")


def test_export_cli_rescales_a_half_scale_depth(wide_sample, tiny_checkpoint, tmp_path, capsys):
    """A folder whose depth files are half the true depth (a relative depth network's output, say): with
    --prior-scale photometric the export command finds x2 for every view and says so."""
    from cylindersplat.cli import main
    from cylindersplat.inference import write_panorama_folder

    folder = write_panorama_folder(tmp_path / "scene", wide_sample.context_images, wide_sample.context_poses,
                                   wide_sample.context_gt_depths * 0.5)
    assert main(["export", "--input", str(folder), "--checkpoint", str(tiny_checkpoint), "--resolution", "64x128",
                 "--out", str(tmp_path / "scene.ply"), "--prior-scale", "photometric",
                 "--skip-plausibility-checks"]) == 0
    line = next(out for out in capsys.readouterr().out.splitlines() if out.startswith("depth rescaled"))
    factors = [float(part.split(" x")[1]) for part in line.split(": ", 1)[1].split(", ")]
    assert len(factors) == 2 and all(abs(f - 2.0) < 0.06 for f in factors), line


def test_default_run_warns_about_a_half_scale_depth(wide_sample, tiny_checkpoint, tmp_path, capsys):
    """With the default --prior-scale model and weights trained without alignment, a depth half the poses' scale is
    used as given but named in a warning with its factor; the true depth gives none, nor does --prior-scale none."""
    from cylindersplat.cli import main
    from cylindersplat.inference import write_panorama_folder

    def export(depth_factor: float, *extra: str) -> list[str]:
        name = f"scene{depth_factor}{len(extra)}"
        folder = write_panorama_folder(tmp_path / name, wide_sample.context_images, wide_sample.context_poses,
                                       wide_sample.context_gt_depths * depth_factor)
        capsys.readouterr()
        assert main(["export", "--input", str(folder), "--checkpoint", str(tiny_checkpoint), "--resolution",
                     "64x128", "--out", str(tmp_path / f"{name}.ply"), *extra]) == 0
        return [line for line in capsys.readouterr().err.splitlines() if "poses' scale" in line]

    half = export(0.5)
    assert len(half) == 1 and "--prior-scale photometric" in half[0], half
    factors = [float(part.split(" x")[1].rstrip(";")) for part in half[0].split("finds ")[1].split("; ")[0].split(", ")]
    assert len(factors) == 2 and all(abs(f - 2.0) < 0.06 for f in factors), half
    assert export(1.0) == []
    assert export(0.5, "--prior-scale", "none") == []


def test_memo_searches_each_input_once(wide_sample, monkeypatch):
    """ScaleMemo gives the search's factors, searches a repeated input (alone or inside a batch) only once, and a
    changed depth map again."""
    from cylindersplat.model import prior_alignment

    images, depth = wide_sample.context_images[None], wide_sample.context_priors[None]
    c2w = wide_sample.context_poses[None]
    direct = photometric_prior_scales(images, depth * 0.7, c2w)
    searched = []
    real = prior_alignment.photometric_prior_scales
    monkeypatch.setattr(prior_alignment, "photometric_prior_scales",
                        lambda i, d, c, s: searched.append(d.shape[0]) or real(i, d, c, s))
    memo = prior_alignment.ScaleMemo()
    assert torch.equal(memo(images, depth * 0.7, c2w), direct)
    assert torch.equal(memo(images, depth * 0.7, c2w), direct) and searched == [1]
    both = memo(torch.cat([images, images]), torch.cat([depth * 0.7, depth * 1.3]), torch.cat([c2w, c2w]))
    assert searched == [1, 1] and torch.equal(both[0], direct[0])  # only the new item searched
    assert torch.allclose(both[1] * 1.3, direct[0] * 0.7, rtol=0.05)  # it undoes its own factor
    small = prior_alignment.ScaleMemo(capacity=1)
    small(images, depth, c2w), small(images, depth * 0.7, c2w)
    assert len(small) == 1


# --- cost: linear in the number of views, once per distinct view ------------------------------------------------


def _views_on_a_line(count: int, seed: int = 0):
    """``count`` random 8x16 panoramas with depth, 0.5 m apart along x: (images, depth, c2w) with batch 1."""
    gen = torch.Generator().manual_seed(seed)
    images = torch.rand(1, count, 3, 8, 16, generator=gen)
    depth = torch.rand(1, count, 8, 16, generator=gen) * 3 + 1
    c2w = torch.stack([make_c2w(translation=torch.tensor([0.5 * i, 0.0, 0.0])) for i in range(count)])[None]
    return images, depth, c2w


def _count_projections(monkeypatch) -> list[int]:
    from cylindersplat.model import prior_alignment

    calls = []
    real = prior_alignment.project_equirect
    monkeypatch.setattr(prior_alignment, "project_equirect", lambda *a, **k: calls.append(1) or real(*a, **k))
    return calls


def test_search_cost_grows_linearly_with_the_views(monkeypatch, capsys):
    """Each view is read in `neighbours` others (coarse + fine pass: 2 projections each), not in all V - 1."""
    calls = _count_projections(monkeypatch)
    search = ScaleSearch(neighbours=2)
    counted = {}
    for count in (4, 8, 16):
        calls.clear()
        found = photometric_prior_scales(*_views_on_a_line(count), search)
        assert found.shape == (1, count) and bool(torch.isfinite(found).all())
        counted[count] = len(calls)
    assert counted == {4: 4 * 2 * 2, 8: 8 * 2 * 2, 16: 16 * 2 * 2}
    lines = capsys.readouterr().err.splitlines()  # 16 views: progress lines where the output is not a terminal
    assert lines[0] == "photometric depth-scale search started: 16 views, a line every 4 views"
    assert [line.split(" (")[0] for line in lines[1:]] == [f"photometric depth-scale search: {k}/16 views"
                                                          for k in (4, 8, 12, 16)]


def test_neighbours_are_the_nearest_camera_centres():
    from cylindersplat.model.prior_alignment import nearest_views

    _, _, c2w = _views_on_a_line(6)
    assert nearest_views(c2w, 2)[0].tolist() == [[1, 2], [0, 2], [1, 3], [2, 4], [3, 5], [3, 4]]
    assert nearest_views(c2w[:, :3], 2) is None  # 2-3 views: every other view, as before


def test_reading_listed_neighbours_equals_reading_every_other_view():
    from cylindersplat.model.prior_alignment import pixel_errors

    images, depth, c2w = _views_on_a_line(4)
    scales = torch.tensor([[0.8, 1.0, 1.3]])
    every = pixel_errors(images, depth, c2w, 1, scales)
    listed = pixel_errors(images, depth, c2w, 1, scales, torch.tensor([[0, 2, 3]]))
    assert torch.equal(every, listed)


def test_the_same_frames_listed_ten_times_are_searched_once(wide_sample, monkeypatch):
    images, depth, c2w = _inputs(wide_sample)
    depth = depth * torch.tensor([0.8, 1.25])[:, None, None]
    calls = _count_projections(monkeypatch)
    once = photometric_prior_scales(images, depth, c2w)
    single = len(calls)
    repeated = photometric_prior_scales(images.repeat(1, 10, 1, 1, 1), depth.repeat(1, 10, 1, 1),
                                        c2w.repeat(1, 10, 1, 1))
    assert len(calls) == 2 * single and torch.equal(repeated, once.repeat(1, 10))
