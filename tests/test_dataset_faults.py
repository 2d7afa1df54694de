"""Issue 27, dataset tools and hostile files: malformed synthetic datasets and JSON are one line, data synth
refuses to mix settings, depth_scale of a scene is honoured."""

import json
import shutil

import pytest
import torch

from cylindersplat.cli import main
from cylindersplat.data.synth import SequenceConfig, write_synthetic_dataset
from cylindersplat.data.synthetic import SyntheticDataset


@pytest.fixture()
def synth_copy(synth_dataset, tmp_path):
    """A writable copy of the session's 1-scene 32x64 dataset."""
    return shutil.copytree(synth_dataset(1, 0), tmp_path / "synth")


def _error(argv, capsys) -> str:
    assert main(argv) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1, lines
    return lines[0]


@pytest.mark.parametrize("meta,message", [
    ({"kind": "room"}, '"frames" must be a non-empty list of frame names, got None'),
    (["00", "01", "02"], "expected a JSON object, got list (is it a file written by cylindersplat data synth?)"),
])
def test_a_malformed_scene_meta_is_one_line(synth_copy, capsys, meta, message):
    scene_meta = synth_copy / "00000000" / "meta.json"
    scene_meta.write_text(json.dumps(meta))
    assert _error(["data", "info", "--data", str(synth_copy), "--occlusion", "0"], capsys) == (
        f"cylindersplat data: error: {scene_meta}: {message}")


def test_a_reflected_pose_is_refused(synth_copy, capsys):
    poses_path = synth_copy / "00000000" / "poses.json"
    poses = json.loads(poses_path.read_text())
    poses["01"][0][0] *= -1
    poses["01"][1][0] *= -1
    poses["01"][2][0] *= -1
    poses_path.write_text(json.dumps(poses))
    with pytest.raises(ValueError, match=r"poses.json frame '01' rotation part is a reflection \(determinant -1\)"):
        SyntheticDataset(synth_copy).example(0)


def test_a_missing_frame_is_named(synth_copy):
    (synth_copy / "00000000" / "02" / "depth.png").unlink()
    with pytest.raises(FileNotFoundError) as info:
        SyntheticDataset(synth_copy).example(0)
    assert str(info.value) == (f"missing depth.png of frame '02': {synth_copy / '00000000' / '02' / 'depth.png'} (the "
                               "scene is incomplete; run data synth again to finish it)")


def test_a_scene_listed_but_absent_is_said(synth_copy):
    meta = json.loads((synth_copy / "meta.json").read_text())
    meta["scenes"].append("00000001")
    (synth_copy / "meta.json").write_text(json.dumps(meta))
    with pytest.warns(UserWarning, match=r"1 of 2 scenes listed in meta.json are missing or incomplete \(00000001\)"):
        assert len(SyntheticDataset(synth_copy)) == 1


def test_the_depth_scale_of_a_scene_is_honoured(synth_copy):
    before = SyntheticDataset(synth_copy).load_frame(SyntheticDataset(synth_copy).example(0).frames[0])[1]
    meta_path = synth_copy / "00000000" / "meta.json"
    meta = json.loads(meta_path.read_text())
    meta["depth_scale"] = 500  # the same PNGs declared as 2 mm units: twice the metres
    meta_path.write_text(json.dumps(meta))
    ds = SyntheticDataset(synth_copy)
    torch.testing.assert_close(ds.load_frame(ds.example(0).frames[0])[1], before * 2)


def test_data_synth_refuses_to_mix_resolutions(synth_copy, capsys):
    write_synthetic_dataset(synth_copy, 1, (32, 64), SequenceConfig(frames=3, spacing=(0.3, 0.5)), seed=0,
                            progress=False)  # the same settings: resumes, nothing to do
    assert _error(["data", "synth", "--out", str(synth_copy), "--scenes", "2", "--resolution", "16x32"], capsys) == (
        f"cylindersplat data: error: {synth_copy} already holds a synthetic dataset made with other settings "
        "(--resolution 32x64 there, 16x32 now; other generator settings); choose another --out, or repeat the "
        "original settings to resume or extend it")
    assert sorted(p.name for p in synth_copy.iterdir()) == ["00000000", "meta.json"]


