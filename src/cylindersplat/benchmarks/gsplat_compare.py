"""Our pinhole renderer against gsplat's rasterizer: speed (forward, forward + backward) and agreement.

    cylindersplat bench gsplat_compare --num 100000 500000 1300000 --height 512 --device cuda
    cylindersplat bench gsplat_compare --num 2000 --height 16 --device cpu --backend torch   # smoke: our side only

Same scene (:func:`cylindersplat.scenes.random_indoor`, SH degree 0 colours), one pinhole camera at
the room's centre, ``H x 2H`` pixels, 90-degree horizontal field of view. gsplat follows the same 3DGS
conventions (0.3 px^2 dilation, alpha cap 0.99 and threshold 1/255, transmittance floor 1e-4), but
sorts by z-depth where we sort by radial distance, and culls at the image border differently, so the
images agree closely but not bit for bit: the agreement is printed (mean |difference|, PSNR of ours
against gsplat's), not asserted.

``--variants FORWARD[,OPTION...] ...`` (with ``--backend triton``) times the Triton backend's variants
beside gsplat, one ``cylindersplat-triton[...]`` row each, as ``bench render --variants`` does (issue 35: the lean
forward and the compaction of the visible pairs, ``default,nonzero``, are to be judged on pinhole views too, where
most pairs are invisible); ``--launches`` adds the kernels one forward and its backward launch.

gsplat is an optional comparison, not a dependency: without it (or without CUDA, which its
kernels need) only our side is timed and the row says why. On a machine without a package index,
carry its wheel (``pip download --no-deps gsplat==1.5.3``: pure Python, its CUDA code is compiled at
first use with the machine's nvcc) and install it with ``pip install --no-index``; ``benchmarks/
gpu_check.sh`` does this from ``$CHECK_WHEELS`` (default ``.whl``).
"""

from __future__ import annotations

import argparse
import contextlib
import math

import torch
from torch import Tensor

from cylindersplat.render import render
from cylindersplat.render.covariance import eval_sh
from cylindersplat.scenes import random_indoor
from cylindersplat.utils.arguments import OneLineErrorParser, positive_int
from cylindersplat.utils.arguments import device as device_name

from .render import _forward_and_backward_ms, _peak_mb, _sync, launch_counts, profile_forward
from .variants import GRAPH_ROW, graph_failure, graph_variants, graphed_render, triton_variant, triton_variant_name
from .views import pinhole_intrinsics, view_camera

__all__ = ["main", "scene_line", "parity_lines"]


def _camera(height: int, device) -> tuple[Tensor, int, int]:
    """``K``, height and width of the benchmarks' 90-degree pinhole view (:func:`.render.pinhole_intrinsics`)."""
    return pinhole_intrinsics(height, device), height, 2 * height


def _gsplat_render(gsplat, g, colours, k, height, width):
    """gsplat's RGB + expected depth for the identity pose (world-to-camera = identity)."""
    colors, alphas, _ = gsplat.rasterization(
        g.means, g.rotations, g.scales, g.opacities, colours, torch.eye(4, device=g.means.device)[None], k[None],
        width, height, near_plane=0.01, eps2d=0.3, render_mode="RGB+ED", packed=True)
    return colors[0, ..., :3].permute(2, 0, 1), colors[0, ..., 3], alphas[0, ..., 0]


def _import_gsplat(device: torch.device):
    if device.type != "cuda":
        return None, "gsplat needs CUDA"
    try:
        import gsplat

        return gsplat, None
    except ImportError as exc:
        return None, f"gsplat not installed ({exc}); carry its wheel (see this module's docstring)"


def _our_renderers(backends: list[str], variants: list[tuple[str, ...]],
                   graph: bool = False) -> list[tuple[str, str, tuple | None, bool]]:
    """``(row name, backend, Triton variant or None, replayed as CUDA graphs)`` for each of our renderers timed: the
    Triton backend once per variant, and where ``graph`` replayed as CUDA graphs once per set of the variants' options
    (:func:`.variants.graph_variants`)."""
    out = []
    for backend in backends:
        for variant in (variants if backend == "triton" and variants else [None]):
            name = f"cylindersplat-{backend}" + (f"[{','.join(variant)}]" if variant else "")
            out.append((name, backend, variant, False))
        if backend == "triton" and graph:
            out += [(f"cylindersplat-triton[{tag}]", backend, variant, True)
                    for tag, variant in graph_variants(variants)]
    return out


