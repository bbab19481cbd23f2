#!/usr/bin/env bash
# One planned data variant of Cube Handoff's 200 Stage + 200 Random-time lr 1e-3 runs
# (docs/results/learning_rate.md), per training seed in SEEDS one after the other: the data
# (`scripts/cube_mix_data.sh $DATA`), then train 8,000 of a 10,000-step cosine (batch 128, 200 warm-up steps, two
# torch threads; lerobot-train arguments after the script's name are added), ship step 8,000 to
# checkpoints/afar_cube_handoff_${DATA}_b2x_lr1e3[_s<seed>], test it on seeds 2000-2039 where
# `bavo-eval --grid configs/grid_table.yaml` finds it (grid method $GRID_METHOD) and write the card with NOTES
# (`train_task.sh ship-test`), then evaluate it and the 200 + 200 variant of the same seed on the validation seeds
# 1000-1039 (the plans' gates read these). Run again after a stop: a finished training is skipped, a killed one
# resumes from its last saved step and bavo-eval from its last finished episode. The plans call it through
# `scripts/stage_tilt_plan.sh`, `scripts/camera_weight_plan.sh`, `scripts/recovery_weight_plan.sh` and
# `scripts/dropout_recovery_plan.sh`, which set DATA, GRID_METHOD and NOTES (and FLAVOUR):
#
#   DATA=mixs400r200sf GRID_METHOD=afar-self-filter-stage400+random200-2x-lr1e-3 \
#     NOTES=docs/results/learning_rate/card_notes_afar_cube_mix600_b2x.md SEEDS=1000 bash scripts/cube_variant_plan.sh
#
# METHOD is the policy type (afar, the default, or maniflow: the same runs for the comparison the plans ask for,
# shipped as checkpoints/maniflow_cube_handoff_${DATA}_b2x_lr1e3[_s<seed>] and validated beside ManiFlow's 200 + 200
# variant). FLAVOUR names a training-only variant on the same data (e.g. FLAVOUR=odr with
# --policy.occluder_dropout_in_recovery=false): the run gets the tag _p128_od50_b2x_lr1e3_$FLAVOUR and the
# checkpoint the name ${METHOD}_cube_handoff_${DATA}${FLAVOUR}_b2x_lr1e3: it never overwrites the data's own.
# BIN is where the project's commands are, as in scripts/train_task.sh (default .venv/bin/; BIN= takes them from
# PATH). Afterwards: the seed's grid entry in configs/grid_table.yaml and `python scripts/grid_runs.py save`.
set -euo pipefail
cd "$(dirname "$0")/.."
data=${DATA:?set DATA to a variant of scripts/cube_mix_data.sh}
grid=${GRID_METHOD:?set GRID_METHOD to the grid method of the variant (configs/grid_table.yaml)}
notes=${NOTES:?set NOTES to the notes file of the card}
T=cube_handoff
method=${METHOD:-afar}
case "$method" in afar|maniflow) ;; *) echo "cube_variant_plan: METHOD is afar or maniflow, not '$method'" >&2; exit 2 ;; esac
flavour=${FLAVOUR:-}
tag=_p128_od50_b2x_lr1e3${flavour:+_$flavour}
bash scripts/cube_mix_data.sh "$data"
for SEED in ${SEEDS:-1000}; do
    S=$([ "$SEED" = 1000 ] && echo "" || echo "_s$SEED")
    SEED=$SEED DATA=$data TASK=$T STEPS=10000 STOP_AT=8000 BATCH=128 LR=1e-3 WARMUP=200 SAVE_FREQ=500 \
        THREADS=2 TAG=$tag bash scripts/train_task.sh recipe-train "$method" "$@"
    C=checkpoints/${method}_${T}_${data}${flavour}_b2x_lr1e3$S
    TASK=$T NOTES=$notes bash scripts/train_task.sh ship-test "${T}_${method}${tag}_${data}_s$SEED" 8000 \
        "$C" "outputs/eval/grid_table/runs/$grid/s$SEED/$T"
    for p in "$C" "checkpoints/${method}_${T}_mixsr400sf_b2x_lr1e3$S"; do
        "${BIN-.venv/bin/}bavo-eval" --policy "$p" --tasks $T --conditions clean,stage,random --episodes 40 \
            --seed 1000 --workers 2 --videos 0 --output-dir "outputs/eval/val_$(basename "$p")"
    done
done
