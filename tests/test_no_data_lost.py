"""Issue 37, item 1: no failed run removes or damages what was there.

Every command that writes takes its outputs as one set (``cylindersplat.utils.atomic.output_set``): written
beside the earlier ones, swapped in when whole. A file-size limit or a full disk part-way leaves the earlier
outputs as they were (same bytes, same files) and the one-line error says which files were not written.
"""

import errno
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from cylindersplat.cli import main
from cylindersplat.utils.atomic import atomic_write_text, output_set

SRC = str(Path(__file__).resolve().parents[1] / "src")


def _files(root: Path) -> dict[str, tuple[int, bytes]]:
    """Every file under ``root``: relative path -> (inode, bytes). A replaced file has a new inode."""
    return {str(p.relative_to(root)): (p.stat().st_ino, p.read_bytes()) for p in sorted(root.rglob("*")) if p.is_file()}


def _file_too_large(*args, **kwargs):
    raise OSError(errno.EFBIG, os.strerror(errno.EFBIG))


def _one_line(capsys) -> str:
    """The command's error line (progress lines may come before it)."""
    err = capsys.readouterr().err
    errors = [line for line in err.splitlines() if ": error: " in line]
    assert len(errors) == 1 and err.strip().endswith(errors[0]) and "Traceback" not in err, err
    return errors[0]


def test_an_output_set_is_swapped_in_whole_and_stale_files_go_only_after(tmp_path):
    atomic_write_text(tmp_path / "a.txt", "old a")
    atomic_write_text(tmp_path / "b.txt", "old b")
    before = _files(tmp_path)
    with pytest.raises(OSError) as failure:
        with output_set(tmp_path, planned=["c.txt"], stale=lambda: [tmp_path / "b.txt"]):
            atomic_write_text(tmp_path / "a.txt", "new a")
            assert (tmp_path / "a.txt").read_text() == "old a"  # held back until the set is whole
            raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "b.txt"))
    assert failure.value.output_note == f"nothing in {tmp_path} was changed (not written: a.txt, b.txt, c.txt)"
    assert _files(tmp_path) == before  # no temporary left, nothing replaced, nothing removed

    with output_set(tmp_path, stale=lambda: [tmp_path / "a.txt", tmp_path / "b.txt"]) as outputs:
        atomic_write_text(tmp_path / "a.txt", "new a")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"] and (tmp_path / "a.txt").read_text() == "new a"
    assert outputs.removed == [tmp_path / "b.txt"]


def _render(folder, checkpoint, out, *more):
    return ["render", "--input", str(folder), "--checkpoint", str(checkpoint), "--resolution", "16x32", "--out",
            str(out), "--device", "cpu", "--min-opacity", "0", "--frames", "2", *more]


def test_a_render_that_hits_a_file_size_limit_keeps_the_earlier_render(panorama_folder, tiny_checkpoint, tmp_path,
                                                                       monkeypatch, capsys):
    from cylindersplat.inference import video

    out = tmp_path / "render"
    assert main(_render(panorama_folder[0], tiny_checkpoint, out)) == 0
    before = _files(out)
    assert {"gaussians.ply", "flythrough.gif", "flythrough_poses.json", "views/poses.json"} <= set(before)
    capsys.readouterr()
    monkeypatch.setattr(video._GifStream, "append", _file_too_large)  # the last big file: all others are written
    assert main(_render(panorama_folder[0], tiny_checkpoint, out, "--yaw", "30")) == 1
    assert _one_line(capsys) == (
        f"cylindersplat render: error: file too large while writing {out}/flythrough.gif (a file-size limit: "
        f"ulimit -f, FAT32's 4 GiB): choose another --out; nothing in {out} was changed (not written: "
        "views/view_000_rgb.png, views/view_000_depth.png, views/poses.json, gaussians.ply, flythrough.gif, "
        "flythrough_poses.json)")
    assert _files(out) == before  # the same files, same bytes, none replaced, no temporary left