def compare(num: int, height: int, device: torch.device, backends: list[str], repeats: int,
            variants: list[tuple[str, ...]] = (), launches: bool = False, profile: bool = False,
            graph: bool = False) -> list[dict]:
    """Rows: each of our renderers (``backends``; the Triton one once per variant of ``variants``, and replayed as CUDA
    graphs where ``graph``) and gsplat timed on the same pinhole view, then each of ours' agreement with gsplat's
    image. ``profile``: each renderer's row also holds ``profile``, the lines of :func:`.render.profile_forward`
    (host and device totals, top operators)."""
    g = random_indoor(num).to(device)
    g = type(g).from_rgb(g.means, g.scales, g.rotations, g.opacities, eval_sh(g.sh[..., :1, :], None))
    params = [t.requires_grad_() for t in g.tensors().values()]
    k, h, w = _camera(height, device)
    c2w = torch.eye(4, device=device)
    camera = view_camera("pinhole", height)
    rows, images = [], {}

    class _Out:  # gsplat's images in the shape _forward_and_backward_ms expects
        def __init__(self, rgb, depth):
            self.rgb, self.depth = rgb, depth

    renders, graphed_renders, skipped = [], [], []
    for name, backend, variant, graphed in _our_renderers(backends, list(variants), graph):
        if graphed and device.type != "cuda":
            skipped.append({"num": num, "renderer": name, "skipped": "CUDA graphs need CUDA"})
        elif graphed:  # timed last: a capture that fails takes none of the other rows with it
            graphed_renders.append((name, variant, graphed_render(g, c2w, camera)))
        else:
            renders.append((name, variant, lambda b=backend: render(g, c2w, camera, backend=b)))
    gsplat, why_not = _import_gsplat(device)
    if gsplat is not None:

        def gsplat_render():
            colours = eval_sh(g.sh, None)  # SH degree 0 -> RGB, in the graph like ours
            rgb, depth, _ = _gsplat_render(gsplat, g, colours, k, h, w)
            return _Out(rgb, depth)

        renders.append(("gsplat", None, gsplat_render))
    for name, variant, fn in renders + graphed_renders:
        row = {"num": num, "size": f"{h}x{w}", "device": str(device), "renderer": name}
        if device.type == "cuda":
            torch.cuda.reset_peak_memory_stats()
        # The variant holds for the whole timing: forward and backward both run inside it.
        with triton_variant(*variant) if variant else contextlib.nullcontext():
            try:
                row["forward_ms"], row["fwd_bwd_ms"] = _forward_and_backward_ms(fn, params, device, repeats)
                row["peak_mb"] = _peak_mb(device)
                with torch.no_grad():
                    images[name] = fn().rgb.float()
                # gsplat's kernels are not PyTorch operations, nor a graph's replay: not counted
                if launches and name != "gsplat" and GRAPH_ROW not in name:
                    for p in params:
                        p.grad = None
                    row["launches"] = launch_counts(fn)
                if profile:
                    row["profile"] = profile_forward(fn, device, f"{name}, {num} Gaussians")
            except (torch.OutOfMemoryError, MemoryError):
                row["error"] = "out of memory"
            except Exception as exc:  # noqa: BLE001 - a graph's capture is new on a device: its failure is a row
                if GRAPH_ROW not in name:
                    raise
                row["error"] = graph_failure(exc)
        for p in params:
            p.grad = None
        _sync(device)
        rows.append(row)
    rows += skipped
    if gsplat is None:
        rows.append({"num": num, "renderer": "gsplat", "skipped": why_not})
    elif "gsplat" in images:
        for name, image in images.items():
            if name == "gsplat":
                continue
            mse = float(((image - images["gsplat"]) ** 2).mean())
            rows.append({"num": num, "agreement": f"{name} vs gsplat",
                         "mean_abs": float((image - images["gsplat"]).abs().mean()),
                         "psnr_db": 10 * math.log10(1.0 / max(mse, 1e-20))})
    return rows


