"""The CLI's error boundary: expected failures are one line (exit 1) and lose nothing; bugs keep tracebacks."""

import errno
import json
import os

import pytest
import torch

from cylindersplat.cli import expected_failure, main


@pytest.mark.parametrize("override,message", [
    ("train.seed=abc", "train.seed must be an integer"),
    ("train.lr=[", "not valid YAML"),
    ("data.batch_size=0", "data.batch_size must be >= 1"),
    ("train.keep_checkpoints=abc", "train.keep_checkpoints must be an integer"),
    ("train.stages=3", "must be a list"),
    ("train.nope=1", "unknown config key"),
])
def test_bad_config_values_are_one_line(tmp_path, capsys, override, message):
    assert main(["train", "--data", str(tmp_path), "--out", str(tmp_path / "run"), override]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "run").exists()


def test_malformed_yaml_names_the_file(tmp_path, capsys):
    bad = tmp_path / "bad.yaml"
    bad.write_text("train: {lr: [1, 2\n")
    assert main(["train", "--config", str(bad)]) == 1
    assert "bad.yaml: malformed YAML" in capsys.readouterr().err


def test_corrupt_checkpoint_is_one_line(tmp_path, capsys):
    weights = tmp_path / "model.safetensors"
    weights.write_bytes(b"\x00" * 64)
    folder = tmp_path / "inputs"
    folder.mkdir()
    code = main(["export", "--input", str(folder), "--checkpoint", str(weights), "--out", str(tmp_path / "g.ply")])
    assert code == 1
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def _wrapped(exc):
    """``exc`` as the context of a library's own exception (what a wrapped full disk looks like)."""
    try:
        try:
            raise exc
        except OSError:
            raise RuntimeError("writer failed") from exc
    except RuntimeError as outer:
        return outer


