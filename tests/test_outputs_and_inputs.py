"""Outputs are atomic (a failed write keeps the previous file) and bad inputs are refused by name."""

import numpy as np
import pytest
import torch

from cylindersplat.data.io import write_depth_png, write_rgb
from cylindersplat.gaussians import Gaussians, load_ply, save_ply
from cylindersplat.geometry.poses import validate_c2w
from cylindersplat.inference.video import check_video_format, write_video
from cylindersplat.utils.atomic import atomic_path, atomic_write_text


def _gaussians(n=5):
    g = torch.Generator().manual_seed(0)
    return Gaussians.from_rgb(torch.randn(n, 3, generator=g), torch.rand(n, 3, generator=g) * 0.1 + 0.01,
                              torch.randn(n, 4, generator=g), torch.rand(n, generator=g), torch.rand(n, 3, generator=g))


def test_a_failed_write_keeps_the_previous_file(tmp_path):
    target = tmp_path / "table.md"
    atomic_write_text(target, "old")
    with pytest.raises(OSError):
        with atomic_path(target) as tmp:
            tmp.write_text("half of the new")
            raise OSError("No space left on device")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["table.md"]  # no temporary left behind


def test_save_ply_failure_leaves_the_earlier_ply_intact(tmp_path, monkeypatch):
    path = save_ply(_gaussians(5), tmp_path / "g.ply")
    before = path.read_bytes()
    import plyfile

    def broken_write(self, stream):
        with open(stream, "wb") as f:
            f.write(b"ply\nformat binary_little_endian 1.0\n")  # a truncated header, then the disk is full
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(plyfile.PlyData, "write", broken_write)
    with pytest.raises(OSError, match="No space"):
        save_ply(_gaussians(50), path)
    assert path.read_bytes() == before
    assert len(load_ply(path)) == 5
    assert [p.name for p in tmp_path.iterdir()] == ["g.ply"]


def test_images_and_videos_are_written_atomically(tmp_path, monkeypatch):
    write_rgb(tmp_path / "a.png", torch.rand(3, 4, 8))
    write_depth_png(tmp_path / "d.png", torch.rand(4, 8) * 5)
    from PIL import Image

    before = (tmp_path / "a.png").read_bytes()

    def broken_save(self, fp, *args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(Image.Image, "save", broken_save)
    with pytest.raises(OSError):
        write_rgb(tmp_path / "a.png", torch.rand(3, 4, 8))
    assert (tmp_path / "a.png").read_bytes() == before
    monkeypatch.undo()
    write_video(tmp_path / "v.gif", [np.zeros((4, 8, 3), np.uint8)] * 2)
    video = (tmp_path / "v.gif").read_bytes()

    def frames_then_full_disk():
        yield np.zeros((4, 8, 3), np.uint8)
        yield np.ones((4, 8, 3), np.uint8)
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError, match="No space"):  # fails half-way through streaming the new video
        write_video(tmp_path / "v.gif", frames_then_full_disk())
    assert (tmp_path / "v.gif").read_bytes() == video  # the earlier video, untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "d.png", "v.gif"]  # no temporary left
    with pytest.raises(ValueError, match="no frames"):
        write_video(tmp_path / "empty.gif", iter([]))
    assert not (tmp_path / "empty.gif").exists()


def test_video_format_is_checked_before_any_work(monkeypatch):
    from cylindersplat.inference import video

    check_video_format("x.gif")
    with pytest.raises(ValueError, match="gif, .mp4"):
        check_video_format("x.avi")
    monkeypatch.setattr(video, "ffmpeg_available", lambda: False)  # as on a machine without imageio-ffmpeg
    with pytest.raises(ValueError, match="imageio-ffmpeg"):
        check_video_format("x.mp4")
    path, note = video.video_path_with_fallback("out/fly.mp4")  # what `render` does: a GIF and one line
    assert path.name == "fly.gif" and "imageio-ffmpeg" in note and "\n" not in note
    assert video.video_path_with_fallback("out/fly.gif") == (path, None)


