#!/usr/bin/env bash
# Everything issue 24 asks of a CUDA machine, in one command, with one summary:
#   tests           the Triton kernels (fused projection, key binning, compositing) compiled on the GPU,
#                   against the reference, beside the reference's own tests (slow ones included);
#   render          rasterizer at 0.1 / 0.5 / 1.3 M Gaussians, 512x1024: reference, Triton, cubemap route;
#   stages          where the Triton path spends its time (projection, binning, compositing, backward);
#   gsplat          our pinhole renderer against gsplat (speed and agreement); gsplat's wheel is carried
#                   in $CHECK_WHEELS (default .whl: `python3 -m pip download --no-deps gsplat==1.5.3 -d .whl`);
#   model           the paper config end to end (network + one render), 1-4 views; model_compiled: the
#                   same through torch.compile;
#   train           one training step of each curriculum stage at 512x1024, batch 1, bf16 autocast;
#   run             a short training run of the paper config on procedural 256x512 data (loss must fall);
#   base            the `base` preset (configs/base.yaml) trained for at most CHECK_BASE_MINUTES (20) in all:
#                   the run folder ($CHECK_BASE_DIR, default outputs/gpu_check_base) is resumed by later calls.
# Usage: bash benchmarks/gpu_check.sh [--smoke] [--append] [OUT_DIR] [ITEMS]
#   ITEMS (default all): tests render stages gsplat model model_compiled train run base
#   --smoke: every item at tiny sizes on whatever machine this is (Triton's CPU interpreter without a
#   GPU; training runs use the reference renderer there; model_compiled is left out), to show that the
#   script works end to end; its numbers mean nothing.
#   --append: add to OUT_DIR/summary.md instead of starting it (one summary over several calls).
# All items take about 45 minutes on an H100, base 20 of them. Where one command may run 10 minutes
# (the device tool), keep OUT_DIR in the checkout (outputs/ survives between calls on a warm machine)
# and split, copying the summary out each time, e.g.
#   bash benchmarks/gpu_check.sh outputs/gpu_check "tests render stages"; cp outputs/gpu_check/* $OUT
#   bash benchmarks/gpu_check.sh --append outputs/gpu_check "gsplat model train"; cp outputs/gpu_check/* $OUT
#   bash benchmarks/gpu_check.sh --append outputs/gpu_check "model_compiled run"; cp ...
#   CHECK_BASE_MINUTES=9 bash benchmarks/gpu_check.sh --append outputs/gpu_check base   # then 18: resumes
# Each item runs under its own time limit (seconds: CHECK_LIMIT_<ITEM>); a failing item does not stop
# the others. Summary: OUT_DIR/summary.md; every item's full log: OUT_DIR/logs.tar.gz.
set -uo pipefail
cd "$(dirname "$0")/.."
smoke=0 append=0
while [ $# -gt 0 ]; do
  case $1 in --smoke) smoke=1; shift ;; --append) append=1; shift ;; *) break ;; esac
