"""Input validation reads the device once per check group, not once per check (issue 35: at 0.1 M Gaussians on a
GPU, 13 host synchronisations of the render call came from validation): ``Gaussians.validate`` and ``validate_c2w``
each wait for the device once on valid input, and still name the first problem, in the same order, on bad input."""

import pytest
import torch

from cylindersplat.gaussians import Gaussians
from cylindersplat.geometry import make_c2w
from cylindersplat.geometry.poses import validate_c2w
from tensor_waits import waits_during


def _waits(fn) -> int:
    """How many times the validators themselves wait for the device during ``fn``."""
    return sum(function in ("validate", "validate_c2w") for _, _, function in waits_during(fn))


def _gaussians(n=50):
    torch.manual_seed(0)
    return Gaussians.from_rgb(torch.randn(n, 3), torch.rand(n, 3) * 0.1, torch.randn(n, 4), torch.rand(n),
                              torch.rand(n, 3))


def test_valid_inputs_are_read_once():
    g = _gaussians()
    assert _waits(g.validate) == 1
    poses = torch.stack([make_c2w(translation=torch.tensor([0.1 * i, 0.0, 0.0])) for i in range(3)])
    assert _waits(lambda: validate_c2w(poses)) == 1


@pytest.mark.parametrize("change,message", [
    (lambda g: g.means.__setitem__((0, 0), float("nan")), "means contains non-finite"),
    (lambda g: g.scales.__setitem__((1, 2), -0.1), "scales must be non-negative"),
    (lambda g: g.opacities.__setitem__(3, 1.5), r"opacities must lie in \[0, 1\]"),
    (lambda g: g.rotations.__setitem__(4, 0.0), "zero quaternion"),
])
def test_bad_gaussians_name_the_problem(change, message):
    g = _gaussians()
    change(g)
    with pytest.raises(ValueError, match=message):
        g.validate()


def test_the_first_problem_wins_as_before():
    g = _gaussians()
    g.scales[0, 0] = float("inf")  # non-finite scales are reported before negative ones
    g.scales[1, 0] = -1.0
    with pytest.raises(ValueError, match="scales contains non-finite"):
        g.validate()


@pytest.mark.parametrize("change,message", [
    (lambda p: p.__setitem__((0, 0, 3), float("inf")), "non-finite"),
    (lambda p: p.__setitem__((1, 0, 0), 2.0), r"not orthonormal \(max \|R R\^T - I\| = 3"),
    (lambda p: p.__setitem__((0, 0, 0), -1.0), "reflection"),
    (lambda p: p.__setitem__((2, 3, 0), 0.5), r"last row must be \[0, 0, 0, 1\]"),
])
def test_bad_poses_name_the_problem(change, message):
    poses = torch.stack([make_c2w() for _ in range(3)])
    change(poses)
    with pytest.raises(ValueError, match=message):
        validate_c2w(poses)


def test_the_deferred_forms_wait_for_nothing_and_flag_what_the_validators_name():
    # The render path that reads the device once (issue 35) queues these flags and reads them with its pair count.
    from cylindersplat.geometry.poses import c2w_problem_flags
    from cylindersplat.validation import camera_too_far

    g = _gaussians()
    poses = torch.stack([make_c2w(translation=torch.tensor([0.1 * i, 0.0, 0.0])) for i in range(3)])
    flags = []

    def queue():
        flags.extend([g.problem_flags(), c2w_problem_flags(poses), camera_too_far(poses)])

    assert waits_during(queue) == []
    assert not any(bool(f.any()) for f in flags)
    g.opacities[3] = 1.5
    poses[1, 0, 0] = -1.0
    poses[2, 2, 3] = 2e4
    assert g.problem_flags().tolist() == [False] * 5 + [False, True, False]  # finite x5, scales, opacities, quaternions
    assert c2w_problem_flags(poses).tolist() == [False, False, True, False]  # the reflection
    assert bool(camera_too_far(poses)) and not bool(camera_too_far(poses[:2]))
    with pytest.raises(ValueError, match=r"opacities must lie in \[0, 1\]"):
        g.validate()
    with pytest.raises(ValueError, match="sh must have shape"):  # the structure is checked at once, as before
        Gaussians(g.means, g.scales, g.rotations, g.opacities, g.sh[:2]).problem_flags()
    with pytest.raises(ValueError, match=r"must have shape \(\.\.\., 4, 4\)"):
        c2w_problem_flags(poses[..., :3])
