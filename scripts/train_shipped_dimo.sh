#!/usr/bin/env bash
# Reproduce the shipped DIMO weights (bop_cender/net/weights/dimo.pt) from nothing: synthetic data, then training.
# On 2 CPU cores: about 17 min of synth, then the training time the card states. Resumable: run it again.
set -euo pipefail
DATA=${DATA:-data}
RUN=${RUN:-runs/dimo-shipped}
EPOCHS=${EPOCHS:-8}
variants=$(python -c "print(','.join(str(v) for v in range(16, 46)))")
# Training set: sim variants 16-45 of 16 scenes (seed 9001); validation: sim variant 0 of 4 other scenes (seed 9003);
# test (not used here): sim variant 0 and real of 12 more scenes (seed 9002). One DIMO catalogue for all three.
bop-cender synth --layout dimo --out "$DATA/dimo_train" --scenes 16 --variants "$variants" --seed 9001 --workers 2 --no-contact-sheets
bop-cender synth --layout dimo --out "$DATA/dimo_val" --scenes 4 --variants 0 --seed 9003 --workers 2 --no-contact-sheets
bop-cender synth --layout dimo --out "$DATA/dimo_test" --scenes 12 --variants 0 --seed 9002 --workers 2
resume=()
[ -f "$RUN/checkpoint.pt" ] && resume=(--resume)
bop-cender train --dataset dimo --data-root "$DATA/dimo_train" --split train --val-split sim \
  --val-data-root "$DATA/dimo_val" --variant dimo-lean --epochs "$EPOCHS" --batch-size 8 --lr 1e-3 --seed 1 \
  --out "$RUN" "${resume[@]}"