done
out=$(realpath -m "${1:-outputs/gpu_check}")
all_items="tests render stages gsplat model model_compiled train run base"
items=${2:-$all_items}
work=${CHECK_WORK:-/tmp/cylindersplat_gpu_check}  # synthetic data and the short run (not results)
base_dir=$(realpath -m "${CHECK_BASE_DIR:-outputs/gpu_check_base$([ $smoke = 1 ] && echo _smoke)}")  # kept: later calls resume it
rm -rf "$work"; mkdir -p "$out" "$work"
rm -f "$out"/*.log
export PYTHONPATH=$PWD/src${PYTHONPATH:+:$PYTHONPATH} PYTHONUNBUFFERED=1
py=${PYTHON:-python3}
summary=$out/summary.md

# Carried wheels (no package index on the GPU machines): installed aside, first on the path.
wheels=${CHECK_WHEELS:-.whl}
if compgen -G "$wheels/*.whl" > /dev/null; then
  $py -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/cylindersplat_site \
      "$wheels"/*.whl && export PYTHONPATH=/tmp/cylindersplat_site:$PYTHONPATH
fi

if [ $smoke = 1 ]; then
  device=$($py -c "import torch; print('cuda' if torch.cuda.is_available() else 'cpu')")
  [ "$device" = cpu ] && export TRITON_INTERPRET=1
else
  device=cuda
fi

if [ $append = 1 ] && [ -f "$summary" ]; then
  { echo; echo "---"; echo "(appended $(date -u '+%Y-%m-%d %H:%M') UTC, commit $(git rev-parse --short HEAD 2>/dev/null || echo unknown): $items)"; } >> "$summary"
else {
  echo "# GPU check — $(date -u +%Y-%m-%d)$([ $smoke = 1 ] && echo " — SMOKE RUN (tiny sizes on $device: the numbers mean nothing)")"
  echo
  echo '```'
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader 2>/dev/null || echo "no nvidia-smi"
  $py -c "import torch, triton; print('torch', torch.__version__, '| triton', triton.__version__, '|', torch.cuda.get_device_name() if torch.cuda.is_available() else 'no CUDA')"
  $py -c "import gsplat; print('gsplat', gsplat.__version__)" 2>/dev/null || echo "gsplat: not installed"
  echo "commit $(git rev-parse --short HEAD 2>/dev/null || echo unknown)"
  echo '```'
} > "$summary"
fi

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

excerpt() {  # lines of the logs matching a pattern, indented into the summary
  local pattern=$1; shift
  grep -h -- "$pattern" "$@" 2>/dev/null | cut -c1-600 | sed 's/^/    /' >> "$summary"
}

# Item sizes: full (the issue's) or smoke (seconds on a CPU).
if [ $smoke = 1 ]; then
  test_args=(-m "not slow" -x tests/test_render_triton_projection.py tests/test_render_binning.py)
  render_args=(--num 300 --height 8 --device "$device" --backend torch triton --repeats 1)
  stages_args=(--num 300 --height 8 --device "$device" --backend triton --stages --repeats 1)
  gsplat_args=(--num 300 --height 8 --device "$device" --backend torch triton --repeats 1)
  model_args=(--config tiny --height 64 --render --views 1 2 --repeats 1 --device "$device")
  train_args=(--config tiny --height 64 --steps 1 --warmup 0 --lpips off --device "$device")
  synth_args=(--scenes 4 --resolution 64x128)
  run_overrides=(model.preset=tiny data.resolution=[64,128] train.steps_per_stage=[12,6] train.log_every=1)
  base_scenes=4; base_resolution=64x128; rm -rf "$base_dir"  # a fresh run each time: chunks and resumes are exercised
  base_overrides=(model.preset=tiny data.resolution=[64,128] train.steps_per_stage=[4,2,4] train.log_every=1
                  train.checkpoint_every=2 data.num_workers=0)
  base_minutes=${CHECK_BASE_MINUTES:-3}; base_chunk=3; require_fall=
  # Training through the Triton interpreter takes minutes per step: on a CPU the run uses the reference.
  run_backends=$([ "$device" = cuda ] && echo "triton torch" || echo torch)
else
  test_args=(tests/test_render_triton.py tests/test_render_triton_projection.py tests/test_render_binning.py tests/test_triton_compile.py
             tests/test_render_cameras.py tests/test_render.py tests/test_render_projection.py)
  render_args=(--num 100000 500000 1300000 --height 512 --device cuda --backend torch triton --cubemap --repeats 5)
  stages_args=(--num 100000 1300000 --height 512 --device cuda --backend triton --stages --repeats 5 --profile)
  gsplat_args=(--num 100000 500000 1300000 --height 512 --device cuda --backend triton --repeats 5)
  model_args=(--config paper --height 512 --render --views 1 2 3 4 --repeats 5)
  train_args=(--config paper --height 512 --steps 5)
  synth_args=(--scenes 24 --resolution 256x512)
  run_overrides=(model.preset=paper data.resolution=[256,512] train.steps_per_stage=[120,40] train.log_every=10)
  base_scenes=100; base_resolution=256x512; base_overrides=()
  base_minutes=${CHECK_BASE_MINUTES:-20}; base_chunk=500; require_fall=--require-fall; run_backends="triton torch"
fi

train_run() {  # backend: a short training run on procedural data (loss must fall)
  $py -m cylindersplat train --config tiny --out "$work/run_$1" data.root="$work/synth" $run_overrides_words \
      train.stages=[1,3] train.lr=3e-4 train.render_backend=$1 train.image_every=0 train.progress=false loss.use_lpips=off &&
  $py benchmarks/train_run_summary.py "$work/run_$1/metrics.jsonl" $require_fall
}

base_train() {  # the base preset, in chunks of base_chunk steps, until finished or the time budget is spent
  local data=$base_dir/data run=$base_dir/run spent_file=$base_dir/seconds_spent
  mkdir -p "$base_dir"
  [ -f "$data/.complete" ] || { rm -rf "$data" && $py -m cylindersplat data synth --out "$data" --scenes $base_scenes \
      --resolution $base_resolution --spacing 0.5:1.5 && touch "$data/.complete"; } || return 1
  local spent=$(cat "$spent_file" 2>/dev/null || echo 0) budget=$((base_minutes * 60)) resume=() state
  [ -f "$run/metrics.jsonl" ] && resume=(--resume "$run")
  while :; do
    local left=$((budget - spent))
    if [ $left -le 0 ]; then echo "base: the ${base_minutes}-minute budget is spent (resume with a larger CHECK_BASE_MINUTES)"; break; fi
    local t0=$SECONDS
    # (overrides in one run: argparse takes the KEY=VALUE positionals only before the options)
    timeout --kill-after=10 $left $py -m cylindersplat train --config base --out "$run" data.root="$data" \
        $base_overrides_words --max-steps $base_chunk "${resume[@]}" > "$base_dir/call.log" 2>&1
    cat "$base_dir/call.log"
    state=$(grep '^training ' "$base_dir/call.log")
    spent=$((spent + SECONDS - t0)); echo $spent > "$spent_file"
    resume=(--resume "$run")
    case $state in
      "training finished"*) echo "base: finished in $spent s of training time"; break ;;
      "training stopped"*) ;;
      *) echo "base: the training call ended without a summary line (killed at the budget, or failed)"; break ;;
    esac
  done
  $py benchmarks/train_run_summary.py "$run/metrics.jsonl" $require_fall
}

# Arrays cannot be exported to the `bash -c` of run_item: the functions get them as words (none has a space).
run_overrides_words="${run_overrides[*]}" base_overrides_words="${base_overrides[*]-}"
export -f train_run base_train
export py work out smoke base_dir base_scenes base_resolution base_minutes base_chunk require_fall run_overrides_words base_overrides_words
for item in $items; do
  case $item in
    tests)
      run_item tests "${CHECK_LIMIT_TESTS:-600}" $py -m pytest -q -p no:cacheprovider "${test_args[@]}"
      tail -n 3 "$out/tests.log" | sed 's/^/    /' >> "$summary" ;;
    render)
      run_item render "${CHECK_LIMIT_RENDER:-300}" $py -m cylindersplat bench render "${render_args[@]}"
      excerpt '^[{#]' "$out/render.log" ;;
    stages)
      run_item stages "${CHECK_LIMIT_STAGES:-150}" $py -m cylindersplat bench render "${stages_args[@]}"
      excerpt '^[{#]' "$out/stages.log" ;;
    gsplat)
      run_item gsplat "${CHECK_LIMIT_GSPLAT:-600}" $py -m cylindersplat bench gsplat_compare "${gsplat_args[@]}"
      excerpt '^[{#]' "$out/gsplat.log" ;;
    model)
      run_item model "${CHECK_LIMIT_MODEL:-180}" $py -m cylindersplat bench model "${model_args[@]}"
      excerpt '^[|#(]' "$out/model.log" ;;
    model_compiled)
      if [ $smoke = 1 ]; then { echo; echo "## model_compiled — left out of the smoke run (torch.compile)"; } >> "$summary"; continue; fi
      run_item model_compiled "${CHECK_LIMIT_MODEL:-240}" $py -m cylindersplat bench model --config paper --height 512 \
          --render --views 2 3 4 --repeats 5 --warmup 2 --compile
      excerpt '^[|#(]' "$out/model_compiled.log" ;;
    train)
      run_item train "${CHECK_LIMIT_TRAIN:-180}" $py -m cylindersplat bench train "${train_args[@]}"
      excerpt '^[|#]' "$out/train.log" ;;
    run)
      run_item run_data 120 $py -m cylindersplat data synth --out "$work/synth" "${synth_args[@]}" --spacing 0.5:1.5
      for backend in ${CHECK_RUN_BACKENDS:-$run_backends}; do
        run_item run_$backend "${CHECK_LIMIT_RUN:-300}" bash -c "train_run $backend"
        excerpt 'training run\|skipped\|diverged\|Error' "$out/run_$backend.log"
      done ;;
    base)  # the budget is enforced inside (chunks + resume); the limit is a safety net
      run_item base "${CHECK_LIMIT_BASE:-$((base_minutes * 60 + 300))}" bash -c base_train
      excerpt 'training run\|^base:\|Error' "$out/base.log" ;;
    *) echo "unknown item $item ($all_items)"; exit 2 ;;
  esac
done
# One archive of the logs beside the summary (fewer files to carry back from a device machine).
archive=logs.tar.gz; [ $append = 1 ] && archive="logs_$(echo $items | tr ' ' '-').tar.gz"
(cd "$out" && tar czf "$archive" ./*.log && rm -f ./*.log)
echo; cat "$summary"
