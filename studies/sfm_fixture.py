"""`cylindersplat data poses` end to end on the real Matterport3D triplet of the shared fixtures (issue 28).

From the three panoramas alone (no poses), with and without depth:

1. `data poses` with the fixture's depth files (`--scale auto`): registered images, points, reprojection error;
   rotation and centre errors after a similarity alignment to the dataset's poses
   (cylindersplat.data.poses.alignment); the automatic scale against the true one (the scale of that
   alignment from the SfM-unit poses).
2. The same with a depth prior instead: the fixture's depth blurred (Gaussian, sigma 8 px at 1024 wide, holes
   kept) stored as `priors/blur/<stem>.png` and passed as `--depth-prior file:blur`.
3. Render: the shipped tiny-synth weights reconstruct Gaussians from panoramas 00 and 02 and render the middle
   one, once with the dataset's poses and once with the recovered ones; WS-PSNR of each against the real
   panorama 01, and their difference.

    python studies/sfm_fixture.py                     # -> studies/results/sfm_fixture.json
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import platform
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
FIXTURE = ROOT.parent / "shared/fixtures/pano_grf/png_render_test_1024x512_seq_len_3_m3d_dist_0.5/00000007"
FRAMES = ("00", "01", "02")


def true_poses(fixture: Path) -> np.ndarray:
    from cylindersplat.data.pano_grf import panogrf_c2w

    return np.stack([panogrf_c2w(np.loadtxt(fixture / f / "rot.txt"),
                                 np.loadtxt(fixture / f / "tran.txt")).double().numpy()
                     for f in FRAMES])


def make_folder(fixture: Path, folder: Path, depth: str) -> None:
    """Panoramas ``pano_NN.png``; ``depth``: ``files`` (``pano_NN_depth.png``), ``blur`` (``priors/blur/``) or
    ``none``."""
    from PIL import Image
    from scipy.ndimage import gaussian_filter

    folder.mkdir(parents=True)
    for f in FRAMES:
        shutil.copy(fixture / f / "rgb.png", folder / f"pano_{f}.png")
        if depth == "files":
            shutil.copy(fixture / f / "depth.png", folder / f"pano_{f}_depth.png")
        elif depth == "blur":
            mm = np.asarray(Image.open(fixture / f / "depth.png")).astype(np.float64)
            valid = (mm > 0).astype(np.float64)
            # Normalised blur (holes do not pull the depth down), wrapping around in longitude.
            blurred = gaussian_filter(mm, 8, mode=("nearest", "wrap")) / np.maximum(
                gaussian_filter(valid, 8, mode=("nearest", "wrap")), 1e-6)
            out = folder / "priors" / "blur" / f"pano_{f}.png"
            out.parent.mkdir(parents=True, exist_ok=True)
            Image.fromarray(np.where(valid > 0, blurred, 0).round().astype(np.uint16)).save(out)


def run_poses(folder: Path, *extra: str) -> tuple[dict, float]:
    from cylindersplat.cli import main

    start = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()) as out:
        code = main(["data", "poses", str(folder), *extra])
    if code != 0:
        raise SystemExit(f"data poses failed on {folder}")
    print(out.getvalue(), end="")
    return json.loads((folder / "poses.json").read_text()), time.perf_counter() - start


def poses_of(data: dict) -> np.ndarray:
    return np.array([frame["c2w"] for frame in sorted(data["frames"], key=lambda f: f["image"])], dtype=np.float64)


def render_middle(folder: Path, poses: np.ndarray, size: tuple[int, int]) -> tuple[float, torch.Tensor]:
    """WS-PSNR of panorama 01 rendered from 00 and 02 at ``poses`` (3 c2w, the frame of ``poses``), and the render."""
    from cylindersplat.data.io import read_rgb
    from cylindersplat.data.poses import PoseRecord, write_poses_json
    from cylindersplat.inference import load_panorama_folder, reconstruct_gaussians, render_views
    from cylindersplat.inference.pipeline import raster_settings
    from cylindersplat.metrics.image import ws_psnr
    from cylindersplat.model.pretrained import from_pretrained

    inputs_folder = folder / "inputs"
    inputs_folder.mkdir(parents=True)
    for f in ("00", "02"):
        for suffix in ("", "_depth"):
            shutil.copy(folder.parent / "files" / f"pano_{f}{suffix}.png", inputs_folder / f"pano_{f}{suffix}.png")
    write_poses_json(inputs_folder / "poses.json", [PoseRecord(f"pano_{f}.png", torch.from_numpy(poses[i]))
                                                    for i, f in ((0, "00"), (2, "02"))])
    torch.manual_seed(0)
    model = from_pretrained("tiny-synth").eval()
    inputs = load_panorama_folder(inputs_folder, size)
    with torch.no_grad():
        gaussians, front = reconstruct_gaussians(model, inputs.images, inputs.depths, inputs.c2w, layers=True)
        out = render_views(gaussians, torch.from_numpy(poses[1]).float()[None], *size,
                           settings=raster_settings(model.config), front=front)  # as `render` draws them
    target = read_rgb(folder.parent / "files" / "pano_01.png", size=size)
    return float(ws_psnr(out.rgb[0], target)), out.rgb[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fixture", type=Path, default=FIXTURE)
    parser.add_argument("--out", type=Path, default=ROOT / "studies/results/sfm_fixture.json")
    parser.add_argument("--resolution", default="128x256", help="render size HxW (default 128x256)")
    args = parser.parse_args()
    from cylindersplat.data.poses.alignment import pose_errors

    torch.set_num_threads(1)
    size = tuple(int(v) for v in args.resolution.split("x"))
    truth = true_poses(args.fixture)
    result: dict = {"fixture": str(args.fixture.relative_to(ROOT.parent)) if args.fixture.is_relative_to(ROOT.parent)
                    else str(args.fixture), "machine": platform.processor() or platform.machine()}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for kind in ("files", "blur", "none"):
            make_folder(args.fixture, tmp / kind, kind)
        unscaled, _ = run_poses(tmp / "none", "--scale", "none")
        true_scale = pose_errors(poses_of(unscaled), truth).similarity.scale  # metres per SfM unit
        for kind, extra in (("files", ()), ("blur", ("--depth-prior", "file:blur"))):
            data, seconds = run_poses(tmp / kind, *extra)
            errors = pose_errors(poses_of(data), truth)
            sfm = data["sfm"]
            result[f"depth_{kind}"] = {
                "command": f"cylindersplat data poses FOLDER {' '.join(extra)}".strip(),
                "registered": len(sfm["registered"]), "not_registered": sfm["not_registered"], "points": sfm["points"],
                "mean_reprojection_error_px": sfm["mean_reprojection_error_px"], "seconds": round(seconds, 2),
                "rotation_error_deg_max": round(max(errors.rotation_deg), 4),
                "centre_error_over_baseline_max": round(errors.centre_over_baseline, 5),
                "scale_estimate": sfm["scale"],
                # data poses' output is already metric: a perfect scale gives an alignment scale of 1
                "scale_error_relative": round(1.0 / errors.similarity.scale - 1.0, 5),
                "metres_per_sfm_unit": sfm["metres_per_sfm_unit"], "true_metres_per_sfm_unit": round(true_scale, 6),
            }
        # --camera-height, with the true height: the three cameras share it (same height in the dataset); the depth
        # straight down (bottom rows) is the floor under 01 and furniture under 00 and 02: the largest of the three.
        from PIL import Image

        downs = []
        for f in FRAMES:
            mm = np.asarray(Image.open(args.fixture / f / "depth.png")).astype(np.float64)[-4:]
            downs.append(float(np.median(mm[mm > 0]) / 1000.0))
        height = max(downs)
        # the same folder as the unscaled run: its poses.json is replaced (data poses keeps it without --overwrite)
        data, seconds = run_poses(tmp / "none", "--camera-height", f"{height:.3f}", "--overwrite")
        errors = pose_errors(poses_of(data), truth)
        result["camera_height"] = {"command": f"cylindersplat data poses FOLDER --camera-height {height:.3f}",
                                   "true_height_m": round(height, 3), "scale_estimate": data["sfm"]["scale"],
                                   "scale_error_relative": round(1.0 / errors.similarity.scale - 1.0, 5)}
        recovered = poses_of(json.loads((tmp / "files" / "poses.json").read_text()))
        psnr_true, rgb_true = render_middle(tmp / "render_true", truth, size)
        psnr_sfm, rgb_sfm = render_middle(tmp / "render_sfm", recovered, size)
    from cylindersplat.metrics.image import ws_psnr

    result["render"] = {
        "model": "tiny-synth (shipped)", "resolution": f"{size[0]}x{size[1]}", "inputs": "pano_00, pano_02",
        "target": "pano_01 (real)", "ws_psnr_true_poses": round(psnr_true, 3),
        "ws_psnr_recovered_poses": round(psnr_sfm, 3),
        "difference_db": round(psnr_sfm - psnr_true, 3),
        "ws_psnr_recovered_vs_true_render": round(float(ws_psnr(rgb_sfm, rgb_true)), 3),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
