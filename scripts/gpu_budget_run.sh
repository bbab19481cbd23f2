#!/usr/bin/env bash
# Issue 27's remaining "too few samples" lever: the shipped CPU recipe (self-filtered clouds, 128 of 512 points
# per step, occluder dropout 0.5, 12 executed actions, `cpu_fast` preset) trained on one GPU with the paper's
# 6.4 M samples instead of the CPU's 512 K, everything else unchanged, so its checkpoint can be evaluated beside
# the recipe's on the same validation seeds (docs/results/random_time.md, docs/gpu.md).
#
#   TASK=cube_handoff METHOD=afar bash scripts/gpu_budget_run.sh [data|train|ship|all]   # default: all
#
# Stages, each resumable (re-run the same command; a killed call loses at most SAVE_FREQ steps):
#   data   100 DART Stage demonstrations with self-filtered clouds and their training views (`train_task.sh
#          data`, WORKERS = all cores but one); skipped once done.
#   train  `train_task.sh recipe-train afar|maniflow` on CUDA at batch BATCH (512), with the learning rate scaled by the
#          square root of the batch from the recipe's 3e-4 at 128 (6e-4), the recipe's schedule shape (a cosine
#          over 5/4 of the steps, stopped at STOP = SAMPLES / BATCH: 12,500 steps, as the recipe stops at 4,000
#          of 5,000) and `--policy.compile=true --policy.compile_mode=reduce-overhead` (COMPILE=0: eager).
#          TRAIN_SECONDS bounds this call's training (a lent machine's 10-minute commands): it is then
#          interrupted and the next call resumes from its last checkpoint.
#   ship   the inference weights of step STOP to $OUT/<method>_<task>_sf_<samples> (`ship_checkpoint.py`), to
#          bring back and evaluate with `bavo-eval --policy ... --seed 1000 --episodes 20` (validation seeds).
#
# A larger model (the "model too small" lever, docs/results/first_grasp.md): PRESET (default cpu_fast) and
# POLICY_ARGS (more `--policy.*` size flags, space-separated) choose it; both are in the run's name. HALF=1
# ships it with `--half --trim-stats` (float16 weights, so that ~3.4 M parameters fit the 7 MB limit), e.g.
#   PRESET=cpu POLICY_ARGS="--policy.dit_mlp_ratio=3.5" HALF=1 TASK=drawer_stowing bash scripts/gpu_budget_run.sh
#
# On the project's lent GPU machine (docs/gpu.md), carrying .device/{whl-av,whl-train,fpsample,gl,on-device.sh}:
# the first call `TRAIN_SECONDS=300 bash scripts/gpu_budget_run.sh`, then at once (the machine keeps /tmp and
# outputs/ only while warm) `bash scripts/gpu_budget_run.sh train ship`. Expected (not measured): data ~4 min
# on 16 cores, training ~6 min at the 16,000-40,000 samples/s measured for `cpu_fast` with graphs plus two
# compilations (~1 min each). Smoke test on a CPU (2 demonstrations, 20 steps, eager):
#   DEMOS=2 DATA=dartsf512smoke SAMPLES=2560 BATCH=128 DEVICE=cpu COMPILE=0 bash scripts/gpu_budget_run.sh
set -euo pipefail
cd "$(dirname "$0")/.."
if [ -f .device/on-device.sh ] && [ ! -x .venv/bin/python ]; then
    source .device/on-device.sh  # the lent machine: installs the carried wheels, commands on PATH
    export BIN=""
fi
export TASK="${TASK:-cube_handoff}" SEED="${SEED:-1000}" SELF_FILTER=1 DATA="${DATA:-dartsf512}"
export DEVICE="${DEVICE:-cuda}" DEMOS="${DEMOS:-100}"
METHOD="${METHOD:-afar}"
BATCH="${BATCH:-512}"
SAMPLES="${SAMPLES:-6400000}"
COMPILE="${COMPILE:-1}"
TRAIN_SECONDS="${TRAIN_SECONDS:-0}"  # 0: no bound
OUT="${OUT:-outputs/gpu_budget}"
export PRESET="${PRESET:-cpu_fast}"
POLICY_ARGS="${POLICY_ARGS:-}"  # e.g. "--policy.dit_mlp_ratio=3.5"
HALF="${HALF:-0}"
case "$METHOD" in afar|maniflow) ;; *) echo "METHOD must be afar or maniflow, not '$METHOD'" >&2; exit 2 ;; esac
STOP=$((SAMPLES / BATCH))
if [ $((STOP % 10)) -ne 0 ] || [ "$STOP" -lt 10 ]; then
    echo "SAMPLES / BATCH = $STOP steps: choose them so the steps are a multiple of 10 (checkpoints every tenth)" >&2
    exit 2
fi
LR="${LR:-$(python3 -c "print(f'{3e-4 * ($BATCH / 128) ** 0.5:.3g}')")}"
BINDIR="${BIN-.venv/bin/}"
# the preset and size flags name the run (and the shipped folder) when they differ from the recipe's
SIZE=""
[ "$PRESET" != cpu_fast ] && SIZE="_$PRESET"
[ -n "$POLICY_ARGS" ] && SIZE="${SIZE}_$(echo "$POLICY_ARGS" | sed -e 's/--policy\.//g' -e 's/[^A-Za-z0-9.]\+/_/g' -e 's/_$//')"
TAG="_p128_od50_gpu$((SAMPLES / 1000))k$SIZE"
RUN="${TASK}_${METHOD}${TAG}_${DATA}_s$SEED"
CKPT=$(printf %06d "$STOP")
log() { echo "[gpu_budget_run $(date +%T)] $*"; }

data() {
    WORKERS="${WORKERS:-$(python3 -c 'import os; print(max(1, os.cpu_count() - 1))')}" bash scripts/train_task.sh data
}

train() {
    local compile=()
    [ "$COMPILE" = 1 ] && compile=(--policy.compile=true --policy.compile_mode=reduce-overhead)
    log "$RUN: batch $BATCH, lr $LR, stop at step $STOP of a $((STOP * 5 / 4))-step cosine"
    STEPS=$((STOP * 5 / 4)) STOP_AT="$STOP" BATCH="$BATCH" LR="$LR" WARMUP=200 SAVE_FREQ=$((STOP / 10)) \
        THREADS="${THREADS:-8}" TAG="$TAG" TRAIN_SECONDS="$TRAIN_SECONDS" \
        bash scripts/train_task.sh recipe-train "$METHOD" "${compile[@]}" $POLICY_ARGS
}

ship() {
    [ -d "outputs/train/$RUN/checkpoints/$CKPT" ] || { log "step $STOP not saved yet: run train again"; return 1; }
    mkdir -p "$OUT"
    local half=()
    [ "$HALF" = 1 ] && half=(--half --trim-stats)
    ${BINDIR}python scripts/ship_checkpoint.py --run "outputs/train/$RUN" --step "$CKPT" "${half[@]}" \
        --output "$OUT/${METHOD}_${TASK}_sf_$((SAMPLES / 1000))k$SIZE"
}

stages=("$@")
[ ${#stages[@]} -eq 0 ] && stages=(all)
for stage in "${stages[@]}"; do
    case "$stage" in
        data) data ;;
        train) train ;;
        ship) ship ;;
        all) data; train; ship || true ;;
        *) echo "stage must be data, train, ship or all, not '$stage'" >&2; exit 2 ;;
    esac
done