def test_new_folders_removes_only_the_empty_folders_it_made(tmp_path):
    from cylindersplat.utils.atomic import new_folders

    (tmp_path / "had").mkdir()
    with pytest.raises(RuntimeError), new_folders(tmp_path / "had", tmp_path / "a" / "b" / "c", tmp_path / "a" / "d"):
        (tmp_path / "a" / "d" / "kept.txt").write_text("written by the block")
        raise RuntimeError("part-way")
    assert sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*")) == ["a", "a/d", "a/d/kept.txt", "had"]
    with new_folders(tmp_path / "x" / "y"):  # success: they stay
        pass
    assert (tmp_path / "x" / "y").is_dir()


def test_a_render_into_a_new_folder_that_fails_leaves_no_folder(panorama_folder, tiny_checkpoint, tmp_path,
                                                                 monkeypatch, capsys):
    """(It left OUT and an empty OUT/views behind while saying that nothing in OUT was changed.)"""
    from cylindersplat.inference import video

    out = tmp_path / "new" / "render"
    monkeypatch.setattr(video._GifStream, "append", _file_too_large)
    assert main(_render(panorama_folder[0], tiny_checkpoint, out)) == 1
    assert f"nothing in {out} was changed" in _one_line(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene", "tiny.safetensors"]  # no "new" left


@pytest.mark.slow
def test_a_render_under_ulimit_f_keeps_the_earlier_render(panorama_folder, tiny_checkpoint, tmp_path):
    """The real limit (``ulimit -f``): the kernel refuses the write with EFBIG (Python ignores SIGXFSZ)."""
    out = tmp_path / "render"
    assert main(_render(panorama_folder[0], tiny_checkpoint, out)) == 0
    before = _files(out)
    limit = 100_000  # above every view and the fly-through, below the PLY (2 x 16 x 32 Gaussians, 248 bytes each)
    assert max(len(data) for name, (_, data) in before.items() if name != "gaussians.ply") < limit
    assert len(before["gaussians.ply"][1]) > limit

    def limited():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = {**os.environ, "PYTHONPATH": SRC, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-m", "cylindersplat", *_render(panorama_folder[0], tiny_checkpoint, out,
                                                                           "--yaw", "30")],
                          capture_output=True, text=True, env=env, preexec_fn=limited, timeout=600)
    assert proc.returncode == 1, proc.stderr
    assert proc.stderr.strip().splitlines()[-1] == (
        f"cylindersplat render: error: file too large while writing {out}/gaussians.ply (a file-size limit: "
        f"ulimit -f, FAT32's 4 GiB): choose another --out; nothing in {out} was changed (not written: "
        "views/view_000_rgb.png, views/view_000_depth.png, views/poses.json, gaussians.ply, flythrough.gif, "
        "flythrough_poses.json)")
    assert _files(out) == before


def test_earlier_render_files_are_removed_only_once_the_new_set_is_in_place(panorama_folder, tiny_checkpoint,
                                                                            tmp_path, capsys):
    out = tmp_path / "render"
    assert main(_render(panorama_folder[0], tiny_checkpoint, out)) == 0
    capsys.readouterr()
    assert main(_render(panorama_folder[0], tiny_checkpoint, out, "--frames", "0", "--no-ply")) == 0
    assert capsys.readouterr().out.splitlines()[-1] == f"removed 3 files of an earlier render in {out}"
    assert sorted(_files(out)) == ["views/poses.json", "views/view_000_depth.png", "views/view_000_rgb.png"]


def test_a_render_refuses_an_out_where_it_would_replace_or_remove_what_it_reads(panorama_folder, tiny_checkpoint,
                                                                               tmp_path, capsys):
    """A render's views are posed panoramas: reconstructing from them (--input OUT/views) into the same OUT replaced
    the panoramas and poses file it read and removed the views it did not write again. Refused before any work;
    --input IN --out IN stays allowed (a render's files there are its own)."""
    import shutil

    out = tmp_path / "render"
    assert main(_render(panorama_folder[0], tiny_checkpoint, out)) == 0
    capsys.readouterr()
    before = _files(out)
    views = out / "views"
    assert main(_render(views, tiny_checkpoint, out, "--depth-prior", "constant:2")) == 1
    assert _one_line(capsys).endswith(f"error: --out {out} would replace or remove {views}/poses.json (and 1 more), "
                                      "which this render reads (--input): choose another --out")
    assert main(_render(panorama_folder[0], tiny_checkpoint, out, "--views", str(views / "poses.json"))) == 1
    assert "which this render reads (--views): choose another --out" in _one_line(capsys)
    assert _files(out) == before  # same files, same bytes, not replaced
    scene = tmp_path / "own"
    shutil.copytree(panorama_folder[0], scene)
    inputs = _files(scene)
    for _ in range(2):  # into the input folder itself, twice: the second run replaces only the first one's files
        assert main(_render(scene, tiny_checkpoint, scene)) == 0
    assert {k: v for k, v in _files(scene).items() if k in inputs} == inputs


