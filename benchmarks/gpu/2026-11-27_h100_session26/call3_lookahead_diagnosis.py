"""Why ``LOOKAHEAD = "row"`` differed from ``"id"`` on a CUDA pinhole view (session 26, 2026-11-27; the failure of
``tests/test_render_triton_lookahead.py::test_loading_the_next_row_ahead_changes_no_bit_on_pinhole_views_with_empty_tiles``
in call 1). Prints, per case, each output's largest difference between the two lookaheads, how many pixels differ,
and each one's distance to the float64 PyTorch reference; then each compiled forward kernel's count of arithmetic
and load instructions, and writes their PTX to OUT_DIR/forward_ptx.txt.

    python benchmarks/gpu/2026-11-27_h100_session26/call3_lookahead_diagnosis.py OUT_DIR   # from the repo's root

The result (call3_lookahead_diagnosis.log): each lookahead is deterministic; they differ only on pinhole views with
``PAIR_FIELD = "ids"``, by at most 2.4e-7, both equally close to the reference; the PTX of the two kernels has the
same arithmetic instructions in another order. (At this call, "id" and "rects" were still the defaults. This file is
call 3's script tidied for the repository: the same cases, its lines labelled a little differently from the log's.)
"""

import os
import sys

import pytest
import torch

sys.path.insert(0, "tests")
from cylindersplat.gaussians import Gaussians  # noqa: E402
from cylindersplat.render import (  # noqa: E402
    Equirect,
    Pinhole,
    RasterSettings,
    render,
    triton_backend,
    triton_binning,
    triton_kernels,
)
from render_scenes import shell_scene, yaw_pose  # noqa: E402

F32 = torch.float32
DEVICE = "cuda" if torch.cuda.is_available() else "cpu"
K = torch.tensor([[14.0, 0.0, 12.3], [0.0, 15.0, 9.6], [0.0, 0.0, 1.0]])
OPS = ("fma.rn.f32", "mul.f32", "add.f32", "sub.f32", "ex2.approx", "ld.global", "bar.sync")
patch = pytest.MonkeyPatch()


def run(g, poses, camera, lookahead, backend="triton", **switches):
    patch.setattr(triton_backend, "LOOKAHEAD", lookahead)
    for name, value in switches.items():
        patch.setattr(triton_backend, name, value)
    patch.setattr(triton_binning, "_CAPACITY", {})
    params = {k: v.detach().to(DEVICE).clone().requires_grad_() for k, v in g.tensors().items()}  # as the test
    return render(Gaussians(**params), poses.to(DEVICE), camera, background=(0.2, 0.3, 0.4), backend=backend,
                  settings=RasterSettings(tile_size=8))


def compare(tag, g, poses, camera, first="id", second="row", **switches):
    a, b = run(g, poses, camera, first, **switches), run(g, poses, camera, second, **switches)
    ref = run(g.to(torch.float64), poses.to(torch.float64), camera, "id", backend="torch")
    for name in ("rgb", "depth", "alpha"):
        x, y, r = getattr(a, name).detach(), getattr(b, name).detach(), getattr(ref, name).detach().float()
        diff = (x - y).abs()
        line = (f"{tag} {name}: {first} vs {second} max {diff.max().item():.3e}, {int((diff > 0).sum())} of "
                f"{diff.numel()} differ; {first} vs torch64 {(x - r).abs().max().item():.3e}, {second} vs torch64 "
                f"{(y - r).abs().max().item():.3e}")
        if (diff > 0).any():
            line += f"; at {torch.nonzero(diff > 0)[:8].tolist()}"
        print(line, flush=True)


def main(out_dir):
    pose = yaw_pose(0.7, dtype=F32)
    g = shell_scene(6, seed=5, scale=(0.05, 0.2), dtype=F32)  # the failing test's scene
    compare("failing-case pinhole ids, determinism", g, pose, Pinhole(K, 20, 24), second="id", PAIR_FIELD="ids")
    compare("failing-case pinhole ids, determinism", g, pose, Pinhole(K, 20, 24), first="row", PAIR_FIELD="ids")
    for pair_field in ("ids", "rects"):
        compare(f"failing-case pinhole {pair_field}", g, pose, Pinhole(K, 20, 24), PAIR_FIELD=pair_field)
    for seed in range(4):
        g = shell_scene(200, seed=seed, scale=(0.05, 0.3), dtype=F32)
        compare(f"seed {seed} pinhole 40x48 ids", g, pose, Pinhole(K * 2, 40, 48), PAIR_FIELD="ids")
        for pair_field in ("ids", "rects"):
            compare(f"seed {seed} equirect 32x64 {pair_field}", g, pose, Equirect(32, 64), PAIR_FIELD=pair_field)
    caches = getattr(triton_kernels.composite_forward_kernel, "device_caches", None)
    if not caches:
        print("no compiled kernels to read (Triton's interpreter?)")
        return
    with open(os.path.join(out_dir, "forward_ptx.txt"), "w") as f:
        for entry in caches.values():
            table = entry[0] if isinstance(entry, tuple) else entry
            for i, (key, kernel) in enumerate(table.items()):
                ptx = kernel.asm.get("ptx", "")
                print(f"kernel {i}: {str(key)[:300]}\n  counts {({op: ptx.count(op) for op in OPS})}", flush=True)
                f.write(f"===== kernel {i} key {key}\n{ptx}\n")


if __name__ == "__main__":
    main(sys.argv[1])
