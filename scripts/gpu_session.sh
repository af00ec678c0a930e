#!/usr/bin/env bash
# One prepared call per phase for a session lent a GPU (15 min of device time, at most 10 per command; the
# machine has torch with CUDA but not every dependency, and writes back only what lies under $OUT).
#
#   bash scripts/gpu_session.sh check   # CUDA tests, then scripts/bench_run.py and bench_net.py on cuda (<= 8.7 min)
#   bash scripts/gpu_session.sh train   # synth a small DIMO set, train the paper's variant on cuda, validate (~9 min)
#
# check: `pytest -m "cuda and not slow"` (the CUDA paths against the CPU's), the method benchmark on the embedded
#   demo (`--devices cuda --profile`: cost calls/s, the edge proxy in both layouts, a scene with stage 3 on cuda),
#   seconds per scene as `run` uses the host (heatmaps on cuda, stage 3 on every CPU core) and the network
#   benchmark; each stage's full output in $OUT/*.txt, results/bench/*.md bundled into $OUT/bench.tar.gz.
# train: the paper's DIMO network (`--variant dimo`, 32/32/64/64 channels, focal centre loss) on SCENES piles x
#   VARIANTS sim variants (seed 9021, the shipped network's second set), validated every epoch on 4 piles (seed
#   9003), for TRAIN_MINUTES; every finished epoch is checkpointed, and $OUT/train_run.tar.gz holds the run
#   (weights, checkpoint, metrics.csv, validation figures): carry it back and set RESUME_BUNDLE to it to go on.
#
# Environment: OUT (default out/), DEVICE (cuda; cpu for a dry run), SCENES (24), VARIANTS (16,17,18,19),
# TRAIN_MINUTES (5), BATCH (32), VOTES (0; 1: the network with centre votes, --center-votes, bop_cender/net/votes.py),
# WORKERS (CPU count - 2), RESUME_BUNDLE (a train_run.tar.gz to continue), WHEELS (.whl: wheels of dependencies the
# device lacks, installed with --no-deps into /tmp/site; fetch them here with
# `pip download --only-binary=:all: --python-version 3.12 --no-deps -d .whl trimesh==5.2.0 manifold3d==3.5.4 rtree==1.4.1
# numba==0.68.1 llvmlite==0.50.0` and carry .whl).
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
VOTES=${VOTES:-0}
if [[ "$VOTES" != 0 && "$VOTES" != 1 ]]; then
  echo "VOTES must be 0 or 1, got '$VOTES'" >&2
  exit 2
fi
WORKERS=${WORKERS:-$(( $(nproc) > 3 ? $(nproc) - 2 : 1 ))}
WHEELS=${WHEELS:-.whl}
DATA=${DATA:-/tmp/gpu_session_data}
RUN=${RUN:-/tmp/gpu_session_run}
mkdir -p "$OUT"
log() { echo "[gpu_session $(date +%H:%M:%S)] $*" | tee -a "$OUT/session.log"; }
# stage NAME SECONDS CMD...: the command's whole output in $OUT/NAME.txt (complete even when the limit kills it),
# its tail in the log; a failure or a time-out is logged, not fatal (the next stages still run).
stage() {
  local name=$1 limit=$2 status=0
  shift 2
  log "$name (at most $limit s)"
  timeout "$limit" "$@" > "$OUT/$name.txt" 2>&1 || status=$?
  tail -n 15 "$OUT/$name.txt" | tee -a "$OUT/session.log"
  if (( status == 124 )); then log "$name: stopped at $limit s"; elif (( status != 0 )); then log "$name: failed ($status)"; fi
  return 0
}