def test_an_export_that_hits_a_file_size_limit_keeps_the_earlier_file(panorama_folder, tiny_checkpoint, tmp_path,
                                                                      monkeypatch, capsys):
    import plyfile

    out = tmp_path / "out" / "g.ply"
    argv = ["export", "--input", str(panorama_folder[0]), "--checkpoint", str(tiny_checkpoint), "--out", str(out),
            "--resolution", "16x32", "--device", "cpu"]
    assert main(argv) == 0
    before = _files(out.parent)
    capsys.readouterr()
    monkeypatch.setattr(plyfile.PlyData, "write", _file_too_large)
    assert main(argv + ["--min-opacity", "0"]) == 1
    assert _one_line(capsys) == (
        f"cylindersplat export: error: file too large while writing {out} (a file-size limit: ulimit -f, FAT32's "
        f"4 GiB): choose another --out; nothing in {out.parent} was changed (not written: g.ply)")
    assert _files(out.parent) == before
    fresh = tmp_path / "new" / "g.ply"  # into a folder of its own: none is left
    assert main([str(fresh) if a == str(out) else a for a in argv] + ["--min-opacity", "0"]) == 1
    assert f"nothing in {fresh.parent} was changed" in _one_line(capsys) and not (tmp_path / "new").exists()


QUIET = ["train.tensorboard=false", "loss.use_lpips=off", "train.image_every=0", "train.progress=false"]


def test_a_checkpoint_that_does_not_fit_keeps_the_last_one_and_resumes(synth_dataset, tmp_path, monkeypatch, capsys):
    from cylindersplat.training import checkpoint

    run = tmp_path / "run"
    write = checkpoint.atomic_write_bytes
    calls = []

    def fails_the_second_time(path, data):
        calls.append(path)
        if len(calls) == 2:
            with open(path.parent / f".{path.stem}.half0000.tmp{path.suffix}", "wb"):
                pass  # what a real write leaves until its clean-up: removed with the half checkpoint
            raise OSError(errno.EFBIG, os.strerror(errno.EFBIG), str(path))
        return write(path, data)

    monkeypatch.setattr(checkpoint, "atomic_write_bytes", fails_the_second_time)
    argv = ["train", "--data", str(synth_dataset(2, seed=5)), "--out", str(run), "--stages", "1", "--steps", "4",
            "train.checkpoint_every=1", "data.resolution=[32,64]", *QUIET]
    assert main(argv) == 1
    assert _one_line(capsys) == (f"cylindersplat train: error: file too large while writing "
                                 f"{run}/checkpoints/step_0000002/state.pt (a file-size limit: ulimit -f, FAT32's "
                                 "4 GiB): choose another --out")
    assert (run / "checkpoints" / "latest").read_text() == "step_0000001\n"
    assert sorted(p.name for p in (run / "checkpoints").iterdir()) == ["latest", "step_0000001"]  # no half step_2
    monkeypatch.setattr(checkpoint, "atomic_write_bytes", write)
    assert main(["train", "--resume", str(run)]) == 0
    assert "resuming" in capsys.readouterr().out and (run / "model.safetensors").is_file()


