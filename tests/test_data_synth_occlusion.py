"""Disocclusion options of the generator (target off the line, occluders, doorways, the ``occlusion``
profile) and the occluded share ``cylindersplat data info`` reports."""

import json
import math
import re

import numpy as np
import pytest
import torch

from cylindersplat.cli import main
from cylindersplat.commands.data import PROFILE_NAMES, PROTOCOL_NAMES
from cylindersplat.data.preview import (
    example_occlusion,
    occlusion_summary,
    open_dataset,
)
from cylindersplat.data.synth import (
    LAYOUTS,
    PROFILES,
    Material,
    SceneBuilder,
    SequenceConfig,
    add_occluders,
    camera_path,
    generate_sequence,
    profile_config,
    target_offset,
    write_synthetic_dataset,
)
from cylindersplat.data.views import PROTOCOLS

torch.set_num_threads(1)


def test_profile_targets_see_what_no_context_sees(tmp_path):
    """The point of the profile: a real share of two_view target pixels hidden from both contexts,
    spread over scenes, where the default line has almost none (32x64, 4 scenes)."""
    shares = {}
    for name in ("default", "occlusion"):
        out = write_synthetic_dataset(tmp_path / name, 4, (32, 64), profile_config(name), seed=0, progress=False)
        ds = open_dataset(out, views="two_view")
        shares[name] = [example_occlusion(ds, i).occluded[0] for i in range(len(ds))]
        summary = occlusion_summary(ds)
        assert summary["examples"] == 4 and summary["mean"] == pytest.approx(np.mean(shares[name]))
    assert np.mean(shares["occlusion"]) >= 0.03
    assert np.mean(shares["occlusion"]) >= 2.5 * np.mean(shares["default"])
    assert sum(s >= 0.02 for s in shares["occlusion"]) >= 3  # not all from one scene


@pytest.mark.parametrize("index", range(6))
def test_moved_target_keeps_clearance_and_leaves_the_line(index):
    cfg = profile_config("occlusion")
    seq = generate_sequence(3, index, cfg)
    centres = seq.poses[:, :3, 3]
    # Every camera, the segment between the contexts and the way to the moved target stay clear,
    # also of the occluders added after the cameras were placed.
    assert seq.scene.clearance_ok(centres, cfg.clearance - 1e-4).all()
    path = torch.from_numpy(camera_path(seq.poses)).float()
    assert seq.scene.clearance_ok(path, cfg.clearance - 1e-4).all()
    x0, x1, z0, z1 = seq.scene.free_region
    assert ((centres[:, 0] >= x0) & (centres[:, 0] <= x1) & (centres[:, 2] >= z0) & (centres[:, 2] <= z1)).all()
    # Contexts keep the line's spacing; the target stands 0.4-1.0 m from its place on the line,
    # at least cos(45 deg) of that sideways: off the segment, not on it.
    assert float((centres[2] - centres[0]).norm()) == pytest.approx(2 * seq.spacing, abs=1e-5)
    assert 0.5 <= seq.spacing <= 1.0
    moved = float((centres[1] - (centres[0] + centres[2]) / 2).norm())
    assert 0.4 - 1e-5 <= moved <= 1.0 + 1e-5
    assert target_offset(seq.poses) >= 0.4 * math.cos(math.pi / 4) - 1e-5
    assert torch.allclose(centres[:, 1], centres[0, 1].expand(3))  # same height
    assert torch.equal(seq.poses[0, :3, :3], seq.poses[1, :3, :3])  # one shared yaw


