#!/usr/bin/env bash
# The planned runs of the 200 Stage + 200 Random-time 2x Cube Handoff variant at peak lr 1e-3
# (docs/results/learning_rate.md, "Plan: lr 1e-3 on the Stage + Random-time variant" for A-FAR and "Plan: ManiFlow
# on the Stage + Random-time variant at lr 1e-3"), one method, the training seeds in SEEDS one after the other:
# train 8,000 of a 10,000-step cosine (batch 128, 200 warm-up steps, two torch threads), ship step 8,000 to
# checkpoints/<method>_cube_handoff_mixsr400sf_b2x_lr1e3[_s<seed>], test it on seeds 2000-2039 in all three
# conditions where `bavo-eval --grid configs/grid_table.yaml` finds it, and write the card. No validation gate
# (one configuration, nothing chosen). Run again after a stop: a killed training resumes from its last saved step
# and bavo-eval from its last finished episode.
#
#   METHOD=maniflow SEEDS="1001 1002" bash scripts/mix400_lr1e3_plan.sh
#
# The data come first (`scripts/cube_mix_data.sh mixsr400sf`: collected once, ~33 min on the 2-core machine, then
# skipped).
# Afterwards: the seed's grid entry in configs/grid_table.yaml and `python scripts/grid_runs.py save`.
set -euo pipefail
cd "$(dirname "$0")/.."
m=${METHOD:?set METHOD=afar or METHOD=maniflow}
case "$m" in afar|maniflow) ;; *) echo "mix400_lr1e3_plan: METHOD is afar or maniflow, not '$m'" >&2; exit 2 ;; esac
T=cube_handoff
bash scripts/cube_mix_data.sh mixsr400sf
for SEED in ${SEEDS:-1000 1001 1002}; do
    S=$([ "$SEED" = 1000 ] && echo "" || echo "_s$SEED")
    SEED=$SEED DATA=mixsr400sf TASK=$T STEPS=10000 STOP_AT=8000 BATCH=128 LR=1e-3 WARMUP=200 SAVE_FREQ=500 \
        THREADS=2 TAG=_p128_od50_b2x_lr1e3 bash scripts/train_task.sh recipe-train "$m"
    C=checkpoints/${m}_${T}_mixsr400sf_b2x_lr1e3$S
    TASK=$T NOTES="docs/results/learning_rate/card_notes_${m}_cube_mix400_b2x.md" bash scripts/train_task.sh \
        ship-test "${T}_${m}_p128_od50_b2x_lr1e3_mixsr400sf_s$SEED" 8000 "$C" \
        "outputs/eval/grid_table/runs/$m-self-filter-stage+random-400-2x-lr1e-3/s$SEED/$T"
done
