"""Issue 27, item 1 (library API) and item 3 (plausibility): reconstruct_gaussians and render refuse bad
inputs with one-line InputErrors instead of returning Gaussians or raising raw errors."""

import numpy as np
import pytest
import torch

from cylindersplat.errors import ImplausibleInputError, InputError
from cylindersplat.gaussians import Gaussians
from cylindersplat.inference import reconstruct_gaussians
from cylindersplat.render import render_equirect
from cylindersplat.render.projection import RasterSettings
from model_inputs import make_inputs


def _inputs(height=16):
    images, depths, c2w = make_inputs(views=2, height=height, width=2 * height)
    return images[0], depths[0], c2w[0]


def _broken(change):
    images, depths, c2w = _inputs()
    change(images, depths, c2w)
    return images, depths, c2w


def _nan_pixel(t):
    t.view(-1)[7] = float("nan")


def _reflect(c2w):
    c2w[1, :3, 0] *= -1


@pytest.mark.parametrize("change,message", [
    (lambda i, d, c: i.mul_(255), "images must be RGB in [0, 1], got values in [0.0203213, 254.959]; "
                                  "divide 8-bit images by 255"),
    (lambda i, d, c: _nan_pixel(i), "images hold NaN or Inf values (view 0); give finite RGB in [0, 1]"),
    (lambda i, d, c: i.sub_(0.5), "images must be RGB in [0, 1], got values in [-0.49"),
    (lambda i, d, c: _nan_pixel(d), "depths hold NaN or Inf values (view 0); use 0 for unknown depth"),
    (lambda i, d, c: d[1].mul_(-1), "depths hold negative values (view 1, min -3"),
    (lambda i, d, c: _nan_pixel(c), "c2w contains non-finite values (NaN or Inf); give OpenCV camera-to-world "
                                    "matrices [R | t] with R a rotation (det +1)"),
    (lambda i, d, c: _reflect(c), "c2w rotation part is a reflection (determinant -1), not a rotation; check the "
                                  "handedness of the pose convention; give OpenCV camera-to-world matrices"),
])
def test_reconstruct_refuses_bad_tensors(tiny_model, change, message):
    with pytest.raises(InputError) as info:
        reconstruct_gaussians(tiny_model, *_broken(change))
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


def test_reconstruct_refuses_a_height_the_model_cannot_tile(tiny_model):
    with pytest.raises(InputError) as info:
        reconstruct_gaussians(tiny_model, *_inputs(height=24))
    assert str(info.value) == ("images are 24x48, but this model needs a height divisible by 16; resize them, e.g. "
                               "to 16x32")


def test_reconstruct_refuses_depth_of_another_size(tiny_model):
    images, depths, c2w = _inputs()
    with pytest.raises(InputError) as info:
        reconstruct_gaussians(tiny_model, images, depths[:, ::2, ::2], c2w)
    assert str(info.value) == ("depths must have shape (V, H, W) = (2, 16, 32) to match the images, got (2, 8, 16); "
                               "resize the depth maps to the images' size")


@pytest.mark.parametrize("scale,message", [
    (1000.0, "depths[0]: median depth 2.41e+03 m is above 1000 m (millimetres read as metres? check depth_scale or "
             "the .npy units); depth is radial metres (--skip-plausibility-checks, or check_plausibility=False in "
             "Python, to use it anyway)"),
    (1e-30, "depths[0]: median depth 2.41e-30 m is below 0.01 m (check depth_scale or the .npy units); depth is radial "
            "metres (--skip-plausibility-checks, or check_plausibility=False in Python, to use it anyway)"),
])
def test_reconstruct_refuses_implausible_depth_unless_told(tiny_model, scale, message):
    images, depths, c2w = _inputs()
    with pytest.raises(ImplausibleInputError) as info:
        reconstruct_gaussians(tiny_model, images, depths * scale, c2w)
    assert str(info.value) == message
    assert len(reconstruct_gaussians(tiny_model, images, depths * scale, c2w, check_plausibility=False)) > 0


def test_reconstruct_refuses_far_cameras(tiny_model):
    images, depths, c2w = _inputs()
    c2w[1, 0, 3] = 1e30
    with pytest.raises(ImplausibleInputError) as info:
        reconstruct_gaussians(tiny_model, images, depths, c2w)
    assert str(info.value) == ("c2w: a camera lies 1e+30 m from the origin, beyond 10000 m; recentre the poses "
                               "(subtract a common origin) and give them in metres")


