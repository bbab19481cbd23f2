#!/usr/bin/env bash
# The planned A-FAR runs of the 200 Stage + 200 Random-time Cube Handoff variant at peak lr 1e-3 with the
# Random-time frames' camera-arm commands weighing 0.25 in the action losses (docs/results/learning_rate.md,
# "Plan: the Random-time demonstrations' camera commands weighted down"): the data, then per training seed in
# SEEDS one after the other: train 8,000 of a 10,000-step cosine (batch 128, 200 warm-up steps, two torch
# threads) with `--policy.sample_weights=true` and the camera arm's `--policy.loss_weight_dims`, ship step 8,000
# to checkpoints/afar_cube_handoff_mixsr400sfcw25_b2x_lr1e3[_s<seed>], test it on seeds 2000-2039 where
# `bavo-eval --grid configs/grid_table.yaml` finds it and write the card (`train_task.sh ship-test`), then
# evaluate it on the validation seeds 1000-1039 (the plan's gate reads these beside the 200 + 200 variant's).
# Run again after a stop: a finished training is skipped, a killed one resumes from its last saved step and
# bavo-eval from its last finished episode.
#
#   SEEDS=1000 bash scripts/camera_weight_plan.sh
#
# Afterwards: the seed's grid entry in configs/grid_table.yaml and `python scripts/grid_runs.py save`.
set -euo pipefail
cd "$(dirname "$0")/.."
T=cube_handoff
bash scripts/cube_mix_data.sh mixsr400sfcw25
for SEED in ${SEEDS:-1000}; do
    S=$([ "$SEED" = 1000 ] && echo "" || echo "_s$SEED")
    SEED=$SEED DATA=mixsr400sfcw25 TASK=$T STEPS=10000 STOP_AT=8000 BATCH=128 LR=1e-3 WARMUP=200 SAVE_FREQ=500 \
        THREADS=2 TAG=_p128_od50_b2x_lr1e3 bash scripts/train_task.sh recipe-train afar \
        --policy.sample_weights=true "--policy.loss_weight_dims=[14,15,16,17,18,19,20]"
    C=checkpoints/afar_${T}_mixsr400sfcw25_b2x_lr1e3$S
    TASK=$T NOTES=docs/results/learning_rate/card_notes_afar_cube_mix400cw25_b2x.md bash scripts/train_task.sh \
        ship-test "${T}_afar_p128_od50_b2x_lr1e3_mixsr400sfcw25_s$SEED" 8000 "$C" \
        "outputs/eval/grid_table/runs/afar-self-filter-stage+random-400-camera-weight-2x-lr1e-3/s$SEED/$T"
    bavo-eval --policy "$C" --tasks $T --conditions clean,stage,random --episodes 40 --seed 1000 --workers 2 \
        --videos 0 --output-dir "outputs/eval/val_$(basename "$C")"
done
