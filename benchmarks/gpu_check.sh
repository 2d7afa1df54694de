#!/usr/bin/env bash
# Everything issues 24 and 35 ask of a CUDA machine, in ONE run of at most 9 minutes (CHECK_TOTAL_SECONDS, 540),
# items in priority order (each also under its own limit, CHECK_LIMIT_<ITEM>; one that would start past the
# total budget is skipped, and says so in the summary):
#   tests           the GPU kernels only (Triton fused projection, key binning, compositing; sm_90 compile),
#                   against the reference - not the reference's slow CPU tests;
#   render          rasterizer at 0.1 / 0.5 / 1.3 M Gaussians, 512x1024: reference and Triton (a reference out of
#                   memory is a table cell, not a crash);
#   stages          where the Triton path spends its time (projection, binning, compositing, backward);
#   gsplat          our pinhole renderer against gsplat (speed and agreement; the Triton variants with their launch
#                   counts; then one forward of each
#                   under torch.profiler, host against device time); gsplat's wheel is carried in
#                   $CHECK_WHEELS (default .whl: `python3 -m pip download --no-deps gsplat==1.5.3 -d .whl`); its
#                   CUDA code (a JIT build of about 75 s) is built in the background while the tests run;
#   graphs          the Triton render replayed as CUDA graphs (render.graphs.RenderGraph: the host's work made once)
#                   beside the default and gsplat on the pinhole view, then on the panorama, then one forward of
#                   each under torch.profiler (a replay's time is the device's alone); its own processes, so that a
#                   capture that fails cannot take the gsplat item's figures with it;
#   model           the paper config end to end (network + one render), 1-4 views;
#   train           one training step of each curriculum stage at 512x1024, batch 1, bf16 autocast;
#   run             a short training run of the paper config on procedural 256x512 data (loss must fall).
# Not in the default run (name them): variants (the Triton backend's variants side by side, with stages and launch
# counts, at 0.1 and 1.3 M Gaussians, 512x1024: `bench render --variants ...`, about two minutes; then a profile of
# three of them at 1.3 M, kernel by kernel, and the stages of four on the pinhole view; `binning` is its older name),
# model_compiled (the model through torch.compile) and base (the `base`
# preset trained for at most CHECK_BASE_MINUTES (20) in all, resumed by later calls from $CHECK_BASE_DIR,
# default outputs/gpu_check_base; at its budget the trainer is interrupted cleanly - a checkpoint - and the
# item ends with the run's summary line).
# Usage: bash benchmarks/gpu_check.sh [--smoke] [--append] [OUT_DIR] [ITEMS]
#   ITEMS (default: tests render stages gsplat graphs model train run); also variants model_compiled base
#   --smoke: every item at tiny sizes on whatever machine this is (Triton's CPU interpreter without a
#   GPU; training runs use the reference renderer there; model_compiled is left out), to show that the
#   script works end to end; its numbers mean nothing.
#   --append: add to OUT_DIR/summary.md instead of starting it (one summary over several calls).
# Where one command may run 10 minutes (the device tool), the default run fits one call:
#   bash benchmarks/gpu_check.sh $OUT/gpu_check          # or outputs/gpu_check, then copy it out
#   CHECK_BASE_MINUTES=8 bash benchmarks/gpu_check.sh --append outputs/gpu_check base   # a later call
# A failing item does not stop the others. Summary: OUT_DIR/summary.md; every item's log: OUT_DIR/logs.tar.gz.
set -uo pipefail
cd "$(dirname "$0")/.."
smoke=0 append=0
while [ $# -gt 0 ]; do
  case $1 in --smoke) smoke=1; shift ;; --append) append=1; shift ;; *) break ;; esac
done
out=$(realpath -m "${1:-outputs/gpu_check}")
all_items="tests render stages variants gsplat graphs model model_compiled train run base"
items=${2:-tests render stages gsplat graphs model train run}
total=${CHECK_TOTAL_SECONDS:-540}
deadline=$((SECONDS + total))  # every item ends by then (the archive and summary take a few seconds more)
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

