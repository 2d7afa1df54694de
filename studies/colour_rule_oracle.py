"""Colour rules for hidden points at the *true* geometry (issue 23's oracle test), and the fill oracles.

    python studies/colour_rule_oracle.py [--data DIR] [--json studies/results/colour_rule_oracle.json]

Every target pixel of the study's 8 held-out scenes is lifted to its true 3D point (ground-truth target depth);
each colour rule then colours that point from the two context panoramas, as the volume branch's colour module
would colour a Gaussian placed there, given the contexts' true depth, the depth prior the model gets, or that prior
rescaled per view by the photometric scale search (``model.prior_alignment=photometric``).
Scored with WS-PSNR on the pixels no input sees (the robust mask of ``data/occlusion.py``) and on all pixels.
If a rule fails here, at perfect geometry, no amount of training of the branch that uses it can make it colour
hidden surfaces. Beside them, fills of the *true* target: copying the nearest visible pixel, and the true mean
colour of all of a target's hidden pixels (the per-view one-colour oracle) or of each connected hidden region
(the per-region oracle). About a minute on 2 CPU cores.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from cylindersplat.data import SyntheticDataset
from cylindersplat.data.occlusion import occluded_mask
from cylindersplat.data.synth import profile_config, write_synthetic_dataset
from cylindersplat.evaluation.masked import MIN_OCCLUDED_PIXELS, masked_ws_psnr
from cylindersplat.geometry import camera_to_world, equirect_rays
from cylindersplat.model.prior_alignment import photometric_prior_scales
from cylindersplat.model.rgb_retrieval import retrieve_colors, retrieve_colors_window
from cylindersplat.utils.jsonfile import json_text

# (name, description, rule(points_world (1, N, 3), images (1, V, 3, H, W), depth (1, V, H, W), c2w (1, V, 4, 4)))
RULES = [
    ("eq6_T1", "Eq. 6, softmax_v(-(d_g - d_o) / T), T = 1 m (the paper)",
     lambda p, i, d, c: retrieve_colors(p, i, d, c, 1.0)[0]),
    ("eq6_T0.1", "Eq. 6 with T = 0.1 m", lambda p, i, d, c: retrieve_colors(p, i, d, c, 0.1)[0]),
] + [
    (f"surface_w{w}_T{t}", f"nearest observed surface, {2 * w + 1}x{2 * w + 1} taps per view, T = {t} m",
     lambda p, i, d, c, w=w, t=t: retrieve_colors_window(p, i, d, c, w, t)[0])
    for w in (1, 2, 4, 6, 8) for t in (1.0, 0.3, 0.1, 0.03)
]


def knn_colours(points: torch.Tensor, images: torch.Tensor, depth: torch.Tensor, c2w: torch.Tensor,
                k: int) -> torch.Tensor:
    """Mean colour of the ``k`` observed 3D points (every context pixel lifted with its depth) nearest each point."""
    _, v, _, h, w = images.shape
    rays = equirect_rays(h, w, dtype=points.dtype)
    observed = camera_to_world((depth[0, :, :, :, None] * rays).reshape(v, -1, 3), c2w[0]).reshape(-1, 3)
    colours = images[0].permute(0, 2, 3, 1).reshape(-1, 3)
    valid = depth[0].reshape(-1) > 0
    observed, colours = observed[valid], colours[valid]
    nearest = torch.cdist(points[0], observed).topk(k, largest=False).indices  # (N, k)
    return colours[nearest].mean(dim=1)[None]


def true_points(sample) -> torch.Tensor:
    """World points of the first target's pixels, (1, H*W, 3)."""
    h, w = sample.target_depths.shape[-2:]
    cam = sample.target_depths[0, :, :, None] * equirect_rays(h, w, dtype=sample.target_depths.dtype)
    return camera_to_world(cam.reshape(-1, 3), sample.target_poses[0]).reshape(1, -1, 3)


