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
