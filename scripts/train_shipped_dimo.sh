#!/usr/bin/env bash
# Reproduce the shipped DIMO weights (bop_cender/net/weights/dimo.pt, card dimo.json) from nothing:
# synthetic data; the lean network (dimo-lean: 14 epochs at lr 1e-3, 2 at 1e-4); then the dimo-context
# variant started from it, with the focal centre loss (20 epochs at 1e-3, 2 at 1e-4); then the same network on a
# second training set of 60 piles that holds every part type (4 epochs at 1e-3, 2 at 1e-4: the first set's 16 piles
# hold no shaft and one pile of brackets); the test figures, the card, the curvature calibration.
# On 2 CPU cores: about 26 min of synth, then about 85 + 100 + 14 min of training (one torch thread, 4-7 min per
# epoch of the context variant; 2.3 min per epoch of the last stage with both cores idle). Resumable: run it again.
set -euo pipefail
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
resume=()
[ -f "$RUN/checkpoint.pt" ] && resume=(--resume)
bop-cender train "${common[@]}" --epochs 14 --lr 1e-3 --seed 1 --out "$RUN" "${resume[@]}"
resume=()
[ -f "$RUN-ft/checkpoint.pt" ] && resume=(--resume)
bop-cender train "${common[@]}" --epochs 2 --lr 1e-4 --seed 2 --init-weights "$RUN/weights.pt" --out "$RUN-ft" "${resume[@]}"
# The context variant: residual dilated convolutions after the lean bottleneck (identity at the start, so the
# lean weights start it), the CenterNet focal loss on the centre head (weight 0.1).
context=(--dataset dimo --data-root "$DATA/dimo_train" --split train --val-split sim --val-data-root "$DATA/dimo_val"
         --variant dimo-context --batch-size 8 --center-loss focal --center-loss-weight 0.1)
resume=()
[ -f "$RUN-context/checkpoint.pt" ] && resume=(--resume)
bop-cender train "${context[@]}" --epochs 20 --lr 1e-3 --seed 3 --init-weights "$RUN-ft/weights.pt" --out "$RUN-context" "${resume[@]}"
resume=()
[ -f "$RUN-context-ft/checkpoint.pt" ] && resume=(--resume)
bop-cender train "${context[@]}" --epochs 2 --lr 1e-4 --seed 4 --init-weights "$RUN-context/weights.pt" \
  --out "$RUN-context-ft" "${resume[@]}"
# Every part type: 60 piles (seed 9021), sim variants 16-23 (3,360 views), from the weights above.
bop-cender synth --layout dimo --out "$DATA/dimo_train60" --scenes 60 --variants 16,17,18,19,20,21,22,23 --seed 9021 \
  --workers 2 --no-contact-sheets
all6=(--dataset dimo --data-root "$DATA/dimo_train60" --split train --val-split sim --val-data-root "$DATA/dimo_val"
      --variant dimo-context --batch-size 8 --center-loss focal --center-loss-weight 0.1)
resume=()
[ -f "$RUN-all6/checkpoint.pt" ] && resume=(--resume)
bop-cender train "${all6[@]}" --epochs 4 --lr 1e-3 --seed 5 --init-weights "$RUN-context-ft/weights.pt" --out "$RUN-all6" "${resume[@]}"
resume=()
[ -f "$RUN-all6-ft/checkpoint.pt" ] && resume=(--resume)
bop-cender train "${all6[@]}" --epochs 2 --lr 1e-4 --seed 6 --init-weights "$RUN-all6/weights.pt" --out "$RUN-all6-ft" "${resume[@]}"
for split in sim real; do
  bop-cender heatmaps --dataset dimo --split "$split" --data-root "$DATA/dimo_test" --weights "$RUN-all6-ft/weights.pt" \
    --out "$RUN-all6-ft/test_$split"
done
python scripts/ship_weights.py "$RUN-all6-ft" --dataset dimo --pretrained-run "$RUN" --pretrained-run "$RUN-ft" \
  --pretrained-run "$RUN-context" --pretrained-run "$RUN-context-ft" --pretrained-run "$RUN-all6" \
  --command "scripts/train_shipped_dimo.sh" \
  --data-note "train: bop-cender synth --layout dimo --out data/dimo_train --scenes 16 --variants 16,...,45 --seed 9001 --workers 2 --no-contact-sheets (split train: paper selection, 3,360 views)" \
  --data-note "val: bop-cender synth --layout dimo --out data/dimo_val --scenes 4 --variants 0 --seed 9003 --workers 2 --no-contact-sheets (split sim, 28 views)" \
  --data-note "test: bop-cender synth --layout dimo --out data/dimo_test --scenes 12 --variants 0 --seed 9002 --workers 2 (splits sim and real, 84 views each)" \
  --data-note "train (last stage): bop-cender synth --layout dimo --out data/dimo_train60 --scenes 60 --variants 16,...,23 --seed 9021 --workers 2 --no-contact-sheets (split train: 3,360 views; every part type)" \
  --test "$RUN-all6-ft/test_sim/heatmaps_dimo-sim.json" --test "$RUN-all6-ft/test_real/heatmaps_dimo-real.json"
# Where stage 3 binarises the network's curvature: the best-F1 threshold on the validation views.
python scripts/calibrate_curvature.py bop_cender/net/weights/dimo.pt --dataset dimo --data-root "$DATA/dimo_val" --split sim
# ... and on the real camera's validation views, for runs on the real split (its best binarisation is lower).
python scripts/calibrate_curvature.py bop_cender/net/weights/dimo.pt --dataset dimo --data-root "$DATA/dimo_val" --split real \
  --for-split real
