#!/usr/bin/env bash
# On a CUDA machine: the Triton backend's tests against the reference (compiled, not interpreted),
# then the issue's benchmark (512x1024; 0.1 M, 0.5 M, 1.3 M Gaussians; reference, Triton, cubemap route).
# Usage: bash benchmarks/gpu_check.sh [OUT_DIR]   -> OUT_DIR/{tests.log,bench.log}
set -uo pipefail
cd "$(dirname "$0")/.."
out=${1:-outputs/gpu_check}
mkdir -p "$out"
export PYTHONPATH=src${PYTHONPATH:+:$PYTHONPATH}
python -c "import torch, triton; print(torch.__version__, triton.__version__, torch.cuda.get_device_name())" | tee "$out/tests.log"
python -m pytest -q tests/test_render_triton.py tests/test_render.py 2>&1 | tee -a "$out/tests.log"
python -m cylindersplat bench render --num 100000 500000 1300000 --height 512 --device cuda \
    --backend torch triton --cubemap --repeats 10 2>&1 | tee "$out/bench.log"