@pytest.mark.parametrize("exc,expected", [
    (OSError(errno.ENOSPC, "No space left on device", "out/g.ply"),
     "disk full while writing out/g.ply: free space or choose another --out"),
    (OSError(errno.ENOSPC, "No space left on device"), "disk full: free space or choose another --out"),
    (OSError(errno.EDQUOT, "Disk quota exceeded", "out/g.ply"), "disk quota exceeded while writing out/g.ply"),
    (OSError(errno.EROFS, "Read-only file system", "/mnt/ro/x"),
     "read-only file system at /mnt/ro/x: choose another --out"),
    (OSError(errno.EFBIG, "File too large", "out/v.mp4"), "file too large while writing out/v.mp4"),
    (PermissionError(errno.EACCES, "Permission denied", "/root/x"), "permission denied for /root/x"),
    (_wrapped(OSError(errno.ENOSPC, "No space left on device", "run/state.pt")),
     "disk full while writing run/state.pt"),
    (RuntimeError('Error while serializing: I/O error: No space left on device (os error 28) '
                  'at path "w/m.safetensors"'),
     "disk full while writing w/m.safetensors"),
    (torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 20 GiB"), "out of memory"),
    (RuntimeError("[enforce fail at alloc_cpu.cpp:127] DefaultCPUAllocator: can't allocate memory: you tried to "
                  "allocate 70368744177664 bytes."), "--resolution"),
    (MemoryError(), "out of memory: use a smaller resolution"),
    (MemoryError("this render needs about 9.1 GiB"), "this render needs about 9.1 GiB"),
    (RuntimeError("Torch not compiled with CUDA enabled"), "--device cpu"),
    (ModuleNotFoundError("No module named 'unik3d'", name="unik3d"), "'unik3d' is not installed"),
])
def test_expected_failures_get_a_message(exc, expected):
    assert expected in expected_failure(exc)


@pytest.mark.parametrize("exc", [TypeError("unsupported operand"), KeyError("x"), RuntimeError("shape mismatch"),
                                 OSError(errno.EIO, "Input/output error"), _wrapped(OSError(errno.EBADF, "Bad fd"))])
def test_bugs_keep_their_traceback(exc):
    assert expected_failure(exc) is None


def test_debug_flag_shows_the_traceback(tmp_path):
    with pytest.raises(ValueError, match="train.seed"):
        main(["--debug", "train", "--data", str(tmp_path), "train.seed=abc"])


def test_weights_with_nan_are_refused_by_name(tmp_path):
    from cylindersplat.model import from_config, load_model, save_model

    model = from_config("tiny_paper")
    with torch.no_grad():
        next(model.parameters()).fill_(float("nan"))
    save_model(model, tmp_path / "diverged.safetensors")
    with pytest.raises(ValueError, match="NaN/inf.*diverged"):
        load_model(tmp_path / "diverged.safetensors")


def test_device_option_resolves_auto_and_refuses_missing_cuda():
    import argparse

    from cylindersplat.commands._arguments import device

    assert device("auto") == ("cuda" if torch.cuda.is_available() else "cpu")
    assert device("CPU") == "cpu"
    with pytest.raises(argparse.ArgumentTypeError, match="not a torch device"):
        device("gpu please")
    if not torch.cuda.is_available():
        with pytest.raises(argparse.ArgumentTypeError, match="no usable CUDA"):
            device("cuda:0")


# -- every expected failure of a command: exit != 0, one line naming the file/option, no traceback, and the
# -- outputs of an earlier run untouched ---------------------------------------------------------------------

PREVIOUS = b"the output of an earlier run"


def _checkpoint_variant(kind, good, tmp_path):
    """A --checkpoint that is not what it should be."""
    import json

    from safetensors.torch import load_file, save_file

    from cylindersplat.model import get_config
    from cylindersplat.model.config import config_to_dict

    path = tmp_path / f"{kind}.safetensors"
    if kind == "truncated":
        path.write_bytes(good.read_bytes()[:5000])
    elif kind == "random":
        path.write_bytes(bytes(torch.randint(0, 256, (4096,), generator=torch.Generator().manual_seed(0)).tolist()))
    elif kind == "wrong_config":  # tiny weights under the paper's config
        save_file(load_file(str(good)), str(path),
                  metadata={"cylindersplat_config": json.dumps(config_to_dict(get_config("paper")))})
    elif kind == "pickle":  # torch.save renamed to .safetensors
        torch.save({"weight": torch.zeros(3)}, path)
    elif kind == "latest_dir":  # a run's checkpoints/latest given as a folder
        path = tmp_path / "run" / "checkpoints" / "latest"
        path.mkdir(parents=True)
    return path


def _full_disk(code):
    """plyfile's writer failing part-way with ``code`` (the file system's errno), as a full disk does."""
    def write(self, stream):
        with open(stream, "wb") as f:
            f.write(b"ply\nformat binary_little_endian 1.0\n")
        raise OSError(code, os.strerror(code))
    return write


def _export_case(tmp_path, folder, checkpoint, monkeypatch, case):
    """-> argv of an `export` that must fail; the earlier export at out/g.ply must survive it."""
    import plyfile

    out = tmp_path / "out" / "g.ply"
    argv = ["export", "--input", str(folder), "--checkpoint", str(checkpoint), "--out", str(out), "--min-opacity", "0"]
    kind, _, detail = case.partition(":")
    if kind == "checkpoint":
        argv[4] = str(_checkpoint_variant(detail, checkpoint, tmp_path))
    elif kind == "poses":
        data = json.loads((folder / "poses.json").read_text())
        if detail == "c2w_string":
            data["frames"][0]["c2w"] = "identity"
        elif detail == "c2w_strings":
            data["frames"][1]["c2w"] = [["1", "0", "0", "0"]] * 4
        elif detail == "frames_dict":
            data["frames"] = {"pano_00.png": data["frames"][0]}
        elif detail == "depth_scale_string":
            data["depth_scale"] = "1000"
        (folder / "poses.json").write_text(json.dumps(data))
    elif kind == "huge_header":  # a PNG whose header claims 40000x20000 (800 MP)
        (folder / "pano_00.png").write_bytes(_png_header(40000, 20000))
    elif kind == "huge_limit":  # the 200 MP limit, made tiny
        monkeypatch.setattr("cylindersplat.data.io.MAX_IMAGE_PIXELS", 100)
    elif kind == "out_under_file":
        (tmp_path / "afile").write_bytes(PREVIOUS)
        argv[argv.index("--out") + 1] = str(tmp_path / "afile" / "g.ply")
    elif kind == "device":
        argv += ["--device", "cuda"]
    elif kind == "resolution":
        argv += ["--resolution", "40x80"]
    elif kind == "memory":  # less free memory than the model forward needs at 64x128, enough for 32x64
        monkeypatch.setattr("cylindersplat.render.rasterize.available_memory", lambda device: 70 * 2**20)
    elif kind == "disk":
        monkeypatch.setattr(plyfile.PlyData, "write", _full_disk(getattr(errno, detail)))
    elif kind == "oom":
        from cylindersplat.model import CylinderSplat

        error = (torch.OutOfMemoryError("CUDA out of memory. Tried to allocate 20.00 GiB") if detail == "torch"
                 else MemoryError())

        def forward(*args, **kwargs):
            raise error
        monkeypatch.setattr(CylinderSplat, "forward", forward)
    return argv


def _png_header(width, height):
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"")) + chunk(b"IEND", b""))


