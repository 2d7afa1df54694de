#!/usr/bin/env bash
# Everything issue "paper scale on the GPU" asks of a CUDA machine, in one command, with one summary:
#   1. the Triton backend's tests compiled on the GPU (and the reference's tests beside them);
#   2. rasterizer at 0.1 / 0.5 / 1.3 M Gaussians, 512x1024: reference, Triton, cubemap route, ratios;
#      plus where the Triton path spends its time;
#   3. the paper config end to end (network + one render), 2 / 3 / 4 views at 512x1024;
#   4. one training step of each curriculum stage at 512x1024, batch 1, bf16 autocast;
#   5. a short training run of the paper config on procedural data at 256x512 (loss must fall).
# Usage: bash benchmarks/gpu_check.sh [OUT_DIR] [ITEMS]
#   ITEMS (default all): tests render stages model model_compiled train run
# Each item runs under its own time limit (seconds: CHECK_LIMIT_<ITEM>); a failing item does not stop
# the others. Summary: OUT_DIR/summary.md; every item's full log: OUT_DIR/logs.tar.gz.
set -uo pipefail
cd "$(dirname "$0")/.."
out=$(realpath -m "${1:-outputs/gpu_check}")
items=${2:-tests render stages model model_compiled train run}
work=${CHECK_WORK:-/tmp/cylindersplat_gpu_check}  # synthetic data and the training run (not results)
rm -rf "$work"; mkdir -p "$out" "$work"
export PYTHONPATH=$PWD/src${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
py=${PYTHON:-python3}
summary=$out/summary.md

{
  echo "# GPU check — $(date -u +%Y-%m-%d)"
  echo
  echo '```'
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null
  $py -c "import torch, triton; print('torch', torch.__version__, '| triton', triton.__version__, '|', torch.cuda.get_device_name())"
  echo '```'
} > "$summary"

run_item() {  # name, limit, command...
  local name=$1 limit=$2; shift 2
  local t0=$SECONDS
  echo "== $name (limit ${limit}s): $*" | tee "$out/$name.log"
  timeout --kill-after=10 "$limit" "$@" >> "$out/$name.log" 2>&1
  local rc=$?
  local status=ok; [ $rc -eq 124 ] && status="TIMED OUT after ${limit}s"; [ $rc -ne 0 ] && [ $rc -ne 124 ] && status="FAILED (exit $rc)"
  { echo; echo "## $name — $status, $((SECONDS - t0)) s"; echo; } >> "$summary"
  echo "== $name: $status ($((SECONDS - t0)) s)"
  return 0
}

train_run() {  # backend: a short paper-config training run on procedural 256x512 data
  $py -m cylindersplat train --config tiny --out "$work/run_$1" model.preset=paper data.root="$work/synth" \
      data.resolution=[256,512] train.stages=[1,3] train.steps_per_stage=[120,40] train.lr=3e-4 \
      train.render_backend=$1 train.log_every=10 train.image_every=0 train.progress=false loss.use_lpips=off &&
  $py benchmarks/train_run_summary.py "$work/run_$1/metrics.jsonl"
}

export -f train_run; export py work

for item in $items; do
  case $item in
    tests)
      run_item tests "${CHECK_LIMIT_TESTS:-150}" $py -m pytest -q -p no:cacheprovider tests/test_render_triton.py \
          tests/test_render_cameras.py tests/test_render.py
      tail -n 3 "$out/tests.log" | sed 's/^/    /' >> "$summary" ;;
    render)
      run_item render "${CHECK_LIMIT_RENDER:-200}" $py -m cylindersplat bench render --num 100000 500000 1300000 \
          --height 512 --device cuda --backend torch triton --cubemap --repeats 5
      grep -h '^[{#]' "$out/render.log" | sed 's/^/    /' >> "$summary" ;;
    stages)  # where the Triton path spends its time, eager and with the compiled projection
      run_item stages "${CHECK_LIMIT_STAGES:-90}" $py -m cylindersplat bench render --num 100000 1300000 \
          --height 512 --device cuda --backend triton --stages --repeats 5 --profile
      run_item stages_compiled "${CHECK_LIMIT_STAGES:-150}" $py -m cylindersplat bench render --num 100000 1300000 \
          --height 512 --device cuda --backend triton --stages --repeats 5 --compile
      grep -h '^[{#]' "$out/stages.log" "$out/stages_compiled.log" | sed 's/^/    /' >> "$summary" ;;
    model)
      run_item model "${CHECK_LIMIT_MODEL:-120}" $py -m cylindersplat bench model --config paper --height 512 \
          --render --views 1 2 3 4 --repeats 5
      grep -h '^[|#(]' "$out/model.log" >> "$summary" ;;
    model_compiled)
      run_item model_compiled "${CHECK_LIMIT_MODEL:-180}" $py -m cylindersplat bench model --config paper --height 512 \
          --render --views 2 3 4 --repeats 5 --warmup 2 --compile
      grep -h '^[|#(]' "$out/model_compiled.log" >> "$summary" ;;
    train)
      run_item train "${CHECK_LIMIT_TRAIN:-120}" $py -m cylindersplat bench train --config paper --height 512 --steps 5
      grep -h '^[|#]' "$out/train.log" >> "$summary" ;;
    run)
      run_item run_data 60 $py -m cylindersplat data synth --out "$work/synth" --scenes 24 --resolution 256x512 \
          --spacing 0.5:1.5
      for backend in ${CHECK_RUN_BACKENDS:-triton torch}; do
        run_item run_$backend "${CHECK_LIMIT_RUN:-150}" bash -c "train_run $backend"
        grep -h 'training run:\|skipped\|diverged\|Error' "$out/run_$backend.log" | cut -c1-400 | head -20 | sed 's/^/    /' >> "$summary"
      done ;;
    *) echo "unknown item $item (tests render stages model model_compiled train run)"; exit 2 ;;
  esac
done
# One archive of the logs beside the summary (fewer files to carry back from a device machine).
(cd "$out" && tar czf logs.tar.gz ./*.log && rm -f ./*.log)
echo; cat "$summary"
