"""Issue 34: why the volume branch costs the shipped weights 1.2-1.6 dB with one view in, and the drawings tried
against it (benchmarks/RESULTS.md, "Sharp as a warp", items 2, 3 and 5).

    python studies/one_view_leak.py --data <pano_grf fixture> --out studies/results/one_view_leak_fixture.json
    python studies/one_view_leak.py --data SYNTH --format synthetic --scenes 00000020,...,00000027 \\
        --priors default,gt --out studies/results/one_view_leak_synthetic.json

Every row draws the same forward pass of the shipped weights (with the inpaint fill behind, as FW + inpaint has). The
stored files were made before session 17, with one footprint for every pixel Gaussian (``fusion.pixel_footprint=
per_view``, ``pixel.footprint_px=0.5``): a ``--checkpoint`` of the shipped tensors saved with those two settings gives
them again.

* ``one pass``: the shipped drawing (since session 16 with the pixel Gaussians blended: the files stored before it,
  ``one_view_leak_fixture.json`` and ``one_view_leak_synthetic.json``, hold the front-most splat's ``one pass``;
  ``--checkpoint`` of a file drawn ``render_pixel_blending=over`` gives it again); ``pixel branch``: its pixel Gaussians
  alone;
* ``layers, over``: pixel Gaussians over volume Gaussians with the plain over operator (only the order changes);
* ``layers, cover LOW-HIGH``: the layered drawing, the front layer opaque from coverage HIGH (render.layered);
* ``layers, front opacity >= T``: only pixel Gaussians of opacity >= T in the front layer (edge-faded ones behind);
* ``layers, gaps only (LO-HI)``: the front layer normalised only where its partial coverage is a gap between opaque
  splats, not coverage lost to edge fading (its coverage against that of the same splats drawn opaque, LO-HI);
* ``volume near edges, R``: volume Gaussians kept only within R x H pixels of a depth edge of some input view;
* ``pixel opacity x K``: pixel Gaussians' opacities scaled by K (alpha capped at 0.99 as ever; not a valid 3DGS
  scene, an experiment only);
* ``layers, interior KxK (LO-HI)``: the front layer normalised only where it covers every pixel of a K x K window
  (an erosion of its coverage: gaps inside a seen surface, not the rims of disocclusions);
* ``surface blend T, MODE``: the pixel layer's colour by surface splatting (the normalised weights of the pixel
  Gaussians within T (relative depth) of the front surface, here the drawn layer's expected depth), with no volume
  behind (``none``), the volume behind by the over operator (``over``) or under the opaque layer (``layers``);
* ``blend (library), solid S, over``: the library's version (``render.layered.blend_front_surface``, the front
  surface that of the splats of opacity >= S drawn opaque, tolerance 0.1) with the volume behind by the over
  operator: ``render_pixel_blending=surface`` draws it so with S = 0.5;
* ``blend, opaque where solid covers (LO-HI)``: that blended layer normalised by its coverage (opaque) where its
  solid splats (opacity >= 0.5, drawn opaque) cover the pixel, smoothstep LO-HI; the over operator elsewhere;
* ``blend, opaque where summed weight (LO-HI)``: the same, where the pixel splats' summed weights (opacity x
  footprint; about 1.6 inside a surface of opaque footprint-0.5 splats, half that at its rim) reach LO-HI.

Per protocol and prior: WS-PSNR on all and hidden pixels, SSIM. Results are appended to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import torch
import torch.nn.functional as F
from sharp_variants import record  # studies/ is the script's folder: its sibling's writer

from cylindersplat.data.datasets import make_dataset
from cylindersplat.evaluation.evaluate import evaluate
from cylindersplat.evaluation.methods import Method, model_method, with_fill
from cylindersplat.geometry import project_equirect, world_to_camera
from cylindersplat.inference.pipeline import raster_settings, render_views
from cylindersplat.model.fusion import depth_edginess
from cylindersplat.model.pretrained import from_pretrained
from cylindersplat.model.sampling import sample_panorama
from cylindersplat.render import Equirect
from cylindersplat.render.api import RenderOutput
from cylindersplat.render.layered import blend_front_surface, composite_layers, render_layered


def smoothstep(x, low, high):
    t = ((x - low) / (high - low)).clamp(0, 1)
    return t * t * (3 - 2 * t)


def opaque_where(front: RenderOutput, back: RenderOutput, s) -> RenderOutput:
    """The front layer over the back one, normalised by its own coverage (opaque) with weight ``s`` per pixel and
    by the plain over operator with ``1 - s``."""
    own = front.alpha.clamp_min(1e-6)
    over = composite_layers(front, back, cover=None)
    return RenderOutput(s[:, None] * front.rgb / own[:, None] + (1 - s)[:, None] * over.rgb,
                        s * front.depth / own + (1 - s) * over.depth, s + (1 - s) * over.alpha)


def composite_interior(front: RenderOutput, back: RenderOutput, k: int, cover) -> RenderOutput:
    """The front layer over the back one, normalised by its own coverage only where it covers every pixel of the
    k x k window around (its erosion reaches ``cover``): a gap between splats inside a seen surface, not the
    partly covered rim of a disocclusion (there the window holds an uncovered pixel and the back layer shows)."""
    a = front.alpha
    flat = a.reshape(-1, 1, *a.shape[-2:])
    r = k // 2
    eroded = -F.max_pool2d(F.pad(-flat, (r, r, 0, 0), mode="circular"), k, stride=1, padding=(r, 0))
    return opaque_where(front, back, smoothstep(eroded.view_as(a), *cover))


def _forward(model, sample):
    out = model(sample.context_images[None], sample.context_priors[None], sample.context_poses[None])
    return out, out.gaussians.batch(0), out.pixel_gaussians.num_gaussians


def drawings(model) -> dict:
    """name -> sample -> RenderOutput of the targets."""
    settings = raster_settings(model.config)

    def size(sample):
        return sample.target_images.shape[-2:]

    def layers(cover):
        def run(sample):
            _, g, n = _forward(model, sample)
            h, w = size(sample)
            if cover is None:  # the plain over operator: front alpha never counts as opaque
                front = render_views(g[:n], sample.target_poses, h, w, settings=settings)
                back = render_views(g[n:], sample.target_poses, h, w, settings=settings)
                return composite_layers(front, back, cover=(0.999998, 0.999999))
            return render_layered(g[:n], g[n:], sample.target_poses, Equirect(h, w), settings=settings, cover=cover)
        return run

    def front_opacity(threshold):
        def run(sample):
            _, g, n = _forward(model, sample)
            index = torch.arange(g.num_gaussians)
            front = (index < n) & (g.opacities >= threshold)
            order = torch.cat([index[front], index[~front]])
            h, w = size(sample)
            return render_views(g[order], sample.target_poses, h, w, settings=settings, front=int(front.sum()))
        return run

    def gaps_only(low, high):  # normalise coverage gaps between opaque splats, not coverage lost to edge fading
        def run(sample):
            _, g, n = _forward(model, sample)
            h, w = size(sample)
            front = render_views(g[:n], sample.target_poses, h, w, settings=settings)
            unfaded = render_views(replace(g[:n], opacities=torch.ones_like(g.opacities[:n])), sample.target_poses,
                                   h, w, settings=settings)
            back = render_views(g[n:], sample.target_poses, h, w, settings=settings)
            a = front.alpha
            return opaque_where(front, back, smoothstep(a, 0.3, 0.6) * smoothstep(a / unfaded.alpha.clamp_min(1e-6),
                                                                                    low, high))
        return run

    def near_edges(radius):
        def run(sample):
            out, g, n = _forward(model, sample)
            _, v, h, w = out.refined_depth.shape
            edge = (depth_edginess(out.refined_depth, 0.05) > 0.5).float().view(v, 1, h, w)
            r = max(1, round(radius * h))
            near = F.max_pool2d(F.pad(edge, (r, r, 0, 0), mode="circular"), 2 * r + 1, stride=1, padding=(r, 0))
            points = world_to_camera(g.means[n:][None, None].expand(1, v, -1, 3), sample.context_poses[None])
            uv, _ = project_equirect(points, h, w)
            keep = sample_panorama(near, uv.view(v, -1, 2)).view(v, -1).amax(0).clamp(0, 1)
            opacities = g.opacities.clone()
            opacities[n:] = opacities[n:] * keep
            th, tw = size(sample)
            return render_views(replace(g, opacities=opacities), sample.target_poses, th, tw, settings=settings)
        return run

    def opacity_gain(k):
        def run(sample):
            _, g, n = _forward(model, sample)
            opacities = g.opacities.clone()
            opacities[:n] = opacities[:n] * k
            h, w = size(sample)
            scaled = replace(g, opacities=opacities)
            scaled.validate = lambda: None  # opacities above 1: outside the container's contract, on purpose
            return render_views(scaled, sample.target_poses, h, w, settings=settings)
        return run

    def interior(k, low, high):  # normalise only where the front layer covers every pixel of a k x k window
        def run(sample):
            _, g, n = _forward(model, sample)
            h, w = size(sample)
            front = render_views(g[:n], sample.target_poses, h, w, settings=settings)
            back = render_views(g[n:], sample.target_poses, h, w, settings=settings)
            return composite_interior(front, back, k, (low, high))
        return run

    def surface_blend(eps, back_mode):
        """The pixel layer's colour as the normalised Gaussian-weighted mean of the pixel Gaussians on the front
        surface (EWA surface splatting's epsilon-z-buffer, gated per Gaussian at its centre), instead of the over
        operator's front-most splat; its coverage stays the opaque drawing's."""
        def run(sample):
            _, g, n = _forward(model, sample)
            h, w = size(sample)
            pix = g[:n]
            front = render_views(pix, sample.target_poses, h, w, settings=settings)
            surface = torch.where(front.alpha > 0.5, front.depth / front.alpha.clamp_min(1e-6),
                                  torch.full_like(front.depth, float("inf")))
            points = world_to_camera(pix.means[None].expand(len(sample.target_poses), -1, 3), sample.target_poses)
            uv, radial = project_equirect(points, h, w)
            u = uv[..., 0].floor().long() % w
            v = uv[..., 1].floor().long().clamp(0, h - 1)
            blend = settings if False else replace(settings, alpha_min=1e-9)
            rgbs = []
            for t in range(len(sample.target_poses)):
                on_front = radial[t] <= surface[t, v[t], u[t]] * (1 + eps)
                weights = replace(pix, opacities=pix.opacities * on_front * 1e-3)
                mean = render_views(weights, sample.target_poses[t:t + 1], h, w, settings=blend)
                colour = mean.rgb / mean.alpha.clamp_min(1e-12)[:, None]
                rgbs.append(torch.where(mean.alpha[:, None] > 1e-7, colour * front.alpha[t:t + 1, None],
                                        front.rgb[t:t + 1]))
            front = RenderOutput(torch.cat(rgbs), front.depth, front.alpha)
            if back_mode == "none":
                return front
            back = render_views(g[n:], sample.target_poses, h, w, settings=settings)
            cover = (0.999998, 0.999999) if back_mode == "over" else (0.3, 0.6)
            return composite_layers(front, back, cover=cover)
        return run

    runs = {"layers, over": layers(None)}
    runs.update({f"layers, cover {lo:g}-{hi:g}": layers((lo, hi)) for lo, hi in ((0.3, 0.6), (0.6, 0.9), (0.8, 0.97))})
    runs.update({f"layers, front opacity >= {t:g}": front_opacity(t) for t in (0.5, 0.9, 0.99)})
    runs.update({f"layers, gaps only ({lo:g}-{hi:g})": gaps_only(lo, hi) for lo, hi in ((0.5, 0.9), (0.8, 0.97))})
    runs.update({f"volume near edges, {r:g}": near_edges(r) for r in (0.03, 0.06, 0.12)})
    runs.update({f"pixel opacity x {k:g}": opacity_gain(k) for k in (1.5, 2.0)})
    runs.update({f"surface blend {e:g}, {m}": surface_blend(e, m) for e in (0.1, 0.2, 0.4)
                 for m in ("none", "over", "layers")})
    def library_blend(solid):  # render.layered.blend_front_surface (gated by the solid splats), volume behind by over
        def run(sample):
            _, g, n = _forward(model, sample)
            h, w = size(sample)
            camera = Equirect(h, w)
            front = render_views(g[:n], sample.target_poses, h, w, settings=settings)
            front = blend_front_surface(g[:n], sample.target_poses, camera, front, settings=settings,
                                        solid_opacity=solid)
            back = render_views(g[n:], sample.target_poses, h, w, settings=settings)
            return composite_layers(front, back, cover=None)
        return run

    runs.update({f"blend (library), solid {s:g}, over": library_blend(s) for s in (0.2, 0.5, 0.8)})

    def blended_opaque_where(coverage, low, high):  # the blended layer opaque where coverage(pix, sample) is high
        def run(sample):
            _, g, n = _forward(model, sample)
            h, w = size(sample)
            pix = g[:n]
            front = render_views(pix, sample.target_poses, h, w, settings=settings)
            front = blend_front_surface(pix, sample.target_poses, Equirect(h, w), front, settings=settings)
            back = render_views(g[n:], sample.target_poses, h, w, settings=settings)
            return opaque_where(front, back, smoothstep(coverage(pix, sample, h, w), low, high))
        return run

    def solid_cover(pix, sample, h, w):  # the coverage of its solid splats
        solid = replace(pix, opacities=(pix.opacities >= 0.5).to(pix.opacities))
        return render_views(solid, sample.target_poses, h, w, settings=settings).alpha

    def weight_sum(pix, sample, h, w):  # its splats' summed weights: the over operator as a sum at 1/1000 opacity
        faint = replace(pix, opacities=pix.opacities * 1e-3)
        return render_views(faint, sample.target_poses, h, w, settings=replace(settings, alpha_min=1e-12)).alpha / 1e-3

    runs.update({f"blend, opaque where solid covers ({lo:g}-{hi:g})": blended_opaque_where(solid_cover, lo, hi)
                 for lo, hi in ((0.3, 0.6), (0.6, 0.9), (0.8, 0.97))})
    runs.update({f"blend, opaque where summed weight ({lo:g}-{hi:g})": blended_opaque_where(weight_sum, lo, hi)
                 for lo, hi in ((0.8, 1.2), (1.0, 1.4), (1.2, 1.8))})
    runs.update({f"layers, interior {k}x{k} ({lo:g}-{hi:g})": interior(k, lo, hi)
                 for k, lo, hi in ((3, 0.3, 0.6), (3, 0.5, 0.8), (5, 0.3, 0.6))})
    return runs


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data", required=True)
    p.add_argument("--format", default="pano_grf")
    p.add_argument("--size", type=int, default=64, help="panorama height (width = 2 x height)")
    p.add_argument("--protocols", default="two_view,one_view")
    p.add_argument("--priors", default="gt,degraded:mono")
    p.add_argument("--scenes", default=None, help="synthetic data: comma list of scene ids")
    p.add_argument("--checkpoint", default="tiny-synth")
    p.add_argument("--out", required=True)
    p.add_argument("--only", default=None, help="drawing-name prefixes to run, separated by '|' (default: all)")
    args = p.parse_args()
    model = from_pretrained(args.checkpoint).eval()
    out = Path(args.out)
    results = json.loads(out.read_text()) if out.exists() else {}
    for prior in args.priors.split(","):
        for protocol in args.protocols.split(","):
            key = f"{protocol} {args.size}x{2 * args.size} {prior}"
            if key in results:
                continue
            start = time.time()
            options = {"scenes": args.scenes.split(",")} if args.scenes else {}
            dataset = make_dataset(args.format, args.data, views=protocol, resolution=(args.size, 2 * args.size),
                                   depth_prior=prior, **options)
            methods = [with_fill(model_method(model, "one pass"), "inpaint", "one pass"),
                       with_fill(model_method(model.with_config().set_mode("pixel"), "pixel branch"), "inpaint",
                                 "pixel branch")]
            runs = drawings(model)
            if args.only:
                runs = {name: run for name, run in runs.items() if name.startswith(tuple(args.only.split("|")))}
            methods += [with_fill(Method(name, run), "inpaint", name) for name, run in runs.items()]
            res = evaluate(dataset, methods, progress=False)
            record(results, key, res, out, start, metrics=("ws_psnr", "ws_psnr_occluded", "ssim"))


if __name__ == "__main__":
    torch.set_grad_enabled(False)
    main()
