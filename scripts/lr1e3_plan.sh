#!/usr/bin/env bash
# The planned lr 1e-3 runs of docs/results/learning_rate.md for one task and training seed, both methods one after
# the other: `scripts/train_task.sh recipe` on the self-filtered data with peak lr 1e-3, two torch threads and the
# plans' validation gate (at least the successes of the recipe's checkpoint of the same seed on seeds 1000-1019,
# Clean and Stage) before shipping to checkpoints/<method>_<task>_sf_lr1e3[_s<seed>] and testing that folder on
# the 40 test seeds where `bavo-eval --grid configs/grid_table.yaml` finds it. Run again after a stop: finished
# steps are kept.
#
#   TASK=dustpan_sweeping METHODS=maniflow SEED=1001 bash scripts/lr1e3_plan.sh
#
# Afterwards: card notes (`scripts/ship_checkpoint.py --notes`) and the grid entry in configs/grid_table.yaml.
set -uo pipefail
cd "$(dirname "$0")/.."
: "${TASK:?set TASK, e.g. TASK=dustpan_sweeping}"
for m in ${METHODS:-afar maniflow}; do
    SELF_FILTER=1 LR=1e-3 THREADS=2 GATE=1 TASK=$TASK SEED=${SEED:-1000} bash scripts/train_task.sh recipe "$m" \
        || { echo "[lr1e3_plan] $m failed" >&2; exit 1; }
done
