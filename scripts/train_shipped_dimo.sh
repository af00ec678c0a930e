#!/usr/bin/env bash
# Reproduce the shipped DIMO weights (bop_cender/net/weights/dimo.pt, card dimo.json) from nothing:
# synthetic data; the lean network (dimo-lean: 14 epochs at lr 1e-3, 2 at 1e-4); then the dimo-context
# variant started from it, with the focal centre loss (20 epochs at 1e-3, 2 at 1e-4); then the same network on a
# second training set of 60 piles that holds every part type (4 epochs at 1e-3, 2 at 1e-4: the first set's 16 piles
# hold no shaft and one pile of brackets); then the same network on 60 piles of the randomised look (`synth
# --appearance randomised`: 4 epochs at 1e-3, 2 at 1e-4; on images of another renderer AR_MSSD<5% 0.660 -> 0.773,
# see results/net/dimo.md); the test figures, the card, the curvature calibration.
# On 2 CPU cores: about 26 + 13 min of synth, then about 85 + 100 + 14 + 22 min of training (one torch thread, 4-7
# min per epoch of the context variant; 2.3-3.6 min per epoch of the last stages with both cores idle). Resumable:
# run it again.
set -euo pipefail
# One training stage into RUN_DIR, resumed where a checkpoint is there: train_stage RUN_DIR TRAIN_ARGS...
train_stage() {
  local out=$1 resume=()
  shift
  [ -f "$out/checkpoint.pt" ] && resume=(--resume)
  bop-cender train "$@" --out "$out" "${resume[@]}"
}
DATA=${DATA:-data}
RUN=${RUN:-runs/dimo-shipped}
variants=$(python -c "print(','.join(str(v) for v in range(16, 46)))")
# Training set: sim variants 16-45 of 16 scenes (seed 9001); validation: sim variant 0 of 4 other scenes (seed 9003);
# test: sim variant 0 and real of 12 more scenes (seed 9002). One DIMO catalogue for all three.
bop-cender synth --layout dimo --out "$DATA/dimo_train" --scenes 16 --variants "$variants" --seed 9001 --workers 2 --no-contact-sheets
bop-cender synth --layout dimo --out "$DATA/dimo_val" --scenes 4 --variants 0 --seed 9003 --workers 2 --no-contact-sheets
bop-cender synth --layout dimo --out "$DATA/dimo_test" --scenes 12 --variants 0 --seed 9002 --workers 2
common=(--dataset dimo --data-root "$DATA/dimo_train" --split train --val-split sim --val-data-root "$DATA/dimo_val"
        --variant dimo-lean --batch-size 8)
train_stage "$RUN" "${common[@]}" --epochs 14 --lr 1e-3 --seed 1
train_stage "$RUN-ft" "${common[@]}" --epochs 2 --lr 1e-4 --seed 2 --init-weights "$RUN/weights.pt"
# The context variant: residual dilated convolutions after the lean bottleneck (identity at the start, so the
# lean weights start it), the CenterNet focal loss on the centre head (weight 0.1).
context=(--dataset dimo --data-root "$DATA/dimo_train" --split train --val-split sim --val-data-root "$DATA/dimo_val"
         --variant dimo-context --batch-size 8 --center-loss focal --center-loss-weight 0.1)
train_stage "$RUN-context" "${context[@]}" --epochs 20 --lr 1e-3 --seed 3 --init-weights "$RUN-ft/weights.pt"
train_stage "$RUN-context-ft" "${context[@]}" --epochs 2 --lr 1e-4 --seed 4 --init-weights "$RUN-context/weights.pt"
# Every part type: 60 piles (seed 9021), sim variants 16-23 (3,360 views), from the weights above.
bop-cender synth --layout dimo --out "$DATA/dimo_train60" --scenes 60 --variants 16,17,18,19,20,21,22,23 --seed 9021 \
  --workers 2 --no-contact-sheets
all6=(--dataset dimo --data-root "$DATA/dimo_train60" --split train --val-split sim --val-data-root "$DATA/dimo_val"
      --variant dimo-context --batch-size 8 --center-loss focal --center-loss-weight 0.1)
