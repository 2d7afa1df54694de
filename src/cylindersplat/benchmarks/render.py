"""Benchmark the equirect rasterizer: forward and forward+backward, median ms and peak memory.

    cylindersplat bench render                       # 100k Gaussians, 256x512, CPU (+CUDA if present)
    cylindersplat bench render --num 100000 500000 1300000 --height 512 --device cuda --backend torch triton --cubemap
    cylindersplat bench render --device cpu --threads 2 --backend torch numba --ply-view 1000000

Scenes come from :func:`cylindersplat.scenes.random_indoor` (Gaussians on the walls of an 8 x 3 x 6 m
room plus 20% scattered inside). ``--stages`` also prints where the time goes: projection, tile
binning, fragment expansion + sort, compositing, backward for the PyTorch reference; with
``--backend triton`` the Triton backend's own stages (fused projection kernel, key binning,
compositing kernels), with ``--backend numba`` (or ``auto`` on the CPU) the numba backend's (fused projection,
counting sort by tile, compositing). ``--ply-view N`` also times what a user waits for to see a scene: a PLY of ``N``
Gaussians loaded and one 512x1024 view rendered (no gradients), per backend. A backend that runs out
of memory is reported as such in the rows and the closing table (the others are still timed).
``--stages`` starts with the render's input checks (``checks``: queued on the device for the Triton backend,
:data:`cylindersplat.render.triton_backend.CHECK`). ``--launches`` also counts the kernels one forward and its
backward launch (PyTorch operations and Triton kernels: on an H100 the Triton path is launch-bound, issue 35).
``--variants FORWARD[,OPTION...] ...`` times the Triton backend's variants side by side (issue 35): one
``triton[...]`` row each - ``triton[lean]`` with the lean forward (:data:`cylindersplat.render.triton_backend.FORWARD`),
``triton[default,nonzero]`` with the visible pairs compacted first (:data:`cylindersplat.render.triton_backend.
COMPACTION`), ``triton[default,torch]`` with the input checks as PyTorch operations
(:data:`cylindersplat.render.triton_backend.CHECK`), ``triton[lean,rects]`` with pairs that carry their pixel rectangles
(:data:`cylindersplat.render.triton_backend.PAIR_FIELD`), ``triton[default,id]`` with only the next pair's Gaussian
id loaded ahead (:data:`cylindersplat.render.triton_backend.LOOKAHEAD`) - then ``# agreement`` lines (each variant's
image and gradients against the first's, at the timed size), e.g. ``--backend triton --stages --variants default
lean default,rects``.
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import statistics
import tempfile
import time

import torch

from cylindersplat.benchmarks.launches import count_render_launches
from cylindersplat.gaussians import load_ply, save_ply
from cylindersplat.render import api, render, render_cubemap, render_equirect, triton_backend
from cylindersplat.render.numba_backend import numba_available
from cylindersplat.render.projection import RasterSettings
from cylindersplat.render.rasterize import bin_to_tiles, composite, expand_fragments
from cylindersplat.scenes import random_indoor
from cylindersplat.utils.allocator import keep_freed_memory
from cylindersplat.utils.arguments import OneLineErrorParser, positive_int
from cylindersplat.utils.arguments import device as device_name

from .variants import (
    GRAPH_ROW,
    graph_failure,
    graph_variants,
    graphed_render,
    triton_variant,
    triton_variant_name,
    variant_agreement,
)
from .views import CAMERAS, view_camera


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize()


def _peak_mb(device: torch.device) -> float:
    if device.type == "cuda":
        return torch.cuda.max_memory_allocated() / 2**20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # peak RSS of the process


def _time(fn, device, repeats: int, warmup: int = 1) -> float:
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        _sync(device)
        t0 = time.perf_counter()
        fn()
        _sync(device)
        times.append((time.perf_counter() - t0) * 1000)
    return statistics.median(times)


def _forward_and_backward_ms(render, params, device, repeats: int) -> tuple[float, float]:
    """Median ms of ``render()`` without gradients, and of ``render()`` + backward of rgb and depth."""

    def forward():
        with torch.no_grad():
            render()

    def forward_backward():
        out = render()
        (out.rgb.sum() + out.depth.sum()).backward()
        for p in params:
            p.grad = None

    return _time(forward, device, repeats), _time(forward_backward, device, repeats)


def bench(num: int, height: int, device: torch.device, backend: str, repeats: int, cubemap: bool, stages: bool,
          launches: bool = False, camera: str = "equirect", graph: bool = False) -> dict:
    """One row: ``backend``'s forward and forward + backward (``graph``: the Triton backend replayed as CUDA graphs,
    :func:`.variants.graphed_render`, timed alone), and what else is asked for."""
    g = random_indoor(num).to(device)
    params = [t.requires_grad_() for t in g.tensors().values()]
    c2w = torch.eye(4, device=device)
    width = 2 * height
    model = view_camera(camera, height)
    row = {"num": num, "size": f"{height}x{width}", "device": str(device), "backend": backend}
    if camera != "equirect":
        row["camera"] = camera

    def measure(prefix: str, render) -> None:
        """Forward and forward+backward of ``render`` into ``row``; out of memory is recorded, not fatal."""
        if device.type == "cuda":
            torch.cuda.reset_peak_memory_stats()
        try:
            row[f"{prefix}forward_ms"], row[f"{prefix}fwd_bwd_ms"] = _forward_and_backward_ms(render, params, device,
                                                                                              repeats)
            row[f"{prefix}peak_mb"] = _peak_mb(device)
        except (torch.OutOfMemoryError, MemoryError):
            row[f"{prefix}error"] = "out of memory"
            _free(params, device)

    if graph:
        row["backend"] = f"{backend}[{GRAPH_ROW}]"
        try:
            measure("", graphed_render(g, c2w, model))
        except Exception as exc:  # noqa: BLE001 - a graph's capture is new on a device: its failure is a row
            row["error"] = graph_failure(exc)
        return row
    measure("", lambda: render(g, c2w, model, backend=backend))
    if cubemap:
        measure("cubemap_", lambda: render_cubemap(g, c2w, height, width, backend=backend))
    if launches and "error" not in row:
        _free(params, device)  # no gradients to accumulate into: the backward counted is a first one
        row["launches"] = launch_counts(lambda: render(g, c2w, model, backend=backend))
        _free(params, device)
    if stages:
        try:
            row["stages_ms"] = stage_breakdown(g, c2w, model, device, repeats, backend)
        except (torch.OutOfMemoryError, MemoryError):
            row["stages_error"] = "out of memory"
            _free(params, device)
    return row


def launch_counts(render) -> dict:
    """Kernels launched by one forward of ``render`` and by its backward (PyTorch operations and Triton kernels:
    :func:`cylindersplat.benchmarks.launches.count_launches`), after one uncounted call."""
    forward, backward = count_render_launches(render)
    return {"forward": forward.kernels, "forward_triton": sum(forward.triton.values()), "backward": backward.kernels}


def _free(params, device) -> None:
    for p in params:
        p.grad = None
    if device.type == "cuda":
        torch.cuda.empty_cache()


def _stage_kind(backend: str, device: torch.device) -> str:
    """Whose stages ``--stages`` times for ``backend``: ``"triton"``, ``"numba"`` or the reference's (``"torch"``);
    ``"auto"`` as the render picks (Triton on CUDA, numba on the CPU where installed)."""
    if backend == "auto":
        return "triton" if device.type == "cuda" else ("numba" if numba_available() else "torch")
    return backend if backend in ("triton", "numba") else "torch"


def stage_breakdown(g, c2w, camera, device, repeats: int, backend: str = "torch") -> dict:
    """Median time of each stage of one forward + backward: the reference's, the Triton backend's or the numba
    backend's (each backend's own projection, binning and compositing)."""
    settings = RasterSettings()
    kind = _stage_kind(backend, device)
    fast = kind == "triton"
    names = (("checks", "project", "bin", "composite", "backward") if kind != "torch"
             else ("checks", "project", "bin", "fragments", "composite", "backward"))
    acc: dict[str, list[float]] = {k: [] for k in names}
    for it in range(repeats + 1):
        marks = [time.perf_counter()]

        def mark():
            _sync(device)
            marks.append(time.perf_counter())

        # The render's input checks: queued as the Triton backend queues them (triton_backend.CHECK), else read now.
        api._queue_checks("triton", g, c2w) if fast else api._check_inputs(g, c2w)
        mark()
        lean = False
        if fast:  # the Triton backend's own stages: fused projection kernel, key binning
            from cylindersplat.render import triton_binning as binning
            from cylindersplat.render.projection import flatten_cameras, project_gaussians
            from cylindersplat.render.triton_projection import project_dense_triton

            proj = project_gaussians(*flatten_cameras(g, c2w)[:2], camera, settings, project_dense_triton,
                                     every_pair=triton_backend.takes_every_pair())
            mark()
            rects = triton_backend.pairs_carry_rects(proj)
            lean = triton_backend.FORWARD == "lean" or not rects  # PairBins (else TileBins)
            if triton_backend.FORWARD == "lean":  # the capacity grows in the warm-up iteration
                key, capacity = binning.lean_capacity(proj, settings.tile_size)
                bins = binning.bin_lean(proj, settings.tile_size, capacity, rects)
                while int(bins.total) > bins.capacity:
                    bins = binning.bin_lean(proj, settings.tile_size, binning.grow_capacity(key, int(bins.total)),
                                            rects)
            elif not rects:
                bins = binning.bin_ids(proj, settings.tile_size)
            else:
                bins = binning.bin_to_tiles_by_key(proj, settings.tile_size)
        elif kind == "numba":  # the numba backend's: fused float64 projection, counting sort by tile
            from cylindersplat.render.numba_backend import bin_pairs_numba
            from cylindersplat.render.numba_projection import project_dense_numba
            from cylindersplat.render.projection import flatten_cameras, project_gaussians

            proj = project_gaussians(*flatten_cameras(g, c2w)[:2], camera, settings, project_dense_numba)
            mark()
            bins = bin_pairs_numba(proj, settings.tile_size)
        else:
            proj = camera.project(g, c2w, settings)
            mark()
            bins = bin_to_tiles(proj, settings.tile_size)
        mark()
        num_fragments = None
        if fast:
            from cylindersplat.render.triton_backend import composite_bins, composite_triton

            rgb, depth, _ = (composite_bins if lean else composite_triton)(proj, bins, settings)
        elif kind == "numba":
            from cylindersplat.render.numba_backend import composite_numba

            rgb, depth, _ = composite_numba(proj, bins, settings)
        else:
            fg, fp = expand_fragments(proj, bins, settings.sigma_extent)
            mark()
            rgb, depth, _ = composite(proj, fg, fp, settings)
            num_fragments = len(fg)
        mark()
        (rgb.sum() + depth.sum()).backward()
        mark()
        for p in g.tensors().values():
            p.grad = None
        if it > 0:  # first iteration is warm-up
            for k, (a, b) in zip(acc, zip(marks[:-1], marks[1:])):
                acc[k].append((b - a) * 1000)
    out = {k: round(statistics.median(v), 2) for k, v in acc.items()}
    out["num_pairs"] = (int(bins.total) if lean else len(bins.pairs) if kind == "numba" else len(bins.tile))
    if num_fragments is not None:
        out["num_fragments"] = num_fragments
    return out


def _profiled(fn, device: torch.device):
    """``torch.profiler``'s record of one call of ``fn`` after one unprofiled call (first-call work: compilation,
    caches), and the key its operators rank by: device time on CUDA, host time on a CPU."""
    fn()
    _sync(device)
    activities = [torch.profiler.ProfilerActivity.CPU]
    activities += [torch.profiler.ProfilerActivity.CUDA] if device.type == "cuda" else []
    with torch.profiler.profile(activities=activities) as prof:
        fn()
        _sync(device)
    return prof, "self_device_time_total" if device.type == "cuda" else "self_cpu_time_total"


def profile(num: int, height: int, device: torch.device, backend: str, rows: int = 20,
            label: str | None = None, camera: str = "equirect") -> None:
    """Top operators (by device time) of one forward + backward."""
    g = random_indoor(num).to(device)
    for t in g.tensors().values():
        t.requires_grad_()
    c2w = torch.eye(4, device=device)
    model = view_camera(camera, height)

    def step():
        out = render(g, c2w, model, backend=backend)
        (out.rgb.sum() + out.depth.sum()).backward()

    prof, key = _profiled(step, device)
    print(f"# profile: {label or backend}, {num} Gaussians, {height}x{2 * height} {camera}, one forward + backward")
    print(prof.key_averages().table(sort_by=key, row_limit=rows, max_name_column_width=60))


def profile_forward(fn, device: torch.device, label: str, rows: int = 10) -> list[str]:
    """One forward of ``fn`` (no gradients) under ``torch.profiler``, after one unprofiled call: a line with its
    host and device totals, then its top ``rows`` operators by device time (by host time on a CPU). The host total
    against the device's says whether the forward waits on its launches (issue 35: ours against gsplat's)."""
    with torch.no_grad():
        prof, key = _profiled(fn, device)
    events = prof.key_averages()
    host_ms = sum(e.self_cpu_time_total for e in events) / 1000
    # The device's own events (kernels, copies) only: an operator's row repeats the time of the kernels it launched.
    kernels = [e for e in events if e.device_type != torch.autograd.DeviceType.CPU]
    device_ms = sum(e.self_device_time_total for e in kernels) / 1000
    lines = [f"# profile, one forward: {label}: host {host_ms:.2f} ms (profiled), device {device_ms:.2f} ms in "
             f"{sum(e.count for e in kernels)} kernels and copies"]
    for e in sorted(events, key=lambda e: getattr(e, key), reverse=True)[:rows]:
        lines.append(f"#   {getattr(e, key) / 1000:8.3f} ms  x{e.count:<3d} {e.key[:70]}")
    return lines


def ply_view(num: int, device: torch.device, backends: list[str], folder: str, height: int = 512) -> list[dict]:
    """Seconds to load a PLY of ``num`` Gaussians and render one ``height x 2 height`` view, per backend (the second
    of two renders: the first compiles where a backend compiles)."""
    path = save_ply(random_indoor(num), os.path.join(folder, f"scene_{num}.ply"))
    rows = []
    for backend in backends:
        row = {"ply_view": num, "size": f"{height}x{2 * height}", "device": str(device), "backend": backend}
        try:
            for _ in range(2):
                t0 = time.perf_counter()
                g = load_ply(path, device=device)
                t1 = time.perf_counter()
                with torch.no_grad():
                    render_equirect(g, torch.eye(4, device=device), height, 2 * height, backend=backend)
                _sync(device)
                t2 = time.perf_counter()
            row.update(load_s=round(t1 - t0, 3), render_s=round(t2 - t1, 3), total_s=round(t2 - t0, 3))
        except (torch.OutOfMemoryError, MemoryError) as exc:
            need = getattr(exc, "need", None)  # the reference's RenderMemoryError: refused before allocating
            row["error"] = "out of memory" + (f" (needs {need / 2**30:.0f} GiB)" if need else "")
        rows.append(row)
    return rows


def ratio_line(base: dict, row: dict, dev: str) -> str:
    """``# B vs A (...)``: how many times faster ``row`` is than ``base``; a run out of memory says so instead."""
    head = f"# {row['backend']} vs {base['backend']} ({row['num']} Gaussians, {row['size']}, {dev}): "
    failed = [r for r in (base, row) if "forward_ms" not in r]
    if failed:
        return head + "; ".join(f"{r['backend']}: {r.get('error', 'no timing')}" for r in failed) + " - no ratio"
    text = head + (f"forward {base['forward_ms'] / row['forward_ms']:.1f}x faster, "
                   f"fwd+bwd {base['fwd_bwd_ms'] / row['fwd_bwd_ms']:.1f}x")
    if "cubemap_forward_ms" in row:
        text += (f"; vs cubemap route: forward {row['cubemap_forward_ms'] / row['forward_ms']:.1f}x, "
                 f"fwd+bwd {row['cubemap_fwd_bwd_ms'] / row['fwd_bwd_ms']:.1f}x")
    return text