def test_a_poses_file_nested_100000_deep_is_one_line(panorama_folder, tiny_checkpoint, tmp_path, capsys):
    folder = panorama_folder[0]
    (folder / "poses.json").write_text("[" * 100_000 + "]" * 100_000)
    assert _error(["export", "--input", str(folder), "--checkpoint", str(tiny_checkpoint), "--resolution", "16x32",
                   "--out", str(tmp_path / "g.ply"), "--device", "cpu"], capsys) == (
        f"cylindersplat export: error: {folder / 'poses.json'}: JSON nested too deeply to read (thousands of levels); "
        "is it the right file?")


def test_a_pickle_given_as_lpips_weights_is_refused_unrun(tmp_path):
    import pickle

    from cylindersplat.metrics.lpips import load_lpips

    class Payload:  # would run `touch` if it were ever unpickled
        def __reduce__(self):
            import os

            return os.system, (f"touch {tmp_path / 'ran'}",)

    weights = tmp_path / "lpips.pth"
    weights.write_bytes(pickle.dumps(Payload()))
    with pytest.raises(ValueError) as info:
        load_lpips(weights)
    assert str(info.value) == (f"{weights}: not a weights file that loads without running code (a pickle of more than "
                               "tensors: refused, never run); give the LPIPS weights as a .pth state_dict or "
                               ".safetensors")
    assert not (tmp_path / "ran").exists()


# --- every frame a training or evaluation sample loads is checked once (base.PanoramaDataset.check_frame) ----

DATASET_OVERRIDE = "data.check_plausibility=false in train, or check_plausibility=False on the dataset in Python"


def test_an_all_zero_reference_depth_is_named(synth_copy):
    """Frame 01 is the two-view protocol's target: its depth is only the metrics' reference, never a prior."""
    from cylindersplat.data.io import write_depth_png

    depth = synth_copy / "00000000" / "01" / "depth.png"
    write_depth_png(depth, torch.zeros(32, 64))
    with pytest.raises(ValueError) as info:
        SyntheticDataset(synth_copy)[0]
    assert str(info.value) == (f"depth file {depth} has no positive depth (all zeros = unknown): the file is empty or "
                               "corrupt; write it again or remove the frame")


def test_a_depth_file_out_of_bounds_is_named_and_can_be_read_on_request(synth_copy):
    from cylindersplat.data import make_dataset
    from cylindersplat.data.io import write_depth_png

    depth = synth_copy / "00000000" / "01" / "depth.png"
    write_depth_png(depth, torch.full((32, 64), 0.005))  # 5 mm everywhere: a scene scaled by 1e-3
    with pytest.raises(ValueError) as info:
        make_dataset("synthetic", synth_copy)[0]
    assert str(info.value) == (f"{depth}: median depth 0.005 m is below 0.01 m (check depth_scale or the .npy units); "
                               f"depth is radial metres ({DATASET_OVERRIDE}, to use it anyway)")
    sample = make_dataset("synthetic", synth_copy, check_plausibility=False)[0]
    assert float(sample.target_depths.max()) == pytest.approx(0.005)


def test_a_non_finite_pose_is_named_by_its_image(synth_copy):
    """Readers check their poses files; the base class checks what any reader hands on, once per frame."""
    ds = SyntheticDataset(synth_copy)
    frame = ds.example(0).frames[1]
    broken = type(frame)(frame.name, frame.rgb, frame.c2w.clone(), frame.depth, frame.depth_scale)
    broken.c2w[0, 3] = float("nan")
    with pytest.raises(ValueError) as info:
        ds.check_frame(broken, None)
    assert str(info.value) == (f"pose of {frame.rgb} contains non-finite values (NaN or Inf); fix the dataset's pose "
                               "of this frame (OpenCV camera-to-world, metres)")


def test_checking_frames_costs_little_next_to_reading_them():
    """The check is a median of every 8th row and column (the full one only near a bound): a few per cent of
    decoding the 16-bit PNG it came from."""
    import time

    from cylindersplat.validation import check_depth_plausible

    depth = torch.rand(512, 1024) * 5 + 0.5
    start = time.perf_counter()
    for _ in range(10):
        check_depth_plausible(depth, "x")
    per_frame = (time.perf_counter() - start) / 10
    assert per_frame < 0.004  # 0.5 ms here; reading the PNG takes about 12 ms