def test_occluders_stand_near_the_path_and_keep_clearance():
    b = SceneBuilder()
    m = b.material(Material("plain", (0.5, 0.5, 0.5), (0.5, 0.5, 0.5)))
    b.box((-4.2, 0.0, -4.2), (4.2, 0.2, 4.2), m)  # floor only: a 8 x 8 m room without walls
    room = b.build(free_region=(-4.0, 4.0, -4.0, 4.0), floor_y=0.0, ceiling_y=-2.8)
    path = np.stack([np.linspace(-1, 1, 21), np.full(21, -1.5), np.zeros(21)], -1)
    scene = add_occluders(room, np.random.default_rng(0), path, count=6, clearance=0.3)
    assert len(scene.materials) > len(room.materials) and scene.num_primitives() >= room.num_primitives() + 6
    assert scene.clearance_ok(torch.from_numpy(path).float(), 0.3).all()
    # The originals are kept, the additions reference their own (appended) materials.
    assert torch.equal(scene.box_lo[: len(room.box_lo)], room.box_lo)
    for mats in (scene.box_mat, scene.sphere_mat, scene.cyl_mat):
        assert mats.numel() == 0 or int(mats.max()) < len(scene.materials)
    # Near the path: each added object's centre within clearance + reach (1.2 m) + its half size (<= 1.1 m).
    centres = torch.cat([((scene.box_lo + scene.box_hi) / 2)[len(room.box_lo):], scene.cyl_center, scene.sphere_center])
    assert len(centres) >= 6
    to_path = torch.hypot((centres[:, 0].abs() - 1).clamp(min=0), centres[:, 2])
    assert float(to_path.max()) <= 0.3 + 1.2 + 1.1 + 1e-4


def test_through_doorways_walks_through_the_door():
    cfg = SequenceConfig(layouts=("two_rooms",), through_doorways=1.0, spacing=(0.5, 1.0))
    crossings = 0
    for index in range(6):
        seq = generate_sequence(0, index, cfg)
        ((dx, _, _, _),) = seq.scene.doorways
        side = (seq.poses[:, 0, 3] - dx).sign()
        crossings += int(side[0] != side[-1])
        assert seq.scene.clearance_ok(seq.poses[:, :3, 3], cfg.clearance - 1e-4).all()
    assert crossings >= 4  # the rest fell back to a free line


def test_config_validation_and_profiles():
    assert set(PROFILE_NAMES) == set(PROFILES) and set(PROTOCOL_NAMES) == set(PROTOCOLS)
    assert profile_config() == SequenceConfig()
    occ = profile_config("occlusion", occluders=2, spacing=None)
    assert occ.occluders == 2 and occ.spacing == (0.5, 1.0) and occ.target_offset[1] > 0
    assert profile_config("occlusion", layouts=("room", "outdoor")).layout_weights == ()
    with pytest.raises(ValueError, match="unknown profile"):
        profile_config("nope")
    with pytest.raises(ValueError, match=">= 3 frames"):
        SequenceConfig(frames=2, target_offset=(0.3, 0.5))
    with pytest.raises(ValueError, match="target_offset"):
        SequenceConfig(target_offset=(0.5, 0.3))
    with pytest.raises(ValueError, match="one weight per layout"):
        SequenceConfig(layout_weights=(1.0, 2.0))
    with pytest.raises(ValueError, match="through_doorways"):
        SequenceConfig(through_doorways=1.5)
    assert len(PROFILES["occlusion"]["layout_weights"]) == len(LAYOUTS)


def test_synth_profile_and_info_print_the_occluded_share(tmp_path, capsys):
    out = tmp_path / "occ"
    assert main(["data", "synth", "--out", str(out), "--scenes", "2", "--resolution", "32x64", "--profile", "occlusion",
                 "--occluders", "3", "--layouts", "two_rooms:3,l_shape"]) == 0
    config = json.loads((out / "meta.json").read_text())["config"]
    assert config["occluders"] == 3 and config["target_offset"] == [0.4, 1.0] and config["spacing"] == [0.5, 1.0]
    assert config["layouts"] == ["two_rooms", "l_shape"] and config["layout_weights"] == [3.0, 1.0]
    capsys.readouterr()
    assert main(["data", "info", "--data", str(out), "--count", "2"]) == 0
    text = capsys.readouterr().out
    listed = re.findall(r"target_offset=([\d.]+).*baseline ([\d.]+) m, occluded ([\d.]+) %", text)
    assert len(listed) == 2
    for offset, baseline, _ in listed:
        assert 0.28 <= float(offset) <= 1.0 and 1.0 - 1e-3 <= float(baseline) <= 2.0 + 1e-3
    mean = re.search(r"over 2 of 2 examples \(2 targets\): mean ([\d.]+) %", text)
    assert mean and float(mean.group(1)) == pytest.approx(np.mean([float(x[2]) for x in listed]), abs=0.01)
    assert main(["data", "info", "--data", str(out), "--count", "1", "--occlusion", "0"]) == 0
    assert "occluded" not in capsys.readouterr().out
