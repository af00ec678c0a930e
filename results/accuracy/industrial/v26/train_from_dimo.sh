#!/usr/bin/env bash
# Issue 44: the industrial network fine-tuned from the shipped DIMO network (its shared centre channel widened to a
# factored head of one channel per part). Resumable: run it again.
set -euo pipefail
cd /work/ind
out=runs/from-dimo
resume=(); [ -f "$out/checkpoint.pt" ] && resume=(--resume)
bop-cender train --dataset bop --data-root bins_4451 --split train --val-split test --val-data-root /work/d44/bins \
  --variant dimo-context --factored-centers --init-weights /work/main/bop_cender/net/weights/dimo.pt \
  --center-loss focal --center-loss-weight 0.1 --batch-size 8 --epochs 16 --lr 3e-4 --seed 1 \
  --out "$out" "${resume[@]}" --no-progress