def test_video_frames_stream_to_the_file(tmp_path, monkeypatch):
    """Each frame is written before the next one is even produced: memory never holds the video."""
    from PIL import Image

    from cylindersplat.inference import video

    written = []
    append = video._GifStream.append
    monkeypatch.setattr(video._GifStream, "append", lambda self, frame: (written.append(1), append(self, frame)))

    def frames(n):
        for k in range(n):
            assert len(written) == k  # every earlier frame is already in the file
            yield np.full((6, 10, 3), 20 * k, np.uint8)

    path = write_video(tmp_path / "v.gif", frames(7), fps=10)
    gif = Image.open(path)
    assert gif.n_frames == 7 and gif.size == (10, 6) and gif.info["duration"] == 100 and gif.info["loop"] == 0
    for k in range(7):
        gif.seek(k)
        assert np.array_equal(np.asarray(gif.convert("RGB")), np.full((6, 10, 3), 20 * k, np.uint8))
    with pytest.raises(ValueError, match="same size"):
        write_video(tmp_path / "w.gif", [np.zeros((6, 10, 3), np.uint8), np.zeros((6, 12, 3), np.uint8)])
    assert not (tmp_path / "w.gif").exists()


def test_gif_frames_keep_the_pictures_colours(tmp_path):
    """Each frame gets a 256-colour palette of its own, chosen from a sample of a large frame's pixels: smooth
    gradients with noise come back within 1.5 dB of Pillow's own whole-frame palette (its GIF saver's median cut,
    PSNR against the frame itself), a few-colour frame exactly."""
    from PIL import Image

    y, x = np.mgrid[0:512, 0:1024] / np.array([511.0, 1023.0])[:, None, None]
    smooth = np.stack((x, y, 0.5 + 0.5 * np.sin(6 * x * y)), -1) * 255
    noisy = np.clip(smooth + np.random.default_rng(0).normal(0, 4, smooth.shape), 0, 255).astype(np.uint8)
    flat = np.zeros((512, 1024, 3), np.uint8)
    flat[:, 300:] = (200, 30, 90)
    flat[100:, 700:] = (10, 250, 40)

    def psnr(image, frame):
        return 10 * np.log10(255**2 / np.mean((np.asarray(image.convert("RGB"), dtype=float) - frame) ** 2))

    whole_frame = psnr(Image.fromarray(noisy).convert("P", palette=Image.Palette.ADAPTIVE, colors=256), noisy)
    gif = Image.open(write_video(tmp_path / "v.gif", [noisy, flat]))
    assert psnr(gif, noisy) > whole_frame - 1.5 and whole_frame > 30
    gif.seek(1)
    assert np.array_equal(np.asarray(gif.convert("RGB")), flat)


@pytest.mark.skipif(not __import__("cylindersplat.inference.video", fromlist=["x"]).ffmpeg_available(),
                    reason="needs imageio-ffmpeg (the video extra)")
def test_mp4_through_ffmpeg(tmp_path):
    import imageio_ffmpeg

    path = write_video(tmp_path / "v.mp4", (np.full((9, 13, 3), 30 * k, np.uint8) for k in range(5)), fps=10)
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    assert meta["size"] == (14, 10) and sum(1 for _ in reader) == 5  # odd sizes padded to even for H.264
    assert [p.name for p in tmp_path.iterdir()] == ["v.mp4"]


@pytest.mark.parametrize("field,column,value,message", [
    ("means", 0, float("nan"), "non-finite position"),
    ("opacities", None, float("inf"), "non-finite opacity"),
    ("sh", 0, float("nan"), "non-finite colour"),
])
def test_load_ply_names_non_finite_fields(tmp_path, field, column, value, message):
    from plyfile import PlyData

    path = save_ply(_gaussians(4), tmp_path / "g.ply")
    ply = PlyData.read(str(path))
    name = {"means": "x", "opacities": "opacity", "sh": "f_dc_0"}[field]
    ply["vertex"].data[name][2] = value
    ply.write(str(tmp_path / "bad.ply"))  # not over the (memory-mapped) original
    with pytest.raises(ValueError, match=message):
        load_ply(tmp_path / "bad.ply")