@pytest.mark.parametrize("value,message", [
    (1.0, "min_opacity must be a number in [0, 1) (Gaussians at or below it are dropped), got 1.0"),
    (float("nan"), "min_opacity must be a number in [0, 1) (Gaussians at or below it are dropped), got nan"),
])
def test_reconstruct_refuses_a_min_opacity_outside_0_1(tiny_model, value, message):
    with pytest.raises(InputError) as info:
        reconstruct_gaussians(tiny_model, *_inputs(), min_opacity=value)
    assert str(info.value) == message


def test_a_min_opacity_that_empties_the_scene_is_an_error(tiny_model):
    with pytest.raises(InputError, match=r"^min_opacity \(--min-opacity\) 0.9999 leaves 0 of [\d,]+ Gaussians \(the "
                                         r"most opaque has [\d.e-]+\); choose a lower value$"):
        reconstruct_gaussians(tiny_model, *_inputs(), min_opacity=0.9999)


def _one_gaussian():
    return Gaussians.from_rgb(torch.tensor([[0.0, 0.0, 2.0]]), torch.full((1, 3), 0.1), torch.tensor([[1.0, 0, 0, 0]]),
                              torch.tensor([0.9]), torch.tensor([[1.0, 0.5, 0.2]]))


@pytest.mark.parametrize("kwargs,message", [
    ({"near": -1}, "RasterSettings.near must be > 0 metres (e.g. 0.01), got -1"),
    ({"near": float("nan")}, "RasterSettings.near must be > 0 metres (e.g. 0.01), got nan"),
    ({"tile_size": 0}, "RasterSettings.tile_size must be an integer >= 1 (e.g. 16), got 0"),
])
def test_raster_settings_are_checked(kwargs, message):
    with pytest.raises(InputError) as info:
        RasterSettings(**kwargs)
    assert str(info.value) == message


def test_backends_are_checked(monkeypatch):
    gaussians = _one_gaussian()
    with pytest.raises(InputError) as info:
        render_equirect(gaussians, torch.eye(4), 8, 16, backend="cuda")
    assert str(info.value).startswith("unknown render backend 'cuda'; available: torch")
    monkeypatch.delenv("TRITON_INTERPRET", raising=False)
    with pytest.raises(InputError) as info:
        render_equirect(gaussians, torch.eye(4), 8, 16, backend="triton")
    assert str(info.value) == ("backend='triton' needs a CUDA GPU, but the Gaussians are on cpu; use backend='torch' "
                               "(or 'auto'), or move the Gaussians to CUDA")


def test_valid_inputs_still_reconstruct_and_render(tiny_model):
    gaussians = reconstruct_gaussians(tiny_model, *_inputs(), min_opacity=0.005)
    out = render_equirect(gaussians, torch.eye(4), 8, 16, backend="torch")
    assert out.rgb.shape == (3, 8, 16) and torch.isfinite(out.rgb).all()


# --- the same bounds through the CLI: one line naming the file or option ---------------------------------


def _export(folder, checkpoint, out, *extra):
    from cylindersplat.cli import main

    return main(["export", "--input", str(folder), "--checkpoint", str(checkpoint), "--resolution", "16x32",
                 "--out", str(out), "--device", "cpu", *extra])


def test_millimetre_npy_depth_is_refused_naming_the_file(panorama_folder, tiny_checkpoint, tmp_path, capsys):
    import numpy as np

    folder, _, depths, _ = panorama_folder
    (folder / "pano_00_depth.png").unlink()
    np.save(folder / "pano_00_depth.npy", (depths[0] * 1000).numpy())  # millimetres where metres belong
    poses = folder / "poses.json"
    poses.write_text(poses.read_text().replace("pano_00_depth.png", "pano_00_depth.npy"))
    assert _export(folder, tiny_checkpoint, tmp_path / "g.ply") == 1
    median = float(depths[0].flatten().median() * 1000)
    assert capsys.readouterr().err.strip().splitlines() == [
        f"cylindersplat export: error: {folder / 'pano_00_depth.npy'}: median depth {median:.3g} m is above 1000 m "
        "(millimetres read as metres? check depth_scale or the .npy units); depth is radial metres "
        "(--skip-plausibility-checks, or check_plausibility=False in Python, to use it anyway)"]
    assert _export(folder, tiny_checkpoint, tmp_path / "g.ply", "--skip-plausibility-checks") == 0


