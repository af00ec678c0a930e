#!/usr/bin/env bash
# Issue 44, next: the industrial network on 2,400 training views (bins_train_4481, made by synth_train_4481.sh),
# continued from runs/from-dimo-cls (started from the shipped DIMO network). Resumable: run it again.
set -euo pipefail
cd /work/ind
./synth_train_4481.sh   # resumes; returns at once when the split is complete
out=runs/big-4481
resume=(); [ -f "$out/checkpoint.pt" ] && resume=(--resume)
bop-cender train --dataset bop --data-root bins_train_4481 --split train --val-split test --val-data-root /work/d44/bins \
  --variant dimo-context --factored-centers --init-weights runs/from-dimo-cls/weights.pt \
  --center-loss focal --center-loss-weight 0.1 --class-loss-weight 1.0 --batch-size 8 --epochs 30 --lr 3e-4 --seed 3 \
  --out "$out" "${resume[@]}" --no-progress
