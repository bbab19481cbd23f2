#!/usr/bin/env bash
# The CPU recipe behind docs/results/ladder_cube_handoff.md and the shipped A-FAR checkpoint, one stage at a
# time. Every training is a plain `lerobot-train` call: resumable with --resume=true (re-run the same stage),
# checkpointed every SAVE_FREQ steps. On a GPU use the same commands with DEVICE=cuda (and, for the paper's
# scale, PRESET=paper STEPS=100000).
#
#   bash scripts/train_cube_handoff.sh collect      # 100 Stage demonstrations (bavo-collect), 3.6-5.1 min on an idle 2-core machine
#   bash scripts/train_cube_handoff.sh views        # the `points` and `state` training views
#   bash scripts/train_cube_handoff.sh state        # rung 1: privileged-state ManiFlow
#   bash scripts/train_cube_handoff.sh maniflow     # rung 2: point-cloud ManiFlow
#   bash scripts/train_cube_handoff.sh afar         # rung 3: A-FAR (same budget and seed as rung 2)
#   bash scripts/train_cube_handoff.sh eval RUN     # bavo-eval of outputs/train/RUN (clean + stage, 20 seeds)
#
# The shipped A-FAR (checkpoints/afar_cube_handoff, step 4000 of this run; its ManiFlow twin: `maniflow` with the
# same variables and arguments, TAG=_p128_od50):
#   DATA=dart STEPS=5000 BATCH=128 LR=3e-4 WARMUP=200 SAVE_FREQ=500 THREADS=1 TAG=_p128_od50 \
#     bash scripts/train_cube_handoff.sh afar --policy.points_per_step=128 --policy.n_action_steps=12 \
#     --policy.occluder_dropout=0.5
# A killed run resumes from its last checkpoint when the same command is run again (same variables: they name
# the run folder).
#
# Arguments after the stage go to lerobot-train (e.g. `afar --policy.points_per_step=128`).
# Environment overrides: STEPS, BATCH, LR, WARMUP, SAVE_FREQ, PRESET, SEED, DEVICE, THREADS, EPISODES, FROM, TAG
# (a suffix of the run name, e.g. TAG=_b256 gives outputs/train/maniflow_state_b256_s1000), and DATA: empty for
# the noise-free demonstrations (outputs/datasets/bavo_cube_handoff), `dart` for the DART-style ones collected
# with `--execution-noise $NOISE` (default 0.01 rad; outputs/datasets/bavo_cube_handoff_dart, runs get a _dart
# suffix).
set -euo pipefail
cd "$(dirname "$0")/.."
export OPENBLAS_NUM_THREADS=1 MUJOCO_GL="${MUJOCO_GL:-egl}" HF_HUB_OFFLINE=1
export OMP_NUM_THREADS="${THREADS:-1}"
DATA="${DATA:-}"
NOISE="${NOISE:-0.01}"
DS=outputs/datasets/bavo_cube_handoff${DATA:+_$DATA}
REPO=local/bavo_cube_handoff${DATA:+_$DATA}
STEPS="${STEPS:-8000}"
BATCH="${BATCH:-64}"
SAVE_FREQ="${SAVE_FREQ:-1000}"
PRESET="${PRESET:-cpu_fast}"
SEED="${SEED:-1000}"
DEVICE="${DEVICE:-cpu}"
EPISODES="${EPISODES:-20}"
LR="${LR:-}"          # empty: the policy's preset (1e-4, the paper's)
WARMUP="${WARMUP:-}"  # empty: the preset's 500 warm-up steps
TAG="${TAG:-}${DATA:+_$DATA}"
FROM="${FROM:-}"      # a pretrained_model folder to fine-tune (e.g. checkpoints/afar_cube_handoff); empty: from scratch

train() {  # train NAME TYPE VIEW [extra lerobot-train args...]
    local name=$1 type=$2 view=$3
    shift 3
    local out=outputs/train/$name
    if [ -f "$out/checkpoints/last/pretrained_model/train_config.json" ]; then
        echo "[train] resuming $out"
        .venv/bin/lerobot-train --config_path="$out/checkpoints/last/pretrained_model/train_config.json" \
            --resume=true 2>&1 | tee -a "outputs/train/$name.log"
        return
    fi
    mkdir -p outputs/train
    local policy_args=(--policy.type="$type" --policy.preset="$PRESET")
    # FROM: start from a checkpoint's weights, EMA and processors (its config; fresh optimiser and schedule)
    [ -n "$FROM" ] && policy_args=(--policy.path="$FROM")
    .venv/bin/lerobot-train "${policy_args[@]}" \
        --dataset.repo_id="${REPO}_$view" --dataset.root="${DS}_$view" \
        --policy.device="$DEVICE" --policy.push_to_hub=false --num_workers=0 \
        --batch_size="$BATCH" --steps="$STEPS" --save_freq="$SAVE_FREQ" --log_freq=50 --seed="$SEED" \
        --output_dir="$out" --wandb.enable=false ${LR:+--policy.optimizer_lr="$LR"} \
        ${WARMUP:+--policy.scheduler_warmup_steps="$WARMUP"} "$@" 2>&1 | tee "outputs/train/$name.log"
}

case "${1:-}" in
    collect)
        .venv/bin/bavo-collect --task cube_handoff --condition stage --episodes 100 --repo-id "$REPO" \
            --root "$DS" --workers 2 ${DATA:+--execution-noise "$NOISE"} ;;
    views)
        for v in points state; do
            [ -d "${DS}_$v" ] || .venv/bin/python -m lerobot_bavo.datasets.views --root "$DS" --view "$v"
        done ;;
    state) train "maniflow_state${TAG}_s$SEED" maniflow state "${@:2}" ;;
    maniflow) train "maniflow${TAG}_s$SEED" maniflow points "${@:2}" ;;
    afar) train "afar${TAG}_s$SEED" afar points "${@:2}" ;;
    eval)
        run=${2:?usage: eval RUN [STEP]}
        step=${3:-last}
        .venv/bin/bavo-eval --policy "outputs/train/$run/checkpoints/$step/pretrained_model" \
            --tasks cube_handoff --conditions clean,stage --episodes "$EPISODES" --seed 1000 \
            --workers 1 --videos 2 --output-dir "outputs/eval/${run}_$step" ;;
    *)
        sed -n 2,16p "$0"; exit 2 ;;
esac
