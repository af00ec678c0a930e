#!/usr/bin/env bash
# One prepared call per phase for a session lent a GPU (15 min of device time, at most 10 per command; the
# machine has torch with CUDA but not every dependency, and writes back only what lies under $OUT).
#
#   bash scripts/gpu_session.sh check   # CUDA tests, then scripts/bench_run.py and bench_net.py on cuda (~6 min)
#   bash scripts/gpu_session.sh train   # synth a small DIMO set, train the paper's variant on cuda, validate (~9 min)
#
# check: `pytest -m "cuda and not slow"` (the CUDA paths against the CPU's), the method benchmark on the embedded
#   demo (`--devices cuda --profile`: cost calls/s, the edge proxy in both layouts, seconds per scene) and the
#   network benchmark; the figures land in results/bench/*.md, bundled into $OUT/bench.tar.gz.
# train: the paper's DIMO network (`--variant dimo`, 32/32/64/64 channels, focal centre loss) on SCENES piles x
#   VARIANTS sim variants (seed 9021, the shipped network's second set), validated every epoch on 4 piles (seed
#   9003), for TRAIN_MINUTES; the checkpoint is atomic per epoch, so a killed run resumes (`--resume`) next time.
#   $OUT gets the run's weights, metrics.csv and validation figures (a tar.gz: $OUT returns few files).
#
# Environment: OUT (required on the device; default out/), DEVICE (cuda; cpu for a dry run here), SCENES (24),
# VARIANTS (16,17,18,19), TRAIN_MINUTES (5), BATCH (32), WORKERS (CPU count - 2), WHEELS (.whl: wheels of the
# dependencies the device lacks, installed with --no-deps into /tmp/site; fetch them here with
# `pip download --only-binary=:all: --python-version 3.12 --no-deps -d .whl trimesh==5.2.0 manifold3d==3.5.4 rtree==1.4.1`
# and carry .whl).
set -euo pipefail
mode=${1:-}
if [[ "$mode" != "check" && "$mode" != "train" ]]; then
  sed -n '2,22p' "$0" | sed 's/^# \{0,1\}//'
  [[ "$mode" == "-h" || "$mode" == "--help" ]] && exit 0
  echo "usage: bash scripts/gpu_session.sh check|train" >&2
  exit 2
fi
cd "$(dirname "$0")/.."
OUT=${OUT:-out}
DEVICE=${DEVICE:-cuda}
SCENES=${SCENES:-24}
VARIANTS=${VARIANTS:-16,17,18,19}
TRAIN_MINUTES=${TRAIN_MINUTES:-5}
BATCH=${BATCH:-32}
WORKERS=${WORKERS:-$(( $(nproc) > 3 ? $(nproc) - 2 : 1 ))}
WHEELS=${WHEELS:-.whl}
DATA=${DATA:-/tmp/gpu_session_data}
RUN=${RUN:-/tmp/gpu_session_run}
mkdir -p "$OUT"
log() { echo "[gpu_session $(date +%H:%M:%S)] $*" | tee -a "$OUT/session.log"; }

# Dependencies: the package from this checkout; the wheels the device lacks, without touching its torch.
if ! python3 -c "import trimesh, manifold3d, rtree" 2>/dev/null; then
  if compgen -G "$WHEELS/*.whl" > /dev/null; then
    python3 -m pip install -q --no-deps --target /tmp/site "$WHEELS"/*.whl
    export PYTHONPATH="/tmp/site:${PYTHONPATH:-}"
  else
    log "trimesh/manifold3d/rtree missing and no wheels in $WHEELS: see the header"
    exit 2
  fi
fi
export PYTHONPATH="$PWD:${PYTHONPATH:-}"
cli() { python3 -m bop_cender.cli "$@"; }
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(),
            torch.cuda.get_device_name(0) if torch.cuda.is_available() else '')" | tee -a "$OUT/session.log"
if [[ "$DEVICE" == "cuda" ]] && ! python3 -c "import torch, sys; sys.exit(not torch.cuda.is_available())"; then
  log "DEVICE=cuda but torch sees no CUDA device"
  exit 2
fi

if [[ "$mode" == "check" ]]; then
  log "CUDA tests"
  timeout 240 python3 -m pytest -q -m "cuda and not slow" tests -p no:cacheprovider 2>&1 | tail -25 \
    | tee "$OUT/cuda_tests.txt" || true
  log "method benchmark"
  timeout 240 python3 scripts/bench_run.py --devices "$DEVICE" --profile --scenes 3 --seconds 2 2>&1 | tail -40 \
    | tee "$OUT/bench_run.txt" || true
  log "network benchmark"
  timeout 120 python3 scripts/bench_net.py --devices "$DEVICE" 2>&1 | tail -20 | tee "$OUT/bench_net.txt" || true
  # one bundle: $OUT returns only a few files
  tar czf "$OUT/bench.tar.gz" results/bench/*.md 2>/dev/null || true
  log "done"
  exit 0
fi

log "synth: $SCENES piles x variants $VARIANTS (train), 4 piles (validation), $WORKERS workers"
cli synth --layout dimo --out "$DATA/dimo_train" --scenes "$SCENES" --variants "$VARIANTS" --seed 9021 \
  --workers "$WORKERS" --no-contact-sheets | tail -2
cli synth --layout dimo --out "$DATA/dimo_val" --scenes 4 --variants 0 --seed 9003 --workers "$WORKERS" \
  --no-contact-sheets | tail -2
resume=()
[[ -f "$RUN/checkpoint.pt" ]] && resume=(--resume)
log "train for $TRAIN_MINUTES min on $DEVICE (batch $BATCH)"
# Many epochs asked for: the time limit ends the run; every finished epoch is checkpointed and validated.
timeout "$(( TRAIN_MINUTES * 60 ))" python3 -m bop_cender.cli train --dataset dimo --data-root "$DATA/dimo_train" \
  --split train --val-split sim --val-data-root "$DATA/dimo_val" --variant dimo --center-loss focal \
  --center-loss-weight 0.1 --batch-size "$BATCH" --epochs 200 --lr 1e-3 --seed 11 --device "$DEVICE" \
  --no-progress --out "$RUN" "${resume[@]}" 2>&1 | tail -30 | tee -a "$OUT/session.log" || true
if [[ -f "$RUN/weights.pt" ]]; then
  log "validation heatmaps of the last epoch"
  cli heatmaps --dataset dimo --split sim --data-root "$DATA/dimo_val" --weights "$RUN/weights.pt" \
    --device "$DEVICE" --out "$RUN/val_sim" | tail -12 | tee -a "$OUT/session.log"
fi
tar czf "$OUT/train_run.tar.gz" --exclude=checkpoint.pt -C "$(dirname "$RUN")" "$(basename "$RUN")" 2>/dev/null || true
log "done"