@pytest.mark.parametrize("case,fragments", [
    ("checkpoint:truncated", ["truncated.safetensors", "not a readable .safetensors", "is it complete"]),
    ("checkpoint:random", ["random.safetensors", "not a readable .safetensors"]),
    ("checkpoint:wrong_config", ["wrong_config.safetensors", "do not match the model config"]),
    ("checkpoint:pickle", ["pickle.safetensors", "PyTorch pickle", "model.safetensors"]),
    ("checkpoint:latest_dir", ["checkpoints/latest is a folder, not a weights file"]),
    ("checkpoint:missing", ["missing.safetensors", "not found"]),
    ("poses:c2w_string", ["poses.json frame 0", "list of numbers", "'identity'"]),
    ("poses:c2w_strings", ["poses.json frame 1", "list of numbers"]),
    ("poses:frames_dict", ['poses.json: "frames" must be a list']),
    ("poses:depth_scale_string", ["poses.json: depth_scale must be a positive number"]),
    ("huge_header", ["pano_00.png", "800 megapixels", "downscale"]),
    ("huge_limit", ["pano_00.png", "megapixels", "downscale"]),
    ("out_under_file", ["--out", "afile is a file, not a folder"]),
    ("device", ["--device", "no usable CUDA", "--help"]),
    ("resolution", ["--resolution 40x80", "divisible by 16", "32x64"]),
    ("memory", ["2 panorama(s) at 64x128", "MiB (estimate)", "70 MiB are free on cpu", "--resolution (e.g. 32x64)"]),
    ("disk:ENOSPC", ["disk full while writing", "g.ply", "free space or choose another --out"]),
    ("disk:EDQUOT", ["disk quota exceeded while writing", "g.ply", "--out"]),
    ("disk:EROFS", ["read-only file system at", "g.ply", "--out"]),
    ("disk:EACCES", ["permission denied for", "g.ply", "--out"]),
    ("oom:torch", ["out of memory", "--resolution", "--device", "Tried to allocate"]),
    ("oom:python", ["out of memory", "--resolution", "--device"]),
])
def test_export_failures_are_one_line_and_keep_earlier_outputs(tmp_path, panorama_folder, tiny_checkpoint, monkeypatch,
                                                               capsys, case, fragments):
    if case == "device" and torch.cuda.is_available():
        pytest.skip("this machine has CUDA")
    folder = panorama_folder[0]
    argv = _export_case(tmp_path, folder, tiny_checkpoint, monkeypatch, case)
    if case == "checkpoint:missing":
        argv[4] = str(tmp_path / "missing.safetensors")
    earlier = tmp_path / "out" / "g.ply"
    earlier.parent.mkdir(parents=True, exist_ok=True)
    earlier.write_bytes(PREVIOUS)
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse: exit 2
        code = exc.code
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code not in (0, None), err
    assert len(lines) == 1 and "Traceback" not in err, err
    assert lines[0].startswith("cylindersplat export: error: "), err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    assert earlier.read_bytes() == PREVIOUS
    assert sorted(p.name for p in earlier.parent.iterdir()) == ["g.ply"]  # no temporary left behind


