#!/usr/bin/env bash
# Reproduce the shipped DIMO weights (bop_cender/net/weights/dimo.pt, card dimo.json) from nothing:
# synthetic data, 14 epochs at lr 1e-3, 2 epochs of fine-tuning at 1e-4, the test figures, the card.
# On 2 CPU cores: about 20 min of synth, then about 85 min of training. Resumable: run it again.
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
for split in sim real; do
  bop-cender heatmaps --dataset dimo --split "$split" --data-root "$DATA/dimo_test" --weights "$RUN-ft/weights.pt" \
    --out "$RUN-ft/test_$split"
done
python scripts/ship_weights.py "$RUN-ft" --dataset dimo --pretrained-run "$RUN" \
  --command "scripts/train_shipped_dimo.sh" \
  --test "$RUN-ft/test_sim/heatmaps_dimo-sim.json" --test "$RUN-ft/test_real/heatmaps_dimo-real.json"
