#!/usr/bin/env bash
# Issue 42, the input-normalisation lever measured alone: two fine-tunings of the shipped DIMO network on the same new
# pile of the randomised look, one with `--input-norm channel` (each image's colour channels standardised before the
# first layer) and one without (the control: the same data, epochs and seeds), then both through the robustness
# benchmark (own, sensor and pyrender looks of an unseen set). Resumable: run it again. On 2 CPU cores with one
# torch thread: about 30 min of synth, 2 x 20 min of training, 30 min of benchmark.
# Usage: DATA=/work/lever TEST=/work/rob/dimo_60601 bash scripts/train_lever_norm.sh
set -euo pipefail
DATA=${DATA:-data}
RUN=${RUN:-runs/lever-norm}
TEST=${TEST:?the unseen test set in its own look (bop-cender synth --layout dimo --scenes 4 --seed 60601)}
train_stage() {
  local out=$1 resume=()
  shift
  [ -f "$out/checkpoint.pt" ] && resume=(--resume)
  bop-cender train "$@" --out "$out" "${resume[@]}" --no-progress
}
bop-cender synth --layout dimo --out "$DATA/dimo_train_dr2" --scenes 40 --variants 16,17,18,19,20,21,22,23 --seed 9041 \
  --appearance randomised --workers 1 --no-contact-sheets
bop-cender synth --layout dimo --out "$DATA/dimo_val" --scenes 4 --variants 0 --seed 9003 --workers 1 --no-contact-sheets
common=(--dataset dimo --data-root "$DATA/dimo_train_dr2" --split train --val-split sim --val-data-root "$DATA/dimo_val"
        --variant dimo-context --batch-size 8 --center-loss focal --center-loss-weight 0.1)
for norm in channel none; do
  train_stage "$RUN-$norm" "${common[@]}" --input-norm "$norm" --epochs 4 --lr 3e-4 --seed 42 \
    --init-weights bop_cender/net/weights/dimo.pt
  train_stage "$RUN-$norm-ft" "${common[@]}" --input-norm "$norm" --epochs 1 --lr 1e-4 --seed 43 \
    --init-weights "$RUN-$norm/weights.pt"
done
for norm in channel none; do
  python scripts/robustness.py --dataset dimo --data-root "$TEST" --looks own,sensor,pyrender \
    --weights "$RUN-$norm-ft/weights.pt" --out "$RUN-$norm-ft/robustness" --workers 1
done