@pytest.mark.parametrize("extra,message", [
    (["--min-opacity", "1"], "cylindersplat export: error: argument --min-opacity: expected a number in [0, 1) "
                             "(Gaussians at or below it are dropped), got '1' (see cylindersplat export --help)"),
    (["--min-opacity", "nan"], "cylindersplat export: error: argument --min-opacity: expected a number in [0, 1) "
                               "(Gaussians at or below it are dropped), got 'nan' (see cylindersplat export --help)"),
    (["--depth-prior", "constant:1e30"], "cylindersplat export: error: constant:1e+30: 1e+30 m is outside the "
                                         "plausible 0.01 to 1000 m; give the scene's typical distance in metres, e.g. "
                                         "constant:2.5"),
])
def test_absurd_options_are_one_line(panorama_folder, tiny_checkpoint, tmp_path, capsys, extra, message):
    try:
        code = _export(panorama_folder[0], tiny_checkpoint, tmp_path / "g.ply", *extra)
    except SystemExit as exit:  # argparse refuses before the command runs
        code = exit.code
    assert code in (1, 2)
    assert capsys.readouterr().err.strip().splitlines()[-1] == message
    assert not (tmp_path / "g.ply").exists()


def test_a_pose_10_km_away_is_refused_naming_the_frame(panorama_folder, tiny_checkpoint, tmp_path, capsys):
    import json

    folder = panorama_folder[0]
    poses = json.loads((folder / "poses.json").read_text())
    poses["frames"][1]["c2w"][0][3] = 1e30
    (folder / "poses.json").write_text(json.dumps(poses))
    assert _export(folder, tiny_checkpoint, tmp_path / "g.ply") == 1
    assert capsys.readouterr().err.strip().splitlines() == [
        f"cylindersplat export: error: {folder / 'poses.json'} frame 1: a camera lies 1e+30 m from the origin, beyond "
        "10000 m; recentre the poses (subtract a common origin) and give them in metres"]


@pytest.mark.parametrize("size", [(8, 16), (32, 64)])
def test_a_depth_file_of_another_size_than_its_panorama_is_refused(panorama_folder, size):
    from cylindersplat.data.io import write_depth_png
    from cylindersplat.inference import load_panorama_folder

    folder = panorama_folder[0]
    write_depth_png(folder / "pano_01_depth.png", torch.full(size, 2.0))
    with pytest.raises(ValueError) as info:
        load_panorama_folder(folder, (16, 32))
    assert str(info.value) == f"{folder / 'pano_01_depth.png'}: expected 32x16 (WxH), got {size[1]}x{size[0]}"


@pytest.mark.parametrize("array,message", [
    (np.ones((16, 32), bool), "depth must be a float array of metres, got dtype bool"),
    (np.zeros((16, 32), [("a", "f4"), ("b", "f4")]), "depth must be a float array of metres, got dtype [('a', '<f4'), "
                                                     "('b', '<f4')]"),
])
def test_npy_depth_of_the_wrong_kind_is_refused(panorama_folder, array, message):
    from cylindersplat.inference import load_panorama_folder

    folder = panorama_folder[0]
    np.save(folder / "pano_01_depth.npy", array)
    (folder / "poses.json").write_text((folder / "poses.json").read_text().replace("pano_01_depth.png",
                                                                                   "pano_01_depth.npy"))
    with pytest.raises(ValueError) as info:
        load_panorama_folder(folder, (16, 32))
    assert str(info.value) == f"{folder / 'pano_01_depth.npy'}: {message}"


def test_rendering_far_from_the_origin_warns():
    far = torch.eye(4)
    far[0, 3] = 1e7
    with pytest.warns(RuntimeWarning, match=r"cameras up to 1e\+07 m from the origin \(beyond 10000 m\): float32 loses "
                                            r"centimetres there and the render is wrong; recentre the scene"):
        render_equirect(_one_gaussian(), far, 8, 16, backend="torch")


def test_panorama_sized_gaussians_are_refused_for_memory_before_allocating(monkeypatch):
    """Gaussians covering the whole panorama: their row spans alone exceed free memory (here 1 MiB)."""
    from cylindersplat.render import rasterize

    monkeypatch.setattr(rasterize, "available_memory", lambda device: 2**20)
    n = 50
    means = torch.nn.functional.normalize(torch.randn(n, 3, generator=torch.Generator().manual_seed(0)), dim=1) * 2
    big = Gaussians.from_rgb(means, torch.full((n, 3), 5.0), torch.tensor([[1.0, 0, 0, 0]]).expand(n, 4),
                             torch.full((n,), 0.9), torch.rand(n, 3))
    with pytest.raises(rasterize.RenderMemoryError, match=r"^this render of 1 view\(s\) at once needs about [\d.]+ GiB "
                                                          r"for [\d,]+ row spans but 0.0 GiB are free on cpu; "
                                                          r"render at a lower resolution"):
        render_equirect(big, torch.eye(4), 32, 64, backend="torch")
