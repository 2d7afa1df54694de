"""Issue 34: pictures of what surface blending and covisible footprints change (docs/model.md, "Sharp pixel
Gaussians").

    cylindersplat data synth --out SYNTH --scenes 28 --resolution 128x256 --profile occlusion --seed 0
    python studies/blend_picture.py --data SYNTH --scene 00000020 --out docs/images/surface_blending.jpg
    python studies/blend_picture.py --data SYNTH --scene 00000020 --compare footprint --protocol one_view \
        --out docs/images/covisible_footprint.jpg

One procedural held-out scene, the first target of ``--protocol``: rows target / the shipped weights drawn the old way
/ drawn the new way, each beside its absolute error (x4). ``--compare blending``: the front-most pixel splat winning
(``render_pixel_blending=over``) against the front surface blended (session 16's drawing); ``footprint``: one
footprint for every pixel Gaussian (session 16's drawing) against footprints by covisibility (the shipped drawing).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).parent))
from sharp_variants import OVER, RECIPE, SHIPPED  # noqa: E402

from cylindersplat.data.datasets import make_dataset  # noqa: E402
from cylindersplat.evaluation.methods import model_method, with_fill  # noqa: E402
from cylindersplat.model.pretrained import from_pretrained  # noqa: E402


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True)
    p.add_argument("--format", default="synthetic")
    p.add_argument("--scene", default="00000020")
    p.add_argument("--size", type=int, default=128)
    p.add_argument("--protocol", default="two_view", choices=("two_view", "one_view"))
    p.add_argument("--compare", default="blending", choices=("blending", "footprint"))
    p.add_argument("--out", required=True)
    args = p.parse_args()
    options = {"scenes": [args.scene]} if args.format == "synthetic" else {}
    dataset = make_dataset(args.format, args.data, views=args.protocol, resolution=(args.size, 2 * args.size),
                           **options)
    sample = dataset[0]
    base = from_pretrained("tiny-synth").eval()
    target = sample.target_images[0]
    rows = [torch.cat([target, torch.zeros_like(target)], 2)]
    for drawing in (OVER, RECIPE) if args.compare == "blending" else (RECIPE, SHIPPED):
        render = with_fill(model_method(base.with_config(**drawing)), "inpaint").run(sample).rgb[0].clamp(0, 1)
        error = ((render - target).abs().mean(0, keepdim=True) * 4).clamp(0, 1).expand(3, -1, -1)
        rows.append(torch.cat([render, error], 2))
    image = (torch.cat(rows, 1).permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    image = np.kron(image, np.ones((2, 2, 1), dtype=np.uint8))  # pixels doubled: the splat lattice is pixel-sized
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(args.out, image, quality=90)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    torch.set_grad_enabled(False)
    main()
