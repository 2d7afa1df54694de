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
    with pytest.raises(OSError):
        write_video(tmp_path / "v.gif", [np.zeros((4, 8, 3), np.uint8)] * 2)
    assert (tmp_path / "a.png").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "d.png"]


def test_video_format_is_checked_before_any_work():
    check_video_format("x.gif")
    with pytest.raises(ValueError, match="gif, .mp4"):
        check_video_format("x.avi")
    try:
        import imageio_ffmpeg  # noqa: F401
    except ImportError:
        with pytest.raises(ValueError, match="imageio\\[ffmpeg\\]"):
            check_video_format("x.mp4")


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
        np.testing.assert_allclose(rgb[1].numpy(), ramp, atol=1 / 255 + 1e-6, err_msg=name)  # not all white, not all black
    Image.fromarray((ramp * 3).astype(np.float32), mode="F").save(tmp_path / "hdr.tiff")
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        read_rgb(tmp_path / "hdr.tiff")
    Image.fromarray((ramp * 255).astype(np.uint8)).save(tmp_path / "depth8.png")
    with pytest.raises(ValueError, match="8-bit depth PNG"):
        read_depth_png(tmp_path / "depth8.png")
