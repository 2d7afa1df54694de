"""How well the photometric scale search (``model.prior_alignment=photometric``) finds each depth prior's scale.

    python studies/prior_alignment.py [--synthetic DIR ...] [--json studies/results/prior_alignment.json]

1. The real Matterport3D triplet (``../shared/fixtures``, 256x512, contexts 1 m apart): its true depth multiplied
   by known per-view factors; the search should find their inverses.
2. Procedural datasets (the held-out 8 scenes of each ``--synthetic`` folder, two views): the simulated prior
   (global scale error exp(N(0, 0.1)), blur, noise, holes); the "true" scale of a view is the median of true depth /
   prior over its valid pixels. Reported: mean |log error| of the scale before and after the search.
Seconds per two-view sample on this machine are reported too.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import torch

from cylindersplat.model.prior_alignment import photometric_prior_scales

FIXTURE = (Path(__file__).resolve().parents[1] / ".." / "shared/fixtures/pano_grf"
           / "png_render_test_1024x512_seq_len_3_m3d_dist_0.5")
KNOWN_ERRORS = ([1.0, 1.0], [0.8, 1.25], [0.6, 1.5], [1.3, 0.9], [0.5, 2.0])


def real_triplet(folder: Path) -> list[dict]:
    from cylindersplat.data.depth_prior import GroundTruthPrior
    from cylindersplat.data.pano_grf import PanoGRFDataset

    s = PanoGRFDataset(folder, resolution=(256, 512), depth_prior=GroundTruthPrior())[0]
    rows = []
    for errors in KNOWN_ERRORS:
        factor = torch.tensor(errors)
        start = time.perf_counter()
        found = photometric_prior_scales(s.context_images[None], s.context_gt_depths[None] * factor[:, None, None],
                                         s.context_poses[None])[0]
        rows.append({"applied": errors, "found": found.tolist(), "residual": (found * factor).tolist(),
                     "seconds": time.perf_counter() - start})
    return rows


def synthetic(folder: Path) -> dict:
    from cylindersplat.data import SyntheticDataset

    before, after, seconds = [], [], []
    for s in SyntheticDataset(folder, views="two_view", scenes=SyntheticDataset(folder).scenes[-8:]):
        start = time.perf_counter()
        found = photometric_prior_scales(s.context_images[None], s.context_priors[None], s.context_poses[None])[0]
        seconds.append(time.perf_counter() - start)
        for v in range(found.shape[0]):
            valid = s.context_priors[v] > 0
            true = float((s.context_gt_depths[v][valid] / s.context_priors[v][valid]).median())
            before.append(abs(math.log(true)))
            after.append(abs(math.log(true / float(found[v]))))
    return {"views": len(before), "mean_abs_log_error_before": sum(before) / len(before),
            "mean_abs_log_error_after": sum(after) / len(after), "max_abs_log_error_after": max(after),
            "seconds_per_sample": sum(seconds) / len(seconds)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fixture", type=Path, default=FIXTURE)
    parser.add_argument("--synthetic", type=Path, nargs="*", default=[], help="procedural dataset folders")
    parser.add_argument("--json", type=Path, default=Path("studies/results/prior_alignment.json"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    report: dict = {"threads": 1}
    if args.fixture.is_dir():
        report["real_triplet"] = real_triplet(args.fixture)
        for row in report["real_triplet"]:
            print("real triplet, applied", row["applied"], "-> residual", [round(x, 4) for x in row["residual"]],
                  f"({row['seconds']:.2f} s)")
    else:
        print(f"real fixture missing: {args.fixture} (skipped)")
    report["synthetic"] = {}
    for folder in args.synthetic:
        report["synthetic"][str(folder)] = row = synthetic(folder)
        print(f"{folder}: mean |log scale error| {row['mean_abs_log_error_before']:.4f} -> "
              f"{row['mean_abs_log_error_after']:.4f} (max {row['max_abs_log_error_after']:.4f}, {row['views']} views)")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