def _tree(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_data_synth_that_does_not_fit_is_finished_by_running_it_again(tmp_path, monkeypatch, capsys):
    from cylindersplat.data.synth import writer

    argv = ["data", "synth", "--scenes", "2", "--resolution", "16x32", "--out"]
    assert main(argv + [str(tmp_path / "clean")]) == 0
    write_depth = writer.write_depth_png
    written = []

    def fails_in_the_second_scene(path, depth, *args, **kwargs):
        written.append(path)
        if len(written) == 4:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
        write_depth(path, depth, *args, **kwargs)

    monkeypatch.setattr(writer, "write_depth_png", fails_in_the_second_scene)
    out = tmp_path / "again"
    assert main(argv + [str(out)]) == 1
    assert _one_line(capsys) == (f"cylindersplat data: error: disk full while writing {out}/00000001/00/depth.png: "
                                 "free space or choose another --out")
    # a kill -9 part-way leaves temporaries as well: the next run removes them
    (out / "00000001" / "00" / ".depth.k9k9k9k9.tmp.png").write_bytes(b"half")
    monkeypatch.setattr(writer, "write_depth_png", write_depth)
    assert main(argv + [str(out)]) == 0
    assert _tree(out) == _tree(tmp_path / "clean")


@pytest.mark.slow
def test_data_synth_killed_and_run_again_gives_the_clean_bytes(tmp_path):
    """``kill -9`` at a random moment (here: once the first scene is done), then the same command again."""
    import signal
    import time

    env = {**os.environ, "PYTHONPATH": SRC, "OMP_NUM_THREADS": "1"}
    argv = [sys.executable, "-m", "cylindersplat", "data", "synth", "--scenes", "4", "--resolution", "32x64", "--out"]
    subprocess.run(argv + [str(tmp_path / "clean")], check=True, env=env, capture_output=True, timeout=600)
    out = tmp_path / "killed"
    proc = subprocess.Popen(argv + [str(out)], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while not (out / "00000000" / "meta.json").is_file() and time.monotonic() < deadline:
        time.sleep(0.001)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    subprocess.run(argv + [str(out)], check=True, env=env, capture_output=True, timeout=600)
    assert _tree(out) == _tree(tmp_path / "clean")
    assert not [p for p in out.rglob("*.tmp*")]


def test_eval_tables_are_written_both_or_neither(tmp_path, monkeypatch):
    from cylindersplat.commands import eval as eval_command

    (tmp_path / "results.md").write_text("earlier")
    calls = []

    def second_fails(path, text):
        calls.append(path)
        if len(calls) == 2:
            raise OSError(errno.EFBIG, os.strerror(errno.EFBIG), str(path))
        return atomic_write_text(path, text)

    monkeypatch.setattr(eval_command, "atomic_write_text", second_fails)
    with pytest.raises(OSError) as failure:
        eval_command.write_tables(tmp_path, "new table", {"means": {}})
    assert failure.value.output_note == f"nothing in {tmp_path} was changed (not written: results.md, results.json)"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results.md"]
    assert (tmp_path / "results.md").read_text() == "earlier"


@pytest.mark.slow
def test_a_demo_that_hits_a_file_size_limit_keeps_the_earlier_results(tmp_path, monkeypatch, capsys):
    from cylindersplat.inference import video

    out = tmp_path / "demo"
    argv = ["demo", "--out", str(out), "--scenes", "2", "--held-out", "1", "--resolution", "16x32", "--frames", "2",
            "--device", "cpu"]
    assert main(argv) == 0
    results = ["results.md", "results.json", "comparison.png", "novel_view_rgb.png", "novel_view_depth.png",
               "gaussians.ply", "flythrough.gif"]
    before = {name: _files(out)[name] for name in results}
    examples = {name: data for name, data in _files(out).items() if name.startswith("examples/")}
    capsys.readouterr()
    monkeypatch.setattr(video._GifStream, "append", _file_too_large)
    assert main(argv) == 1
    assert _one_line(capsys) == (
        f"cylindersplat demo: error: file too large while writing {out}/flythrough.gif (a file-size limit: ulimit -f, "
        f"FAT32's 4 GiB): choose another --out; nothing in {out} was changed (not written: "
        "examples/example_0000_view0.png, results.md, results.json, novel_view_rgb.png, novel_view_depth.png, "
        "comparison.png and 2 more)")
    after = _files(out)
    assert {name: after[name] for name in results} == before
    assert {name: data for name, data in after.items() if name.startswith("examples/")} == examples
    assert not [name for name in after if ".tmp" in name]