# Dependencies: the package from this checkout; the wheels the device lacks, without touching its torch.
if ! python3 -c "import trimesh, manifold3d, rtree, numba" 2>/dev/null; then
  if compgen -G "$WHEELS/*.whl" > /dev/null; then
    python3 -m pip install -q --no-deps --target /tmp/site "$WHEELS"/*.whl
    export PYTHONPATH="/tmp/site:${PYTHONPATH:-}"
  else
    log "trimesh/manifold3d/rtree/numba missing and no wheels in $WHEELS: see the header"
    exit 2
  fi
fi
export PYTHONPATH="$PWD:${PYTHONPATH:-}"
missing=$(python3 -c "import importlib.util as u; print(' '.join(m for m in ('torch', 'numpy', 'scipy', 'trimesh',
  'manifold3d', 'rtree', 'numba', 'skimage', 'pandas', 'cv2', 'tqdm', 'matplotlib', 'pytest') if u.find_spec(m) is None))")
if [[ -n "$missing" ]]; then
  log "missing Python modules: $missing (carry their wheels in $WHEELS)"
  exit 2
fi
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available(),
            torch.cuda.get_device_name(0) if torch.cuda.is_available() else '')" | tee -a "$OUT/session.log"
if [[ "$DEVICE" == "cuda" ]] && ! python3 -c "import torch, sys; sys.exit(not torch.cuda.is_available())"; then
  log "DEVICE=cuda but torch sees no CUDA device"
  exit 2
fi
cli() { python3 -m bop_cender.cli "$@"; }

if [[ "$mode" == "check" ]]; then
  bundle() { tar czf "$OUT/bench.tar.gz" results/bench/*.md 2>/dev/null || true; }  # $OUT returns few files
  stage cuda_tests 150 python3 -m pytest -q -m "cuda and not slow" tests -p no:cacheprovider
  stage bench_run 170 python3 scripts/bench_run.py --devices "$DEVICE" --profile --scenes 1 --seconds 2
  bundle
  # seconds per scene as `run` uses a GPU host: heatmaps on the GPU, stage 3 on the host's cores (compiled loops)
  stage bench_scenes_host 110 python3 scripts/bench_run.py --devices "$DEVICE" --pose-device cpu \
    --loop-threads "$(nproc)" --scenes-only --scenes 3
  bundle
  stage bench_net 90 python3 scripts/bench_net.py --devices "$DEVICE"
  bundle
  log "done"
  exit 0
fi

bundle() { tar czf "$OUT/train_run.tar.gz" -C "$(dirname "$RUN")" "$(basename "$RUN")" 2>/dev/null || true; }
if [[ -n "${RESUME_BUNDLE:-}" ]]; then
  [[ -f "$RESUME_BUNDLE" ]] || { log "RESUME_BUNDLE=$RESUME_BUNDLE: no such file"; exit 2; }
  mkdir -p "$(dirname "$RUN")"
  tar xzf "$RESUME_BUNDLE" -C "$(dirname "$RUN")"
fi
log "synth: $SCENES piles x variants $VARIANTS (train), 4 piles (validation), $WORKERS workers"
cli synth --layout dimo --out "$DATA/dimo_train" --scenes "$SCENES" --variants "$VARIANTS" --seed 9021 \
  --workers "$WORKERS" --no-contact-sheets | tail -2
cli synth --layout dimo --out "$DATA/dimo_val" --scenes 4 --variants 0 --seed 9003 --workers "$WORKERS" \
  --no-contact-sheets | tail -2
resume=()
[[ -f "$RUN/checkpoint.pt" ]] && resume=(--resume)
votes=()
[[ "$VOTES" == 1 ]] && votes=(--center-votes)
# Many epochs asked for: the time limit ends the run; every finished epoch is checkpointed and validated.
stage train $(( TRAIN_MINUTES * 60 )) python3 -m bop_cender.cli train --dataset dimo --data-root "$DATA/dimo_train" \
  --split train --val-split sim --val-data-root "$DATA/dimo_val" --variant dimo --center-loss focal \
  --center-loss-weight 0.1 --batch-size "$BATCH" --epochs 200 --lr 1e-3 --seed 11 --device "$DEVICE" \
  --no-progress --out "$RUN" ${votes[@]+"${votes[@]}"} ${resume[@]+"${resume[@]}"}
bundle
if [[ -f "$RUN/weights.pt" ]]; then
  stage validation_heatmaps 120 python3 -m bop_cender.cli heatmaps --dataset dimo --split sim \
    --data-root "$DATA/dimo_val" --weights "$RUN/weights.pt" --device "$DEVICE" --out "$RUN/val_sim"
  bundle
else
  log "no finished epoch: nothing to validate"
fi
log "done"