# The kernel tests compile a hundred-odd Triton specialisations on a fresh machine (1-3 s each, most of the item's
# time): with pytest-xdist carried (`python3 -m pip download --no-deps pytest-xdist execnet -d .whl`), they compile
# in CHECK_TEST_WORKERS (8) processes at once.
test_workers=()
if [ "${CHECK_TEST_WORKERS:-8}" -gt 1 ] && $py -c "import xdist" 2> /dev/null; then
  test_workers=(-n "${CHECK_TEST_WORKERS:-8}")
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

left_s() { echo $((deadline - SECONDS)); }

run_item() {  # name, limit, command... (the limit is cut to what is left of the total budget)
  local name=$1 limit=$2; shift 2
  local t0=$SECONDS left=$(left_s)
  if [ "$left" -lt 15 ]; then
    { echo; echo "## $name — skipped: the ${total}-second budget of this run is spent"; echo; } >> "$summary"
    echo "== $name: skipped (budget spent)"; return 0
  fi
  [ "$left" -lt "$limit" ] && limit=$left
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

run_excerpted() {  # name, limit, pattern, command...: run_item, then its log's lines matching the pattern (excerpt)
  local name=$1 limit=$2 pattern=$3; shift 3
  run_item "$name" "$limit" "$@"
  excerpt "$pattern" "$out/$name.log"
}

# Item sizes: full (the issue's) or smoke (seconds on a CPU).
# The default forward beside the lean one (no host sync before compositing: triton_backend.FORWARD), with pairs that
# carry their pixel rectangles (",rects": triton_backend.PAIR_FIELD; the default "ids" carries only the Gaussian), with
# the compositing loading only the next pair's Gaussian id ahead (",id": triton_backend.LOOKAHEAD; the default "row"
# loads its whole row while it composites one) - ",rects,id" was the default until 2026-11-27 (session 26) - and with
# the input checks as PyTorch operations (",torch": triton_backend.CHECK; the default "fused" is one kernel);
# --launches counts each variant's kernel launches per forward and backward. The binning and backward variants
# measured on 2026-11-26 (and removed since), the compaction of the visible pairs (",nonzero":
# triton_backend.COMPACTION) on 2026-11-27 (no faster, on panoramas or pinhole views): benchmarks/RESULTS.md.
variants="--launches --variants default default,rects default,id default,rects,id lean default,torch"
profile_variants="--variants default default,rects default,rects,id"
# Pinhole views beside gsplat (3.2 M pairs of 0.18 M visible Gaussians at 1.3 M, 512x1024: the pairs' bytes count
# there), with their launch counts.
gsplat_variants="--launches --variants default default,rects default,rects,id lean"
pinhole_variants="--variants default default,rects default,rects,id lean"
if [ $smoke = 1 ]; then
  test_args=(-m "not slow" -x tests/test_render_triton_projection.py tests/test_render_binning.py)
  render_args=(--num 300 --height 8 --device "$device" --backend torch triton --repeats 1)
  stages_args=(--num 300 --height 8 --device "$device" --backend triton --stages --repeats 1)
  variants_args=(--num 40 --height 8 --device "$device" --backend triton --stages --repeats 1 $variants)
  profile_args=(--num 40 --height 8 --device "$device" --backend triton --repeats 1 --profile $profile_variants)
  pinhole_args=(--num 40 --height 8 --device "$device" --backend triton --camera pinhole --stages --repeats 1
                $pinhole_variants)
  gsplat_args=(--num 300 --height 8 --device "$device" --backend torch triton --repeats 1 $gsplat_variants)
  gsplat_profile_args=(--num 300 --height 8 --device "$device" --backend triton --repeats 1 --profile)
  graphs_args=(--num 300 --height 8 --device "$device" --backend triton --repeats 1 --graph
               --variants default default,rects,id)
  graphs_render_args=(--num 300 --height 8 --device "$device" --backend triton --repeats 1 --graph
                      --variants default default,rects,id)
  graphs_profile_args=(--num 300 --height 8 --device "$device" --backend triton --repeats 1 --graph
                       --variants default --profile)
  model_args=(--config tiny_paper --height 64 --render --views 1 2 --repeats 1 --device "$device")
  train_args=(--config tiny_paper --height 64 --steps 1 --warmup 0 --lpips off --device "$device")
  synth_args=(--scenes 4 --resolution 64x128)
  run_overrides=(model.preset=tiny_paper data.resolution=[64,128] train.steps_per_stage=[12,6] train.log_every=1)
  base_scenes=4; base_resolution=64x128; rm -rf "$base_dir"  # a fresh run each time: chunks and resumes are exercised
  base_overrides=(model.preset=tiny_paper data.resolution=[64,128] train.steps_per_stage=[4,2,4] train.log_every=1
                  train.checkpoint_every=2 data.num_workers=0)
  base_minutes=${CHECK_BASE_MINUTES:-3}; base_chunk=3; require_fall=
  # Training through the Triton interpreter takes minutes per step: on a CPU the run uses the reference.
  run_backends=$([ "$device" = cuda ] && echo "triton torch" || echo torch)
else
  # The GPU kernels' tests only (slow-marked ones included: seconds on a GPU), not the reference's CPU tests.
  test_args=(tests/test_render_triton.py tests/test_render_triton_projection.py tests/test_render_binning.py
             tests/test_render_triton_sync.py tests/test_render_triton_lean.py tests/test_render_triton_ids.py
             tests/test_render_triton_lookahead.py tests/test_render_graphs.py
             tests/test_triton_compile.py
             tests/test_render_deferred_checks.py tests/test_render_triton_checks.py
             "tests/test_render_layered.py::test_blending_is_the_normalised_weighted_mean_of_the_front_surface")
  render_args=(--num 100000 500000 1300000 --height 512 --device cuda --backend torch triton --repeats 10)
  stages_args=(--num 100000 1300000 --height 512 --device cuda --backend triton --stages --repeats 3)
  variants_args=(--num 100000 1300000 --height 512 --device cuda --backend triton --stages --repeats 5 $variants)
  profile_args=(--num 1300000 --height 512 --device cuda --backend triton --repeats 1 --profile $profile_variants)
  pinhole_args=(--num 100000 1300000 --height 512 --device cuda --backend triton --camera pinhole --stages --repeats 5
                $pinhole_variants)
  # (10 repeats: a render takes milliseconds, and the median of 3 moved by 1-2 ms between calls, 2026-11-26/27)
  gsplat_args=(--num 100000 500000 1300000 --height 512 --device cuda --backend triton --repeats 10 $gsplat_variants)
  # One forward of ours (both forwards) and of gsplat under torch.profiler: host against device time (issue 35's
  # pinhole gap: is it our launches or our kernels?)
  gsplat_profile_args=(--num 100000 1300000 --height 512 --device cuda --backend triton --repeats 1 --profile
                       --variants default default,rects,id)
  # (each variant eager, then replayed as CUDA graphs: the ids and lookahead options timed without the host's noise)
  graphs_args=(--num 100000 500000 1300000 --height 512 --device cuda --backend triton --repeats 10 --graph
               --variants default default,rects,id)
  graphs_render_args=(--num 100000 1300000 --height 512 --device cuda --backend triton --repeats 10 --graph
                      --variants default default,rects,id)
  graphs_profile_args=(--num 100000 1300000 --height 512 --device cuda --backend triton --repeats 3 --graph
                       --variants default --profile)
  model_args=(--config paper --height 512 --render --views 1 2 3 4 --repeats 3)
  train_args=(--config paper --height 512 --steps 3)
  synth_args=(--scenes 12 --resolution 256x512)
  # Stage 3 logs 40 batches: with 10 (40 steps, every 4th) its verdict compared medians of two batches each and
  # said "did NOT fall" on 2026-11-27 (0.0305 -> 0.0480), which two batches' scenes can decide alone.
  run_overrides=(model.preset=paper data.resolution=[256,512] train.steps_per_stage=[160,80] train.log_every=2)
  base_scenes=100; base_resolution=256x512; base_overrides=()
  base_minutes=${CHECK_BASE_MINUTES:-20}; base_chunk=500; require_fall=--require-fall; run_backends=triton  # (CHECK_RUN_BACKENDS="triton torch": both)
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
  local spent=$(cat "$spent_file" 2>/dev/null || echo 0) budget=$((base_minutes * 60)) resume=() state rc
  local call_end=$((SECONDS + base_call_seconds))  # what this run's total budget leaves to this call
  [ -f "$run/metrics.jsonl" ] && resume=(--resume "$run")
  while :; do
    local left=$((budget - spent)) call_left=$((call_end - SECONDS))
    if [ $left -le 0 ]; then echo "base: the ${base_minutes}-minute budget is spent (resume with a larger CHECK_BASE_MINUTES)"; break; fi
    if [ $call_left -le 5 ]; then echo "base: this run's time is spent after $spent s of training (resume in a later call)"; break; fi
    [ $call_left -lt $left ] && left=$call_left
    local t0=$SECONDS
    # (overrides in one run: argparse takes the KEY=VALUE positionals only before the options)
    # At the budget: Ctrl-C (SIGINT), which the trainer answers with a checkpoint; killed only if that hangs.
    timeout --signal=INT --kill-after=60 $left $py -m cylindersplat train --config base --out "$run" data.root="$data" \
        $base_overrides_words --max-steps $base_chunk "${resume[@]}" > "$base_dir/call.log" 2>&1
    rc=$?
    cat "$base_dir/call.log"
    state=$(grep '^training ' "$base_dir/call.log")
    spent=$((spent + SECONDS - t0)); echo $spent > "$spent_file"
    resume=(--resume "$run")
    case $state in
      "training finished"*) echo "base: finished in $spent s of training time"; break ;;
      "training stopped"*) ;;
      *) if [ $rc -eq 124 ]; then
           echo "base: stopped at its time budget after $spent s of training ($(grep -o 'interrupted after step [0-9]*' \
                "$base_dir/call.log" || echo 'interrupted before its first step')); resume with a larger CHECK_BASE_MINUTES"
         else
           echo "base: the training call failed (exit $rc) - see above"
         fi
         break ;;
    esac
  done
  $py benchmarks/train_run_summary.py "$run/metrics.jsonl" $require_fall
}

