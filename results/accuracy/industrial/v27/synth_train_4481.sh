#!/usr/bin/env bash
# Issue 44: a larger training split for the industrial network (150 bins x 4 captures x 4 cameras = 2,400 views).
# Resumable: run it again (synth skips finished scene folders).
set -euo pipefail
cd /work/ind
nice -n 19 bop-cender synth --layout industrial --out bins_train_4481 --scenes 1 --views 4 --train-scenes 150 \
  --seed 4481 --no-contact-sheets
