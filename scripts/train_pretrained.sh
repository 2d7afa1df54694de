#!/usr/bin/env bash
# Train the shipped weights (src/cylindersplat/weights/tiny_synth.safetensors): the tiny model on 96
# procedural scenes of the occlusion profile at 64x128, seed 1 (the demo's scenes use seed 0, so its
# held-out scenes stay unseen), 2000 steps of the 3-stage curriculum, with issue 23's recipe for the volume branch
# (nearest-observed-surface colour, the released stage-3 volume loss, pixel clearing, photometrically rescaled
# depth priors, an 8x32x16 triplane grid; benchmarks/RESULTS.md, "Volume branch, second attempt"); ~60 min on
# 2 CPU cores.
#   bash scripts/train_pretrained.sh [OUT]          (default outputs/pretrained)
set -euo pipefail
cd "$(dirname "$0")/.."
. scripts/_python.sh
choose_python  # the Python the set-up scripts installed into (.venv where the system Python refuses installs)
cylindersplat() { "$PYTHON" -m cylindersplat "$@"; }
OUT=${1:-outputs/pretrained}
export OMP_NUM_THREADS=${OMP_NUM_THREADS:-2}
cylindersplat data synth --out "$OUT/data" --scenes 96 --resolution 64x128 --profile occlusion --seed 1
cylindersplat train --config tiny --data "$OUT/data" --out "$OUT/run" --overwrite \
  train.stages=[1,2,3] train.steps_per_stage=[1200,400,400] train.lr=2e-3 train.warmup_steps=20 \
  train.checkpoint_every=200 train.image_every=0 train.tensorboard=false train.log_every=50 \
  model.volume.color=surface loss.volume_loss=released loss.volume_weight=1 model.fusion.pixel_clearing=seen_through \
  model.prior_alignment=photometric 'model.volume.grid=[8,32,16]' 'model.volume.image_grid=[4,16,8]'
cp "$OUT/run/model.safetensors" src/cylindersplat/weights/tiny_synth.safetensors
echo "shipped weights updated: src/cylindersplat/weights/tiny_synth.safetensors (log: $OUT/run/metrics.jsonl)"
