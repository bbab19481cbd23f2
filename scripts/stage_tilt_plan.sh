#!/usr/bin/env bash
# The planned A-FAR runs of the 400 Stage + 200 Random-time Cube Handoff variant at peak lr 1e-3
# (docs/results/learning_rate.md, "Plan: more Stage demonstrations in the lr 1e-3 variant"): the data, then per
# training seed in SEEDS one after the other: train 8,000 of a 10,000-step cosine (batch 128, 200 warm-up steps,
# two torch threads), ship step 8,000 to checkpoints/afar_cube_handoff_mixs400r200sf_b2x_lr1e3[_s<seed>], test
# it on seeds 2000-2039 where `bavo-eval --grid configs/grid_table.yaml` finds it and write the card
# (`train_task.sh ship-test`), then evaluate it and the 200 + 200 variant of the same seed on the validation
# seeds 1000-1039 (the plan's gate for more seeds reads these). Run again after a stop: a finished training is
# skipped, a killed one resumes from its last saved step and bavo-eval from its last finished episode.
#
#   SEEDS=1000 bash scripts/stage_tilt_plan.sh
#
# Afterwards: the seed's grid entry in configs/grid_table.yaml and `python scripts/grid_runs.py save`.
set -euo pipefail
cd "$(dirname "$0")/.."
T=cube_handoff
bash scripts/cube_mix_data.sh mixs400r200sf
for SEED in ${SEEDS:-1000}; do
    S=$([ "$SEED" = 1000 ] && echo "" || echo "_s$SEED")
    SEED=$SEED DATA=mixs400r200sf TASK=$T STEPS=10000 STOP_AT=8000 BATCH=128 LR=1e-3 WARMUP=200 SAVE_FREQ=500 \
        THREADS=2 TAG=_p128_od50_b2x_lr1e3 bash scripts/train_task.sh recipe-train afar
    C=checkpoints/afar_${T}_mixs400r200sf_b2x_lr1e3$S
    TASK=$T NOTES=docs/results/learning_rate/card_notes_afar_cube_mix600_b2x.md bash scripts/train_task.sh ship-test \
        "${T}_afar_p128_od50_b2x_lr1e3_mixs400r200sf_s$SEED" 8000 "$C" \
        "outputs/eval/grid_table/runs/afar-self-filter-stage400+random200-2x-lr1e-3/s$SEED/$T"
    for p in "$C" "checkpoints/afar_${T}_mixsr400sf_b2x_lr1e3$S"; do
        bavo-eval --policy "$p" --tasks $T --conditions clean,stage,random --episodes 40 --seed 1000 --workers 2 \
            --videos 0 --output-dir "outputs/eval/val_$(basename "$p")"
    done
done