def test_load_ply_refuses_overflowing_scales(tmp_path):
    from plyfile import PlyData

    path = save_ply(_gaussians(3), tmp_path / "g.ply")
    ply = PlyData.read(str(path))
    ply["vertex"].data["scale_1"][0] = 800.0  # exp(800) overflows float64
    ply.write(str(tmp_path / "bad.ply"))
    with pytest.raises(ValueError, match="scale_"):
        load_ply(tmp_path / "bad.ply")


def test_reflection_is_not_a_pose():
    mirror = torch.diag(torch.tensor([-1.0, 1.0, 1.0, 1.0]))
    with pytest.raises(ValueError, match="reflection"):
        validate_c2w(mirror)
    validate_c2w(torch.eye(4))


def test_image_modes_are_read_or_refused_explicitly(tmp_path):
    from PIL import Image

    from cylindersplat.data.io import read_depth_png, read_rgb

    ramp = np.linspace(0, 1, 8 * 16).reshape(8, 16)
    Image.fromarray((ramp * 65535).astype(np.uint16)).save(tmp_path / "g16.png")  # 16-bit grayscale
    Image.fromarray(ramp.astype(np.float32), mode="F").save(tmp_path / "f.tiff")
    Image.fromarray((ramp * 255).astype(np.uint8)).convert("RGBA").save(tmp_path / "rgba.png")
    for name in ("g16.png", "f.tiff", "rgba.png"):
        rgb = read_rgb(tmp_path / name)
        assert rgb.shape == (3, 8, 16), name
        # not all white, not all black
        np.testing.assert_allclose(rgb[1].numpy(), ramp, atol=1 / 255 + 1e-6, err_msg=name)
    Image.fromarray((ramp * 3).astype(np.float32), mode="F").save(tmp_path / "hdr.tiff")
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        read_rgb(tmp_path / "hdr.tiff")
    Image.fromarray((ramp * 255).astype(np.uint8)).save(tmp_path / "depth8.png")
    with pytest.raises(ValueError, match="8-bit depth PNG"):
        read_depth_png(tmp_path / "depth8.png")


def test_contact_sheet_eval_pictures_and_input_poses_are_atomic(tmp_path, monkeypatch, panorama_folder, synth_dataset):
    """A failed write of a contact sheet, an evaluation picture or an input folder's poses.json keeps the earlier
    file."""
    from pathlib import Path

    from PIL import Image

    from cylindersplat.data import make_dataset
    from cylindersplat.data.preview import write_contact_sheet
    from cylindersplat.evaluation import evaluate, forward_warp_method
    from cylindersplat.inference import write_panorama_folder

    def half_written(self, fp, *args, **kwargs):  # writes part of the file, then the disk is full
        Path(fp if isinstance(fp, (str, Path)) else self).write_bytes(b"partial")
        raise OSError(28, "No space left on device")

    sheet = write_contact_sheet(synth_dataset(2, seed=0), tmp_path / "sheet" / "sheet.png", count=1, height=16)
    examples = tmp_path / "examples"
    dataset = make_dataset("folder", panorama_folder[0], targets=["pano_01.png"])
    evaluate(dataset, [forward_warp_method()], example_dir=examples, num_pictures=1, progress=False)
    (picture,) = examples.iterdir()
    folder, images, depths, poses = panorama_folder
    before = {path: path.read_bytes() for path in (sheet, picture, folder / "poses.json")}
    with monkeypatch.context() as patch:
        patch.setattr(Image.Image, "save", half_written)
        with pytest.raises(OSError, match="No space"):
            write_contact_sheet(synth_dataset(2, seed=0), sheet, count=1, height=16)
        with pytest.raises(OSError, match="No space"):
            evaluate(dataset, [forward_warp_method()], example_dir=examples, num_pictures=1, progress=False)
    with monkeypatch.context() as patch:
        patch.setattr(Path, "write_text", lambda self, text, *a, **k: half_written(None, self))
        with pytest.raises(OSError, match="No space"):
            write_panorama_folder(folder, images, poses.flip(0), depths)
    for path, data in before.items():
        assert path.read_bytes() == data, path
    for parent in (sheet.parent, examples, folder):  # no temporary left behind
        assert not [p.name for p in parent.iterdir() if ".tmp" in p.name]