def _load_note() -> str:
    """``", load average 0.52 / 0.61 / 0.70 (1 / 5 / 15 min)"``, or nothing where the system has none."""
    try:
        loads = os.getloadavg()
    except (AttributeError, OSError):  # not on Windows
        return ""
    return ", load average " + " / ".join(f"{x:.2f}" for x in loads) + " (1 / 5 / 15 min)"


def table(rows: list[dict]) -> list[str]:
    """Markdown table of timed rows; a backend out of memory shows that in its cells."""
    lines = ["| device | backend | Gaussians | size | forward ms | fwd+bwd ms | peak MB |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        if "ply_view" in r:
            cells = ((f"PLY load {r['load_s']} s + view {r['render_s']} s = {r['total_s']} s", "", "")
                     if "total_s" in r else (r.get("error", "failed"),) * 2 + ("",))
            lines.append(f"| {r['device']} | {r['backend']} | {r['ply_view']:,} (PLY) | {r['size']} "
                         "| " + " | ".join(cells) + " |")
            continue
        if "forward_ms" in r:
            cells = (f"{r['forward_ms']:.1f}", f"{r['fwd_bwd_ms']:.1f}", f"{r['peak_mb']:.0f}")
        else:
            cells = (r.get("error", "failed"),) * 2 + ("",)
        lines.append(f"| {r['device']} | {r['backend']} | {r['num']:,} | {r['size']} | " + " | ".join(cells) + " |")
    return lines


def main(argv: list[str] | None = None) -> None:
    parser = OneLineErrorParser(prog="cylindersplat bench render", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--num", type=positive_int, nargs="+", default=[100_000], help="numbers of Gaussians")
    parser.add_argument("--height", type=positive_int, default=256)
    parser.add_argument("--device", nargs="+", type=device_name, default=None,
                        help="devices: cpu, cuda[:N], auto (default: cpu, and cuda when present)")
    parser.add_argument("--backend", nargs="+", default=["torch"], choices=["torch", "triton", "numba", "auto"],
                        help="render backends, timed in one run; ratios are printed against the first "
                             "(%(choices)s)")
    parser.add_argument("--repeats", type=positive_int, default=5)
    parser.add_argument("--camera", choices=CAMERAS, default="equirect",
                        help="the view timed: the 512x1024-style panorama, or a 90-degree pinhole view of the same "
                             "size (gsplat's kind of camera; `bench gsplat_compare` times gsplat on it)")
    parser.add_argument("--cubemap", action="store_true", help="also time the cubemap route (panoramas)")
    parser.add_argument("--stages", action="store_true", help="print the per-stage breakdown")
    parser.add_argument("--threads", type=positive_int, default=None, help="torch CPU threads")
    parser.add_argument("--default-malloc", action="store_true", help="skip the glibc allocator tuning")
    parser.add_argument("--profile", action="store_true",
                        help="print torch.profiler's top kernels of one forward+backward")
    parser.add_argument("--compile", action="store_true", help="projection through torch.compile "
                                                               "(render.projection.compile_projection)")
    parser.add_argument("--variants", nargs="+", type=triton_variant_name, default=[],
                        metavar="FORWARD[,OPTION...]",
                        help="Triton variants timed side by side, one row each: forward "
                             f"{'|'.join(triton_backend.FORWARDS)} (default {triton_backend.FORWARD}; lean: no host "
                             "sync before compositing), then options in any order: compaction "
                             f"{'|'.join(triton_backend.COMPACTIONS)} (default {triton_backend.COMPACTION}; nonzero: "
                             "only the visible pairs, one more host sync), input checks "
                             f"{'|'.join(triton_backend.CHECKS)} (default {triton_backend.CHECK}; torch: some seventy "
                             "PyTorch operations instead of one kernel), pair fields "
                             f"{'|'.join(triton_backend.PAIR_FIELDS)} (default {triton_backend.PAIR_FIELD}; ids: pairs "
                             "carry only their Gaussian, the compositing computes their pixel rectangles), lookahead "
                             f"{'|'.join(triton_backend.LOOKAHEADS)} (default {triton_backend.LOOKAHEAD}; row: the "
                             "compositing loads the next pair's row while it composites one)")
    parser.add_argument("--launches", action="store_true",
                        help="also count the kernels one forward and its backward launch (PyTorch operations and "
                             "Triton kernels; on any device)")
    parser.add_argument("--graph", action="store_true",
                        help="also time the Triton backend replayed as CUDA graphs (render.graphs.RenderGraph: the "
                             "render's host work made once, at capture), one more row (CUDA only)")
    parser.add_argument("--tile-walk", action="store_true",
                        help="also print, per size, how many (Gaussian, tile) pairs the Triton compositing kernels "
                             "walk before every pixel of a tile is opaque (benchmarks.tile_walk, on the CPU)")
    parser.add_argument("--ply-view", type=positive_int, nargs="+", default=[], metavar="N",
                        help="also time loading a PLY of N Gaussians and rendering one 512x1024 view, per backend")
    args = parser.parse_args(argv)
    if args.cubemap and args.camera != "equirect":
        parser.error("--cubemap renders panoramas: leave out --camera pinhole")
    for flag, given in (("--variants", args.variants), ("--graph", args.graph)):
        if given and "triton" not in args.backend:  # it times Triton rows only: refused, not silently ignored
            parser.error(f"{flag} needs --backend triton")
    if args.compile:
        from cylindersplat.render.projection import compile_projection

        compile_projection(True)
    if not args.default_malloc:
        keep_freed_memory()
    if args.threads:
        torch.set_num_threads(args.threads)
    devices = args.device or (["cpu", "cuda"] if torch.cuda.is_available() else ["cpu"])
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, {torch.get_num_threads()} torch "
          f"threads, torch {torch.__version__}{', compiled projection' if args.compile else ''}{_load_note()}")
    if torch.cuda.is_available():
        print(f"# GPU: {torch.cuda.get_device_name()}")
    timed = []
    for dev in devices:
        for num in args.num:
            rows = []
            triton_ran = False
            for backend in args.backend:
                interpreted = os.environ.get("TRITON_INTERPRET") == "1"
                if backend == "triton" and torch.device(dev).type != "cuda" and not interpreted:
                    print(f"# skipping triton on {dev}: needs CUDA (or TRITON_INTERPRET=1, very slow)")
                    continue
                triton_ran |= backend == "triton"
                variants = args.variants if backend == "triton" and args.variants else [None]
                for variant in variants:
                    with triton_variant(*(variant or ())):
                        rows.append(bench(num, args.height, torch.device(dev), backend, args.repeats, args.cubemap,
                                          args.stages, args.launches, args.camera))
                        if variant is not None:
                            rows[-1]["backend"] = f"triton[{','.join(variant)}]"
                        print(rows[-1])
                        if args.profile:
                            profile(num, args.height, torch.device(dev), backend, label=rows[-1]["backend"],
                                    camera=args.camera)
                for tag, variant in graph_variants(args.variants) if backend == "triton" and args.graph else []:
                    if torch.device(dev).type != "cuda":
                        print(f"# skipping triton[{tag}] on {dev}: CUDA graphs need CUDA")
                        continue
                    with triton_variant(*(variant or ())):
                        rows.append(bench(num, args.height, torch.device(dev), backend, args.repeats, False, False,
                                          camera=args.camera, graph=True))
                    rows[-1]["backend"] = f"triton[{tag}]"
                    print(rows[-1])
            for row in rows[1:]:
                print(ratio_line(rows[0], row, dev))
            if triton_ran and len(args.variants) > 1:
                for line in variant_agreement(num, args.height, torch.device(dev), args.variants, args.camera):
                    print(line)
            timed += rows
        if args.ply_view:
            with tempfile.TemporaryDirectory(prefix="cylindersplat_bench_") as folder:
                for num in args.ply_view:
                    backends = [b for b in args.backend if b != "triton" or torch.device(dev).type == "cuda"]
                    for row in ply_view(num, torch.device(dev), backends, folder):
                        print(row)
                        timed.append(row)
    if args.tile_walk:
        from .tile_walk import tile_walk_line

        for num in args.num:
            print(tile_walk_line(num, args.height, args.camera))
    print()
    print("\n".join(table(timed)))
    if any(row.get("device") == "cpu" and "peak_mb" in row for row in timed):
        print("# peak MB on the CPU: the process's peak resident memory up to that row, so a row includes the rows "
              "before it (time one backend per command to compare their memory); on CUDA, "
              "torch.cuda.max_memory_allocated of the row's renders")
    if _load_note():  # other jobs on a shared machine slow every row: the load before and after says how much
        print(f"#{_load_note().removeprefix(',')} at the end")


if __name__ == "__main__":
    main()