def main(argv: list[str] | None = None) -> None:
    parser = OneLineErrorParser(prog="cylindersplat bench gsplat_compare", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--num", type=positive_int, nargs="+", default=[100_000], help="numbers of Gaussians")
    parser.add_argument("--height", type=positive_int, default=512, help="image height (width = 2 x height)")
    parser.add_argument("--device", type=device_name, default="auto", help="auto (CUDA when present), cpu, cuda[:N]")
    parser.add_argument("--backend", nargs="+", default=["triton"], choices=["triton", "torch", "numba", "auto"],
                        help="our backends to time")
    parser.add_argument("--repeats", type=positive_int, default=5)
    parser.add_argument("--variants", nargs="+", type=triton_variant_name, default=[],
                        metavar="FORWARD[,OPTION...]",
                        help="the Triton backend's variants, one row each (as `cylindersplat bench render --variants`)")
    parser.add_argument("--launches", action="store_true",
                        help="also count the kernels one forward and its backward of ours launch")
    parser.add_argument("--profile", action="store_true",
                        help="also profile one forward of each renderer (torch.profiler): host and device totals, "
                             "top operators")
    parser.add_argument("--graph", action="store_true",
                        help="also time the Triton backend replayed as CUDA graphs (render.graphs.RenderGraph: the "
                             "render's host work made once, at capture), one more row")
    args = parser.parse_args(argv)
    if args.variants and "triton" not in args.backend:
        parser.error("--variants needs --backend triton")
    if args.graph and "triton" not in args.backend:
        parser.error("--graph needs --backend triton")
    device = torch.device(args.device)
    print(f"# pinhole {args.height}x{2 * args.height}, 90 deg horizontal FOV; torch {torch.__version__}"
          + (f"; GPU: {torch.cuda.get_device_name()}" if device.type == "cuda" else "; CPU"))
    ratios: dict[str, list[tuple[int, float, float]]] = {}
    every_row: list[dict] = []
    for num in args.num:
        rows = compare(num, args.height, device, args.backend, args.repeats, args.variants, args.launches,
                       args.profile, args.graph)
        every_row += rows
        for row in rows:
            print({k: v for k, v in row.items() if k != "profile"})
        for row in rows:
            print("\n".join(row.get("profile", [])))
        print(scene_line(num, args.height, device))
        timed = {r["renderer"]: r for r in rows if "forward_ms" in r}
        if any("agreement" in r for r in rows):
            print("# agreement: this scene's overlapping random-coloured splats are ordered by z-depth in gsplat and by"
                  " radial distance here, which decides their colours (sparse scenes agree to 45-55 dB, issue 35)")
        if "gsplat" in timed:
            for name, row in timed.items():
                if name != "gsplat":
                    ref = timed["gsplat"]
                    ratio = (row["forward_ms"] / ref["forward_ms"], row["fwd_bwd_ms"] / ref["fwd_bwd_ms"])
                    ratios.setdefault(name, []).append((num, *ratio))
                    print(f"# {name} vs gsplat ({num} Gaussians): forward {ratio[0]:.2f}x gsplat's time, fwd+bwd "
                          f"{ratio[1]:.2f}x")
    print("\n".join(parity_lines(ratios)))
    print()
    print("\n".join(comparison_table(every_row)))


def comparison_table(rows: list[dict]) -> list[str]:
    """A Markdown table of the timed rows: one line per renderer, one column per number of Gaussians, each cell
    ``forward / fwd+bwd`` ms and, where gsplat was timed at that size, the renderer's times as multiples of gsplat's
    (the table RESULTS.md keeps); a renderer skipped or failed at a size says so in its cell."""
    sizes = sorted({r["num"] for r in rows if "renderer" in r})
    cells: dict[str, dict[int, str]] = {}
    gsplat = {r["num"]: r for r in rows if r.get("renderer") == "gsplat" and "forward_ms" in r}
    for r in rows:
        if "renderer" not in r:
            continue
        if "forward_ms" in r:
            cell = f"{r['forward_ms']:.2f} / {r['fwd_bwd_ms']:.2f}"
            ref = gsplat.get(r["num"])
            if ref is not None and r["renderer"] != "gsplat":
                cell += f" ({r['forward_ms'] / ref['forward_ms']:.2f}x / {r['fwd_bwd_ms'] / ref['fwd_bwd_ms']:.2f}x)"
        else:
            cell = r.get("skipped") or r.get("error") or "failed"
        cells.setdefault(r["renderer"], {})[r["num"]] = cell
    if not cells:
        return []
    lines = ["| renderer | " + " | ".join(f"{num / 1e6:g} M: fwd / fwd+bwd ms (x gsplat)" for num in sizes) + " |",
             "|---|" + "---|" * len(sizes)]
    for name, by_size in cells.items():
        lines.append(f"| {name} | " + " | ".join(by_size.get(num, "") for num in sizes) + " |")
    return lines


def scene_line(num: int, height: int, device: torch.device, tile_size: int = 16) -> str:
    """``# scene`` line: how many of the view's Gaussians are visible and how many (Gaussian, tile) pairs they make
    (the reference projection's visible pairs and tile counts: the work a binning and compositing do, which on a
    90-degree view differs from a panorama's)."""
    from cylindersplat.render import RasterSettings
    from cylindersplat.render.rasterize import tile_spans

    g = random_indoor(num).to(device)
    with torch.no_grad():
        proj = view_camera("pinhole", height).project(g, torch.eye(4, device=device)[None], RasterSettings())
        spans = tile_spans(proj, tile_size)
        pairs = int((spans.ny * (spans.nx0 + spans.nx1)).sum())
    return (f"# scene: {len(proj.depth):,} of {num:,} Gaussians visible, {pairs:,} (Gaussian, tile) pairs "
            f"({tile_size} px tiles)")


def parity_lines(ratios: dict[str, list[tuple[int, float, float]]]) -> list[str]:
    """``# parity`` lines: for each of our renderers (its ``(num, forward ratio, fwd+bwd ratio)`` to gsplat's time at
    each size), whether it is no slower than gsplat at every size, forward and forward + backward (issue 35's
    pinhole goal), and its worst ratios."""
    lines = []
    for name, rows in ratios.items():
        worst_forward = max(rows, key=lambda r: r[1])
        worst_both = max(rows, key=lambda r: r[2])
        met = worst_forward[1] <= 1.0 and worst_both[2] <= 1.0
        sizes = "/".join(f"{num / 1e6:g} M" for num, *_ in rows)
        lines.append(f"# parity {name} (no slower than gsplat at {sizes}, forward and fwd+bwd): "
                     f"{'MET' if met else 'not met'}; worst forward {worst_forward[1]:.2f}x ({worst_forward[0]}), "
                     f"worst fwd+bwd {worst_both[2]:.2f}x ({worst_both[0]})")
    return lines


if __name__ == "__main__":
    main()