def region_fill(truth: np.ndarray, hidden: np.ndarray, regions: str, depth: np.ndarray | None = None) -> np.ndarray:
    """The true target with its hidden pixels replaced by their true latitude-weighted mean colour, per target
    (``"target"``), per connected hidden region (``"component"``) or per region and 10 %-wide depth band
    (``"component_depth"``, roughly one surface each; needs the target's ``depth``)."""
    from scipy import ndimage

    from cylindersplat.metrics.image import ws_weights

    weight = ws_weights(truth.shape[1])[:, None].numpy() * hidden
    if regions == "target":
        labels = hidden.astype(int)
    elif regions in ("component", "component_depth"):
        labels = ndimage.label(hidden, structure=np.ones((3, 3)))[0]
        if regions == "component_depth":
            band = np.floor(np.log(np.maximum(depth, 1e-3)) / 0.1).astype(int)
            labels = np.where(hidden, labels * 10_000 + (band - band.min()), 0)
    else:
        raise ValueError(f"unknown regions {regions!r}")
    fill = truth.copy()
    for label in np.unique(labels[hidden]):
        region = labels == label
        fill[:, region] = (truth[:, region] * weight[region]).sum(1, keepdims=True) / weight[region].sum()
    return fill


def nearest_visible(truth: np.ndarray, hidden: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    rows, cols = ndimage.distance_transform_edt(hidden, return_distances=False, return_indices=True)
    return truth[:, rows, cols]


@torch.no_grad()
def run(data: Path) -> dict:
    if not (data / "meta.json").is_file():
        write_synthetic_dataset(data, 28, (64, 128), profile_config("occlusion"), seed=0)
    scenes = SyntheticDataset(data).scenes[-8:]
    dataset = SyntheticDataset(data, views="two_view", scenes=scenes)
    scores: dict[str, dict[str, list[float]]] = {}

    def add(name: str, key: str, value: float) -> None:
        scores.setdefault(name, {}).setdefault(key, []).append(float(value))

    hidden_counts = []
    for sample in dataset:
        h, w = sample.target_images.shape[-2:]
        truth = sample.target_images[0].double()
        mask = occluded_mask(sample.target_depths[0], sample.target_poses[0], sample.context_gt_depths,
                             sample.context_poses)
        hidden_counts.append(int(mask.sum()))
        scored = int(mask.sum()) >= MIN_OCCLUDED_PIXELS
        points = true_points(sample).double()
        images, c2w = sample.context_images[None].double(), sample.context_poses[None].double()
        aligned = sample.context_priors * photometric_prior_scales(
            sample.context_images[None], sample.context_priors[None], sample.context_poses[None])[0, :, None, None]
        for depth_name, depth in (("true depth", sample.context_gt_depths), ("prior", sample.context_priors),
                                  ("prior, photometric scale", aligned)):
            depth = depth[None].double()
            rules = RULES + [(f"knn{k}", f"mean colour of the {k} nearest observed 3D points",
                              lambda p, i, d, c, k=k: knn_colours(p, i, d, c, k)) for k in (1, 8)]
            for name, _, rule in rules:
                colours = rule(points, images, depth, c2w)[0].T.reshape(3, h, w)
                add(f"{name} | {depth_name}", "all", masked_ws_psnr(colours, truth, torch.ones_like(mask)))
                if scored:
                    add(f"{name} | {depth_name}", "occluded", masked_ws_psnr(colours, truth, mask))
        if scored:
            t, m = truth.numpy(), mask.numpy()
            for name, fill in (("nearest visible pixel of the truth", nearest_visible(t, m)),
                               ("per-view one-colour oracle", region_fill(t, m, "target")),
                               ("per-region oracle", region_fill(t, m, "component"))):
                add(name, "occluded", masked_ws_psnr(torch.from_numpy(fill), truth, mask))
    means = {name: {key: float(np.mean(v)) for key, v in parts.items()} for name, parts in scores.items()}
    descriptions = {name: text for name, text, _ in RULES}
    descriptions.update({"knn1": "colour of the nearest observed 3D point", "knn8": "mean colour of the 8 nearest"})
    return {"data": str(data), "held_out_scenes": scenes, "hidden_pixels": hidden_counts,
            "hidden_share": sum(hidden_counts) / (len(hidden_counts) * h * w), "descriptions": descriptions,
            "means": means}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=Path("outputs/study28"),
                        help="the study's data (generated there if absent: 28 scenes, occlusion profile, 64x128)")
    parser.add_argument("--json", type=Path, default=Path("studies/results/colour_rule_oracle.json"))
    args = parser.parse_args()
    report = run(args.data)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json_text(report))
    print(f"hidden share {report['hidden_share']:.3%}; WS-PSNR hidden / all:")
    for name, m in sorted(report["means"].items(), key=lambda kv: -kv[1].get("occluded", 0)):
        print(f"  {name:45s} {m.get('occluded', float('nan')):6.2f} / {m.get('all', float('nan')):6.2f}")


if __name__ == "__main__":
    main()
