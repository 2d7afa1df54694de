"""Trivial hole fills (evaluation/fills.py) against independent constructions: a direct sparse solve of the
discrete Laplace equation, the solid-angle mean written out, and the compositing rule."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch

from cylindersplat.evaluation import Method, fill_methods, with_fill
from cylindersplat.evaluation.fills import fill_uncovered, harmonic_inpaint, mean_input_colour
from cylindersplat.render.api import RenderOutput


def _laplace_reference(values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Solve ``deg(i) x_i - sum_{j ~ i} x_j = 0`` on the unknown pixels by scipy's sparse LU: neighbours are
    left/right (wrapping) and up/down (none beyond the first and last row); known pixels are fixed."""
    h, w = known.shape
    index = -np.ones((h, w), dtype=int)
    unknown = np.argwhere(~known)
    index[~known] = np.arange(len(unknown))
    rows, cols, vals = [], [], []
    b = np.zeros(len(unknown))
    for k, (i, j) in enumerate(unknown):
        neighbours = [(i, (j - 1) % w), (i, (j + 1) % w)] + [(ii, j) for ii in (i - 1, i + 1) if 0 <= ii < h]
        rows.append(k), cols.append(k), vals.append(len(neighbours))
        for ii, jj in neighbours:
            if known[ii, jj]:
                b[k] += values[ii, jj]
            else:
                rows.append(k), cols.append(index[ii, jj]), vals.append(-1.0)
    solution = spla.spsolve(sp.csr_matrix((vals, (rows, cols)), shape=(len(unknown),) * 2), b)
    out = values.copy()
    out[~known] = solution
    return out


def test_harmonic_inpaint_equals_a_direct_sparse_solve():
    gen = torch.Generator().manual_seed(0)
    h, w = 10, 20
    image = torch.rand(3, h, w, generator=gen, dtype=torch.float64)
    known = torch.rand(h, w, generator=gen) < 0.3
    known[4:8, 5:15] = False  # a large hole, and one that touches the seam
    known[:, 0] = False
    out = harmonic_inpaint(image, known)
    for c in range(3):
        np.testing.assert_allclose(out[c].numpy(), _laplace_reference(image[c].numpy(), known.numpy()), atol=1e-6)
    assert torch.equal(out[:, known], image[:, known])  # known pixels untouched
    # the maximum principle: the fill stays within the known colours' range
    assert out.min() >= image[:, known].min() - 1e-9 and out.max() <= image[:, known].max() + 1e-9


def test_harmonic_inpaint_edge_cases():
    image = torch.rand(3, 4, 8, dtype=torch.float64)
    everything = torch.ones(4, 8, dtype=torch.bool)
    assert torch.equal(harmonic_inpaint(image, everything), image)
    nothing = harmonic_inpaint(image, ~everything)  # no known pixel: the image mean
    assert torch.allclose(nothing, image.mean(dim=(-2, -1), keepdim=True).expand_as(image))
    one = torch.zeros(4, 8, dtype=torch.bool)
    one[2, 3] = True  # a single known pixel: its colour everywhere
    assert torch.allclose(harmonic_inpaint(image, one), image[:, 2:3, 3:4].expand_as(image), atol=1e-6)


def test_mean_input_colour_weights_rows_by_solid_angle():
    h, w = 6, 12
    images = torch.zeros(2, 3, h, w, dtype=torch.float64)
    images[0, 0, 0] = 1.0  # red only on the top row of view 0
    images[1, 1] = 0.5  # green everywhere in view 1
    weight = np.sin(np.pi * (np.arange(h) + 0.5) / h)
    expected_red = weight[0] * w / (2 * weight.sum() * w)
    mean = mean_input_colour(images)
    assert mean.tolist() == pytest.approx([expected_red, 0.25, 0.0])


def test_fill_goes_behind_the_render_and_leaves_depth_alone():
    h, w = 8, 16
    alpha = torch.zeros(1, h, w)
    alpha[:, :, :8] = 1.0
    alpha[:, :, 8] = 0.25  # partly covered
    colour = torch.tensor([0.2, 0.4, 0.6]).view(1, 3, 1, 1)
    render = RenderOutput(colour * alpha[:, None], torch.full((1, h, w), 2.0) * alpha, alpha)
    inputs = torch.full((2, 3, h, w), 0.5)
    for fill, behind in (("mean", torch.tensor([0.5, 0.5, 0.5])), ("inpaint", torch.tensor([0.2, 0.4, 0.6]))):
        out = fill_uncovered(render, inputs, fill)
        expected = render.rgb + (1 - alpha)[:, None] * behind.view(1, 3, 1, 1)
        assert torch.allclose(out.rgb, expected, atol=1e-5), fill
        assert out.depth is render.depth and out.alpha is render.alpha
    with pytest.raises(ValueError, match="unknown fill"):
        fill_uncovered(render, inputs, "zeros")


def test_fill_methods_name_and_describe_their_background():
    render = RenderOutput(torch.zeros(1, 3, 4, 8), torch.zeros(1, 4, 8), torch.zeros(1, 4, 8))
    base = Method("warp", lambda sample: render)
    methods = fill_methods(base, ["mean", "inpaint"])
    assert [m.name for m in methods] == ["warp", "warp + mean fill", "warp + inpaint fill"]
    assert [m.background for m in methods] == ["black", "the inputs' mean colour",
                                               "a 2-D inpaint from the covered pixels"]

    class FakeSample:
        context_images = torch.full((1, 3, 4, 8), 0.3)

    assert torch.allclose(methods[1].run(FakeSample()).rgb, torch.full((1, 3, 4, 8), 0.3))
    with pytest.raises(ValueError, match="unknown fill"):
        with_fill(base, "blur")
