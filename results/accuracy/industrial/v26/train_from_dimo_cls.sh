#!/usr/bin/env bash
# Issue 44, second stage: runs/from-dimo continued with the class logits weighted 10x more (its ids were wrong:
# 110 of 196 rows of objects the image does not hold). Resumable: run it again.
set -euo pipefail
cd /work/ind
out=runs/from-dimo-cls
resume=(); [ -f "$out/checkpoint.pt" ] && resume=(--resume)
bop-cender train --dataset bop --data-root bins_4451 --split train --val-split test --val-data-root /work/d44/bins \
  --variant dimo-context --factored-centers --init-weights runs/from-dimo/weights.pt \
  --center-loss focal --center-loss-weight 0.1 --class-loss-weight 1.0 --batch-size 8 --epochs 16 --lr 3e-4 --seed 2 \
  --out "$out" "${resume[@]}" --no-progress
