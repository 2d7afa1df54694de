"""Every Triton kernel compiles for a Hopper GPU (sm_90), here, without one.

Triton's CPU interpreter runs the kernels' arithmetic but skips the compiler's checks (constexpr
globals, types, control flow it cannot lower); this compiles each kernel ahead of time through
Triton's whole NVIDIA pipeline (TTIR -> PTX -> cubin with the bundled ptxas) for the constants the
backends use, so a kernel that only the GPU would refuse fails here first. The compilation runs in a
child process without ``TRITON_INTERPRET`` (under it ``@triton.jit`` makes interpreted functions).
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

triton = pytest.importorskip("triton")

from triton.compiler import ASTSource  # noqa: E402

try:
    import triton.backends.nvidia as nvidia_backend
    from triton.backends.compiler import GPUTarget
except ImportError:  # pragma: no cover - a Triton without the NVIDIA backend
    nvidia_backend = None

from cylindersplat.render import (  # noqa: E402
    triton_binning_kernels,
    triton_checks_kernels,
    triton_kernels,
    triton_projection_kernels,
)

FLOAT_SCALARS = {"fx", "fy", "cx", "cy", "near", "pole_eps", "dilation", "sigma_extent", "alpha_min", "max_u2",
                 "max_v2",
                 "sigma2", "alpha_max", "t_min", "inv_atol", "max_distance"}
POINTER_TYPES = {"valid_ptr": "*i1", "uv_ptr": "*fp32", "ext_ptr": "*fp32", "depth_bits_ptr": "*i32",
                 "pair_gaussian_ptr": "*i64", "rows_ptr": "*i64", "cols_ptr": "*i64", "tile_start_ptr": "*i64"}
# Every pointer of the binning kernels is int64 but the depth bits, the tile keys and the depth ranks
# (and the centres and extents the fused binning reads).
INT64_POINTER_KERNELS = {"count_pairs_kernel", "emit_fused_keys_kernel", "write_fused_pairs_kernel",
                         "count_lean_kernel", "emit_lean_keys_kernel", "write_lean_pairs_kernel"}
# The lean forward's int32 pair fields (triton_backend.FORWARD = "lean"), as the lean binning writes them and the
# compositing kernels read them.
LEAN_PAIRS = {"pair_gaussian_ptr": "*i32", "rows_ptr": "*i32", "cols_ptr": "*i32"}


# Where the compositing kernels read a pair's parameters (triton_backend.CompositeRows): the projection's rows, the
# opacities and the colours apart, or pack_projected's 11 columns.
SPLIT_ROWS = {"GEO_STRIDE": 8, "OPAC_STRIDE": 1, "COLOUR_STRIDE": 3, "DEPTH_COL": 7}
PACKED_ROWS = {"GEO_STRIDE": 11, "OPAC_STRIDE": 11, "COLOUR_STRIDE": 11, "DEPTH_COL": 9}


def _signature(kernel, constexprs, pointers=None):
    sig = {}
    for name in kernel.arg_names:
        if name in constexprs:
            sig[name] = "constexpr"
        elif name.endswith("_ptr"):
            default = "*i64" if kernel.__name__ in INT64_POINTER_KERNELS else "*fp32"
            sig[name] = (pointers or {}).get(name, POINTER_TYPES.get(name, default))
        else:
            sig[name] = "fp32" if name in FLOAT_SCALARS else "i32"
    return sig


def _ptxas_available() -> bool:
    if nvidia_backend is None:
        return False
    return (Path(nvidia_backend.__file__).parent / "bin" / "ptxas").exists() or shutil.which("ptxas") is not None


KERNELS = [
    (triton_projection_kernels.project_forward_kernel, {"MODEL": 0, "BLOCK": 128}),
    (triton_projection_kernels.project_forward_kernel, {"MODEL": 1, "BLOCK": 128}),
    (triton_projection_kernels.project_backward_kernel, {"MODEL": 0, "BLOCK": 128}),
    (triton_projection_kernels.project_backward_kernel, {"MODEL": 1, "BLOCK": 128}),
    # the binning (int16 tile keys under 32768 tiles, else int32), panorama (wrapped columns) and pinhole
    (triton_binning_kernels.count_pairs_kernel, {"TILE": 16, "WRAP_U": True, "BLOCK": 128}),
    (triton_binning_kernels.count_pairs_kernel, {"TILE": 16, "WRAP_U": False, "BLOCK": 128},
     {"uv_ptr": "*fp64", "ext_ptr": "*fp64"}),  # float64 projections (the reference's, of float64 Gaussians)
    (triton_binning_kernels.emit_fused_keys_kernel, {"TILE": 16, "WRAP_U": True, "BLOCK": 128},
     {"key_ptr": "*i16", "rank_ptr": "*i32"}),
    (triton_binning_kernels.emit_fused_keys_kernel, {"TILE": 16, "WRAP_U": False, "BLOCK": 128},
     {"key_ptr": "*i32", "rank_ptr": "*i32"}),
    (triton_binning_kernels.write_fused_pairs_kernel, {"TILE": 16, "WRAP_U": True, "BLOCK": 128}, {"rank_ptr": "*i32"}),
    (triton_binning_kernels.write_fused_pairs_kernel, {"TILE": 16, "WRAP_U": False, "BLOCK": 128},
     {"rank_ptr": "*i32"}),
    # the lean binning (strided centres and extents, int32 pair fields, tile starts)
    (triton_binning_kernels.count_lean_kernel, {"TILE": 16, "WRAP_U": True, "BLOCK": 128}, {"key_ptr": "*i16"}),
    (triton_binning_kernels.count_lean_kernel, {"TILE": 16, "WRAP_U": False, "BLOCK": 128}, {"key_ptr": "*i32"}),
    (triton_binning_kernels.emit_lean_keys_kernel, {"TILE": 16, "WRAP_U": True, "BLOCK": 128},
     {"key_ptr": "*i16", "rank_ptr": "*i32"}),
    (triton_binning_kernels.emit_lean_keys_kernel, {"TILE": 16, "WRAP_U": False, "BLOCK": 128},
     {"key_ptr": "*i32", "rank_ptr": "*i32"}),
    (triton_binning_kernels.write_lean_pairs_kernel, {"TILE": 16, "WRAP_U": True, "BLOCK": 128},
     {"sorted_key_ptr": "*i16", "rank_ptr": "*i32", "gaussian_ptr": "*i32", "rows_ptr": "*i32", "cols_ptr": "*i32"}),
    (triton_binning_kernels.write_lean_pairs_kernel, {"TILE": 16, "WRAP_U": False, "BLOCK": 128},
     {"sorted_key_ptr": "*i32", "rank_ptr": "*i32", "gaussian_ptr": "*i32", "rows_ptr": "*i32", "cols_ptr": "*i32"}),
    # pairs that carry only their Gaussian (triton_backend.PAIR_FIELD = "ids"): its row emitted, no rectangles
    (triton_binning_kernels.emit_fused_keys_kernel, {"TILE": 16, "WRAP_U": True, "BLOCK": 128, "ROW_IDS": True},
     {"key_ptr": "*i16", "rank_ptr": "*i32"}),
    (triton_binning_kernels.emit_lean_keys_kernel, {"TILE": 16, "WRAP_U": False, "BLOCK": 128, "ROW_IDS": True},
     {"key_ptr": "*i32", "rank_ptr": "*i32"}),
    (triton_binning_kernels.write_lean_pairs_kernel, {"TILE": 16, "WRAP_U": True, "BLOCK": 128, "RECTS": False},
     {"sorted_key_ptr": "*i16", "rank_ptr": "*i32", "gaussian_ptr": "*i32", "rows_ptr": "*i32", "cols_ptr": "*i32"}),
    # the input checks: float32 Gaussians and poses, and float64 / bfloat16 ones
    (triton_checks_kernels.input_checks_kernel, {"FLAT": 1024, "CAMERAS": 32}, {"flags_ptr": "*i64"}),
    (triton_checks_kernels.input_checks_kernel, {"FLAT": 1024, "CAMERAS": 32},
     {"flags_ptr": "*i64", "means_ptr": "*fp64", "scales_ptr": "*bf16", "rotations_ptr": "*fp16", "c2w_ptr": "*fp64"}),
    (triton_kernels.composite_forward_kernel, {"TILE": 16, "WRAP_U": True, **SPLIT_ROWS}, LEAN_PAIRS),
    # the default forward's compositing on the projection's rows, opacities and colours with int64 pair fields
    (triton_kernels.composite_forward_kernel, {"TILE": 16, "WRAP_U": True, **SPLIT_ROWS}),
    (triton_kernels.composite_backward_kernel, {"TILE": 16, "WRAP_U": False, **SPLIT_ROWS, "SPLIT": 1}),
    (triton_kernels.composite_backward_kernel, {"TILE": 16, "WRAP_U": True, **SPLIT_ROWS, "SPLIT": 1}, LEAN_PAIRS),
    # the compositing computing each pair's rectangle (PAIR_FIELD "ids"), panorama (the seam's two intervals) and
    # pinhole
    (triton_kernels.composite_forward_kernel, {"TILE": 16, "WRAP_U": True, **SPLIT_ROWS, "RECTS": False}, LEAN_PAIRS),
    (triton_kernels.composite_forward_kernel, {"TILE": 16, "WRAP_U": False, **SPLIT_ROWS, "RECTS": False},
     LEAN_PAIRS),
    (triton_kernels.composite_backward_kernel, {"TILE": 16, "WRAP_U": True, **SPLIT_ROWS, "SPLIT": 1, "RECTS": False},
     LEAN_PAIRS),
    (triton_kernels.composite_backward_kernel, {"TILE": 16, "WRAP_U": False, **SPLIT_ROWS, "SPLIT": 1,
                                                "RECTS": False}, LEAN_PAIRS),
    # the next pair's row loaded while one is composited (LOOKAHEAD "row"), with and without rectangles
    (triton_kernels.composite_forward_kernel, {"TILE": 16, "WRAP_U": True, **SPLIT_ROWS, "RECTS": False,
                                               "ROW_AHEAD": True}, LEAN_PAIRS),
    (triton_kernels.composite_forward_kernel, {"TILE": 16, "WRAP_U": False, **SPLIT_ROWS, "ROW_AHEAD": True}),
    (triton_kernels.composite_backward_kernel, {"TILE": 16, "WRAP_U": True, **SPLIT_ROWS, "SPLIT": 1, "RECTS": False,
                                                "ROW_AHEAD": True}, LEAN_PAIRS),
    (triton_kernels.composite_backward_kernel, {"TILE": 16, "WRAP_U": False, **SPLIT_ROWS, "SPLIT": 1,
                                                "ROW_AHEAD": True}),
    # the packed rows of other projections (pack_projected's 11 columns)
    (triton_kernels.composite_forward_kernel, {"TILE": 16, "WRAP_U": True, **PACKED_ROWS}),
    (triton_kernels.composite_backward_kernel, {"TILE": 16, "WRAP_U": False, **PACKED_ROWS, "SPLIT": 0}),
    (triton_kernels.composite_backward_kernel, {"TILE": 16, "WRAP_U": True, **PACKED_ROWS, "SPLIT": 0}),
]


def _with_defaults(kernel, constexprs: dict) -> dict:
    """``constexprs`` and the kernel's defaults of the compile-time constants not given (e.g. ``RECTS``)."""
    defaults = {p.name: p.default for p in kernel.params if p.is_constexpr and p.has_default}
    return {**defaults, **constexprs}


def compile_all() -> None:
    """Compile every kernel of :data:`KERNELS` for sm_90 (run without ``TRITON_INTERPRET``)."""
    for kernel, constexprs, *pointers in KERNELS:
        constexprs = _with_defaults(kernel, constexprs)
        signature = _signature(kernel, constexprs, *pointers)
        compiled = triton.compile(ASTSource(fn=kernel, signature=signature, constexprs=constexprs),
                                  target=GPUTarget("cuda", 90, 32))
        assert compiled.asm.get("cubin"), kernel.__name__
        print("compiled", kernel.__name__, constexprs)


@pytest.mark.slow
@pytest.mark.skipif(not _ptxas_available(), reason="Triton's NVIDIA backend (with ptxas) is not installed")
def test_every_kernel_compiles_for_sm90():
    env = {k: v for k, v in os.environ.items() if k != "TRITON_INTERPRET"}
    env["PYTHONPATH"] = os.pathsep.join([str(Path(__file__).resolve().parents[1] / "src"), env.get("PYTHONPATH", "")])
    done = subprocess.run([sys.executable, __file__], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert done.stdout.count("compiled ") == len(KERNELS), done.stdout


if __name__ == "__main__":
    compile_all()