@pytest.mark.parametrize("argv,fragments", [
    (["--background", "nan", "0", "0"], ["--background", "[0, 1]", "nan"]),
    (["--background", "0", "inf", "0"], ["--background", "inf"]),
    (["--out", "FILE"], ["--out", "is a file, but this command writes a folder"]),
    (["--out", "FILE/sub"], ["--out", "is a file, not a folder"]),
])
def test_render_failures_are_one_line_and_keep_earlier_views(tmp_path, panorama_folder, tiny_checkpoint, capsys, argv,
                                                             fragments):
    out = tmp_path / "render"
    view = out / "views" / "view_000_rgb.png"
    view.parent.mkdir(parents=True)
    view.write_bytes(PREVIOUS)
    (tmp_path / "FILE").write_bytes(PREVIOUS)
    argv = [a.replace("FILE", str(tmp_path / "FILE")) for a in argv]
    base = ["render", "--input", str(panorama_folder[0]), "--checkpoint", str(tiny_checkpoint), "--out", str(out)]
    assert main(base + argv) == 1
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
    for fragment in fragments:
        assert fragment in err, (fragment, err)
    assert view.read_bytes() == PREVIOUS and (tmp_path / "FILE").read_bytes() == PREVIOUS


@pytest.mark.parametrize("argv,message", [
    (["render", "--camera", "pinhole", "--fov", "180"], "argument --fov: expected a field of view in degrees between "
                                                        "0 and 180 (e.g. 90), got '180'"),
    (["render", "--fov", "nan"], "argument --fov: expected a field of view in degrees between 0 and 180"),
    (["render", "--yaw", "nan"], "argument --yaw: expected a finite number, got 'nan'"),
    (["view", "--fov", "0"], "argument --fov: expected a field of view in degrees between 0 and 180 (e.g. 90), "
                             "got '0'"),
    (["view", "scene.ply", "--frustum-scale", "nan", "--html", "x.html"], "argument --frustum-scale: expected a "
                                                                          "positive number, got 'nan'"),
    (["view", "scene.ply", "--duration", "-5"], "argument --duration: expected a positive number, got '-5'"),
    (["ablate", "--lr", "nan"], "argument --lr: expected a positive number, got 'nan'"),
    (["demo", "--lr", "0"], "argument --lr: expected a positive number, got '0'"),
    (["data", "import-poses", "t.txt", "--from", "tum", "--out", "p.json", "--fps", "inf"],
     "argument --fps: expected a positive number, got 'inf'"),
    (["view", "scene.ply", "--port", "-1"], "argument --port: expected a port number from 1 to 65535 (0: any free "
                                            "port), got '-1'"),
    (["render", "--ply", "s.ply", "--fps", "0"], "argument --fps: expected an integer >= 1, got '0'"),
    (["render", "--ply", "s.ply", "--frames", "-1"], "argument --frames: expected 0 (no fly-through) or a number of "
                                                     "frames >= 2, got '-1'"),
    (["render", "--ply", "s.ply", "--frames", "1"], "argument --frames: expected 0 (no fly-through) or a number"),
    (["demo", "--frames", "-2"], "argument --frames: expected 0 (no fly-through) or a number of frames >= 2"),
    (["data", "preview", "--data", "d", "--out", "p.png", "--height", "-5"],
     "argument --height: expected an integer >= 1, got '-5'"),
])
def test_numbers_that_make_no_sense_are_refused_at_parse_time(tmp_path, monkeypatch, capsys, argv, message):
    """(Angles were refused after the reconstruction, a NaN yaw as 'c2w contains non-finite values'. A NaN frustum
    size wrote a page of NaN frustums; a negative --duration served for no time; a NaN learning
    rate trained to NaN; port -1 left the viewer hanging on a dead server; a one-frame fly-through was refused after
    the reconstruction, by `demo` after its whole run.)"""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and len(err.strip().splitlines()) == 1 and message in err, err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("case,fragments", [
    ("out_is_file", ["--out", "is a file, but this command writes a folder"]),
    ("out_under_file", ["--out", "is a file, not a folder"]),
    ("resume_garbage", ["state.pt: cannot read this training state", "--overwrite"]),
    ("resume_foreign", ["state.pt is not a training state written by cylindersplat", "stages"]),
    ("resume_missing", ["no training checkpoint at"]),
    ("init_pickle", ["init.safetensors is a PyTorch pickle"]),
])
def test_train_failures_are_one_line_and_keep_the_run(tmp_path, synth_dataset, tiny_checkpoint, capsys, case,
                                                      fragments):
    run = tmp_path / "run"
    state = run / "checkpoints" / "step_0000001" / "state.pt"
    state.parent.mkdir(parents=True)
    (state.parent / "model.safetensors").write_bytes(tiny_checkpoint.read_bytes())
    state.write_bytes(PREVIOUS)
    (run / "checkpoints" / "latest").write_text("step_0000001\n")
    (tmp_path / "afile").write_bytes(PREVIOUS)
    argv = ["train", "--data", str(synth_dataset(2, seed=3)), "--out", str(tmp_path / "new"), "--stages", "1",
            "--steps", "1",
            "train.tensorboard=false", "loss.use_lpips=off", "train.progress=false"]
    if case == "out_is_file":
        argv[4] = str(tmp_path / "afile")
    elif case == "out_under_file":
        argv[4] = str(tmp_path / "afile" / "run")
    elif case == "resume_garbage":
        argv += ["--resume", str(run)]
    elif case == "resume_foreign":
        torch.save({"weights": torch.zeros(2)}, state)
        argv += ["--resume", str(run)]
    elif case == "resume_missing":
        argv += ["--resume", str(tmp_path / "nowhere")]
    elif case == "init_pickle":
        torch.save({"weights": torch.zeros(2)}, tmp_path / "init.safetensors")
        argv += ["--init", str(tmp_path / "init.safetensors")]
    before = {p: p.read_bytes() for p in (state, tmp_path / "afile")}
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    for fragment in fragments:
        assert fragment in err[0], (fragment, err[0])
    assert {p: p.read_bytes() for p in before} == before
    assert not (tmp_path / "new" / "checkpoints").exists()


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0,
                    reason="root ignores permissions (the path-under-a-file cases cover this as root)")