# gsplat compiles its CUDA code at first use (about 75 s): build it in the background while the tests run.
gsplat_build=
if [[ " $items " == *" gsplat "* || " $items " == *" graphs "* ]] && $py -c "import gsplat" 2>/dev/null; then
  (timeout 400 $py -c "from gsplat.cuda._backend import _C; print('gsplat CUDA build:', 'ok' if _C is not None else 'unavailable')" \
     > "$out/gsplat_build.log" 2>&1) &
  gsplat_build=$!
fi

# Arrays cannot be exported to the `bash -c` of run_item: the functions get them as words (none has a space).
run_overrides_words="${run_overrides[*]}" base_overrides_words="${base_overrides[*]-}"
export -f train_run base_train
export py work out smoke base_dir base_call_seconds=0 base_scenes base_resolution base_minutes base_chunk require_fall run_overrides_words base_overrides_words
# Timings while gsplat compiles in the background share the host with 8-16 compiler processes (load 10-11 on
# 2026-11-27: the variants' forwards moved by up to 1.2 ms): every item but the tests waits for the build first.
await_gsplat_build() {
  [ -n "$gsplat_build" ] || return 0
  local t0=$SECONDS
  while kill -0 "$gsplat_build" 2>/dev/null && [ "$(left_s)" -gt 15 ]; do sleep 2; done
  [ $((SECONDS - t0)) -gt 0 ] && echo "(waited $((SECONDS - t0)) s for gsplat's CUDA build before timing $1)" >> "$summary"
  return 0
}
for item in $items; do
  [ "$item" = tests ] || await_gsplat_build "$item"
  case $item in
    tests)
      run_item tests "${CHECK_LIMIT_TESTS:-180}" $py -m pytest -q -p no:cacheprovider "${test_workers[@]}" \
          "${test_args[@]}"
      tail -n 3 "$out/tests.log" | sed 's/^/    /' >> "$summary" ;;
    render)
      run_excerpted render "${CHECK_LIMIT_RENDER:-120}" '^[{#|]' \
          $py -m cylindersplat bench render "${render_args[@]}" ;;
    stages)
      run_excerpted stages "${CHECK_LIMIT_STAGES:-60}" '^[{#]' $py -m cylindersplat bench render "${stages_args[@]}" ;;
    variants|binning)  # (binning: its name until the binning variants were removed)
      run_excerpted variants "${CHECK_LIMIT_VARIANTS:-150}" '^[{#|]' \
          $py -m cylindersplat bench render "${variants_args[@]}"
      # Where the time goes, kernel by kernel (torch.profiler, device time), panorama.
      run_excerpted variants_profile "${CHECK_LIMIT_VARIANTS_PROFILE:-75}" '^[#]\|Self CUDA\|Self CPU\|^ *[a-zA-Z_].*%' \
          $py -m cylindersplat bench render "${profile_args[@]}"
      # The same stages through gsplat's kind of camera (the 90-degree pinhole view of the gsplat item).
      run_excerpted variants_pinhole "${CHECK_LIMIT_VARIANTS_PINHOLE:-90}" '^[{#|]' \
          $py -m cylindersplat bench render "${pinhole_args[@]}" ;;
    gsplat)
      # (its background build was awaited above, within what is left of the budget)
      [ -n "$gsplat_build" ] && tail -n 1 "$out/gsplat_build.log" 2>/dev/null | sed 's/^/    /' >> "$summary"
      run_excerpted gsplat "${CHECK_LIMIT_GSPLAT:-120}" '^[{#|]' \
          $py -m cylindersplat bench gsplat_compare "${gsplat_args[@]}"
      run_excerpted gsplat_profile "${CHECK_LIMIT_GSPLAT_PROFILE:-60}" '^# profile\|^#  ' \
          $py -m cylindersplat bench gsplat_compare "${gsplat_profile_args[@]}" ;;
    graphs)
      run_excerpted graphs "${CHECK_LIMIT_GRAPHS:-90}" '^[{#|]' \
          $py -m cylindersplat bench gsplat_compare "${graphs_args[@]}"
      run_excerpted graphs_render "${CHECK_LIMIT_GRAPHS_RENDER:-60}" '^[{#|]' \
          $py -m cylindersplat bench render "${graphs_render_args[@]}"
      # One forward of each under torch.profiler: a graph's replay is the device's time alone, beside gsplat's.
      run_excerpted graphs_profile "${CHECK_LIMIT_GRAPHS_PROFILE:-45}" '^# profile\|^#  ' \
          $py -m cylindersplat bench gsplat_compare "${graphs_profile_args[@]}" ;;
    model)
      run_excerpted model "${CHECK_LIMIT_MODEL:-60}" '^[|#(]' $py -m cylindersplat bench model "${model_args[@]}" ;;
    model_compiled)
      if [ $smoke = 1 ]; then { echo; echo "## model_compiled — left out of the smoke run (torch.compile)"; } >> "$summary"; continue; fi
      run_excerpted model_compiled "${CHECK_LIMIT_MODEL:-240}" '^[|#(]' \
          $py -m cylindersplat bench model --config paper --height 512 --render --views 2 3 4 --repeats 5 --warmup 2 \
          --compile ;;
    train)
      run_excerpted train "${CHECK_LIMIT_TRAIN:-60}" '^[|#]' $py -m cylindersplat bench train "${train_args[@]}" ;;
    run)
      run_item run_data 60 $py -m cylindersplat data synth --out "$work/synth" "${synth_args[@]}" --spacing 0.5:1.5
      for backend in ${CHECK_RUN_BACKENDS:-$run_backends}; do
        run_excerpted run_$backend "${CHECK_LIMIT_RUN:-90}" 'training run\|skipped\|diverged\|Error' \
            bash -c "train_run $backend"
      done ;;
    base)  # the budget is enforced inside (chunks + resume, SIGINT at the end); the limit is a safety net
      base_call_seconds=$(( $(left_s) - 30 )); export base_call_seconds
      run_excerpted base "${CHECK_LIMIT_BASE:-$((base_minutes * 60 + 300))}" 'training run\|^base:\|Error' \
          bash -c base_train ;;
    *) echo "unknown item $item ($all_items)"; exit 2 ;;
  esac
done
# One archive of the logs beside the summary (fewer files to carry back from a device machine).
[ -n "$gsplat_build" ] && kill "$gsplat_build" 2>/dev/null  # not needed past the gsplat item
archive=logs.tar.gz; [ $append = 1 ] && archive="logs_$(echo $items | tr ' ' '-').tar.gz"
(cd "$out" && tar czf "$archive" ./*.log && rm -f ./*.log)
echo; cat "$summary"
