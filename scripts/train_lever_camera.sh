#!/usr/bin/env bash
# Issue 42, the camera-augmentation lever measured alone: the shipped DIMO network fine-tuned on the same new pile of
# the randomised look as the input-normalisation lever's control (results/robustness/README.md, v2), with the same
# epochs, learning rates and seeds, plus `--camera-augment` (bop_cender/net/camera_augment.py: colour cast, tone
# curve, defocus, resolution loss, signal-dependent noise, grey). The control is that v2 run (RUN_CONTROL, made by
# commit 95c6b39's scripts/train_lever_norm.sh with --input-norm none, which is the default network).
# Then the three networks (shipped, control, lever) through the stage-1 measure on the looks of an unseen set.
# Resumable: run it again. On 2 CPU cores shared with other jobs: 62 min of training (5 epochs), 3 x 5 min of
# heatmap figures, 3 x 6 x 2 min of pose runs (2026-12-08; results/robustness/README.md, v4).
# Usage: DATA=/work/lever TEST=/work/rob/dimo_60631 RUN_CONTROL=/work/lever/runs/lever-norm-none-ft \
#   bash scripts/train_lever_camera.sh
set -euo pipefail
DATA=${DATA:-data}
RUN=${RUN:-runs/lever-camera}
TEST=${TEST:?the unseen test set in its own look (bop-cender synth --layout dimo --scenes 20 --variants 0 --seed 60631)}
RUN_CONTROL=${RUN_CONTROL:?the control run (the v2 fine-tuning without the lever)}
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
        --variant dimo-context --batch-size 8 --center-loss focal --center-loss-weight 0.1 --camera-augment)
train_stage "$RUN" "${common[@]}" --epochs 4 --lr 3e-4 --seed 42 --init-weights bop_cender/net/weights/dimo.pt
train_stage "$RUN-ft" "${common[@]}" --epochs 1 --lr 1e-4 --seed 43 --init-weights "$RUN/weights.pt"
# Stage 1 alone (centre F1, curvature AP per look; the looks' copies are made once beside TEST).
for net in "shipped:bop_cender/net/weights/dimo.pt" "control:$RUN_CONTROL/weights.pt" "camera:$RUN-ft/weights.pt"; do
  python scripts/robustness.py --dataset dimo --data-root "$TEST" --measure heatmaps --looks own,sensor,pyrender \
    --weights "${net#*:}" --out "$RUN-ft/robustness-heatmaps/${net%%:*}"
done
# End to end (AR_MSSD<5% per look; the looks' copies above are reused).
for net in "shipped:bop_cender/net/weights/dimo.pt" "control:$RUN_CONTROL/weights.pt" "camera:$RUN-ft/weights.pt"; do
  python scripts/robustness.py --dataset dimo --data-root "$TEST" --splits sim,real --looks own,sensor,pyrender \
    --weights "${net#*:}" --out "$RUN-ft/robustness-pose/${net%%:*}" --workers 2
done