def test_read_only_out_folder_is_refused_before_any_work(tmp_path, panorama_folder, tiny_checkpoint, capsys):
    out = tmp_path / "locked"
    out.mkdir()
    (out / "g.ply").write_bytes(PREVIOUS)
    out.chmod(0o500)
    try:
        code = main(["export", "--input", str(panorama_folder[0]), "--checkpoint", str(tiny_checkpoint),
                     "--out", str(out / "g.ply")])
    finally:
        out.chmod(0o700)
    err = capsys.readouterr().err
    assert code == 1 and len(err.strip().splitlines()) == 1 and "no permission to write in" in err and "--out" in err
    assert (out / "g.ply").read_bytes() == PREVIOUS


@pytest.mark.parametrize("argv,fragments", [
    (["data", "synth", "--scenes", "1", "--resolution", "16x32", "--out", "FILE"],
     ["FILE is a file where a folder is needed"]),
    (["data", "synth", "--scenes", "1", "--resolution", "16x32", "--out", "FILE/sub"],
     ["FILE is a file where a folder", "(for"]),
    (["eval", "--data", "DATA", "--checkpoint", "FILE", "--out", "OUT"], ["FILE is not a readable .safetensors file"]),
    (["eval", "--data", "DATA", "--out", "FILE"], ["FILE is a file where a folder is needed"]),
    (["train", "--config", "BAD_YAML", "--data", "DATA"], ["bad.yaml: malformed YAML"]),
])
def test_other_commands_fail_in_one_line(tmp_path, synth_dataset, capsys, argv, fragments):
    (tmp_path / "file").write_bytes(PREVIOUS)
    (tmp_path / "bad.yaml").write_text("train: {lr: [1, 2\n")
    names = {"FILE": str(tmp_path / "file"), "DATA": str(synth_dataset(2, seed=3)), "OUT": str(tmp_path / "out"),
             "BAD_YAML": str(tmp_path / "bad.yaml")}
    for key, value in names.items():
        argv = [a.replace(key, value) for a in argv]
        fragments = [f.replace(key, value) for f in fragments]
    assert main(argv) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "Traceback" not in err[0], err
    for fragment in fragments:
        assert fragment in err[0], (fragment, err[0])
    assert (tmp_path / "file").read_bytes() == PREVIOUS