train_stage "$RUN-all6" "${all6[@]}" --epochs 4 --lr 1e-3 --seed 5 --init-weights "$RUN-context-ft/weights.pt"
train_stage "$RUN-all6-ft" "${all6[@]}" --epochs 2 --lr 1e-4 --seed 6 --init-weights "$RUN-all6/weights.pt"
# Domain randomisation: 60 piles (seed 9031) of the randomised look (metal, lights, environment, carrier, background,
# exposure and sensor drawn wide), sim variants 16-23 (3,360 views), from the weights above.
bop-cender synth --layout dimo --out "$DATA/dimo_train_dr" --scenes 60 --variants 16,17,18,19,20,21,22,23 --seed 9031 \
  --appearance randomised --workers 2 --no-contact-sheets
dr=(--dataset dimo --data-root "$DATA/dimo_train_dr" --split train --val-split sim --val-data-root "$DATA/dimo_val"
    --variant dimo-context --batch-size 8 --center-loss focal --center-loss-weight 0.1)
train_stage "$RUN-dr" "${dr[@]}" --epochs 4 --lr 1e-3 --seed 10 --init-weights "$RUN-all6-ft/weights.pt"
train_stage "$RUN-dr-ft" "${dr[@]}" --epochs 2 --lr 1e-4 --seed 11 --init-weights "$RUN-dr/weights.pt"
# The test figures: seed 9002's sim and real views, and its sim views rendered again by pyrender (another renderer).
[ -d "$DATA/dimo_test_pyrender" ] || python scripts/rerender_pyrender.py "$DATA/dimo_test" "$DATA/dimo_test_pyrender" --split sim
for split in sim real; do
  bop-cender heatmaps --dataset dimo --split "$split" --data-root "$DATA/dimo_test" --weights "$RUN-dr-ft/weights.pt" \
    --out "$RUN-dr-ft/test_$split"
done
bop-cender heatmaps --dataset dimo --split sim --data-root "$DATA/dimo_test_pyrender" --weights "$RUN-dr-ft/weights.pt" \
  --out "$RUN-dr-ft/test_pyr"
python scripts/ship_weights.py "$RUN-dr-ft" --dataset dimo --pretrained-run "$RUN" --pretrained-run "$RUN-ft" \
  --pretrained-run "$RUN-context" --pretrained-run "$RUN-context-ft" --pretrained-run "$RUN-all6" \
  --pretrained-run "$RUN-all6-ft" --pretrained-run "$RUN-dr" --command "scripts/train_shipped_dimo.sh" \
  --data-note "train: bop-cender synth --layout dimo --out data/dimo_train --scenes 16 --variants 16,...,45 --seed 9001 --workers 2 --no-contact-sheets (split train: paper selection, 3,360 views)" \
  --data-note "val: bop-cender synth --layout dimo --out data/dimo_val --scenes 4 --variants 0 --seed 9003 --workers 2 --no-contact-sheets (split sim, 28 views)" \
  --data-note "test: bop-cender synth --layout dimo --out data/dimo_test --scenes 12 --variants 0 --seed 9002 --workers 2 (splits sim and real, 84 views each)" \
  --data-note "train (fifth stage): bop-cender synth --layout dimo --out data/dimo_train60 --scenes 60 --variants 16,...,23 --seed 9021 --workers 2 --no-contact-sheets (split train: 3,360 views; every part type)" \
  --data-note "train (last stage, domain randomisation): bop-cender synth --layout dimo --out data/dimo_train_dr --scenes 60 --variants 16,...,23 --seed 9031 --appearance randomised --workers 2 --no-contact-sheets (split train: 3,360 views of the randomised look)" \
  --data-note "test (another renderer): python scripts/rerender_pyrender.py data/dimo_test data/dimo_test_pyrender --split sim (split sim, 84 views)" \
  --test "$RUN-dr-ft/test_sim/heatmaps_dimo-sim.json" --test "$RUN-dr-ft/test_real/heatmaps_dimo-real.json" \
  --test "$RUN-dr-ft/test_pyr/heatmaps_dimo-sim.json"
# Where stage 3 binarises the network's curvature: the best-F1 threshold on the validation views.
python scripts/calibrate_curvature.py bop_cender/net/weights/dimo.pt --dataset dimo --data-root "$DATA/dimo_val" --split sim
# ... and on the real camera's validation views, for runs on the real split (its best binarisation is lower).
python scripts/calibrate_curvature.py bop_cender/net/weights/dimo.pt --dataset dimo --data-root "$DATA/dimo_val" --split real \
  --for-split real
