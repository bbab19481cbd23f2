#!/usr/bin/env bash
# The planned lr 1e-3 runs of docs/results/learning_rate.md for one task, end to end and resumable: the recipe's
# self-filtered data (collected once, seeded), then per method the recipe with peak lr 1e-3 (seed 1000, two
# threads, stopped at step 4000), validation seeds 1000-1019 (Clean, Stage) for it and for the recipe's shipped
# seed-1000 checkpoint, and, if it passes the plans' gate (at least the recipe's validation successes), shipping to
# checkpoints/<method>_<task>_sf_lr1e3 and the 40 test seeds 2000-2039 of the shipped folder where
# `bavo-eval --grid configs/grid_table.yaml` finds it. Run again after a stop: finished steps are kept.
#
#   TASK=dustpan_sweeping METHODS=maniflow bash scripts/lr1e3_plan.sh
#
# Afterwards: card notes (`scripts/ship_checkpoint.py --notes`), the grid entry, `scripts/grid_runs.py save`.
set -uo pipefail
cd "$(dirname "$0")/.."
export PATH=$PWD/.venv/bin:$PATH OPENBLAS_NUM_THREADS=1 MUJOCO_GL="${MUJOCO_GL:-egl}" HF_HUB_OFFLINE=1
T=${TASK:?set TASK, e.g. TASK=dustpan_sweeping}
stamp() { echo "[lr1e3_plan $(date -u +%H:%M:%S)] $*"; }
successes() {  # successes EVAL_DIR: successful episodes in its episodes.jsonl (the eval package's own reader)
    python -c 'import sys; from pathlib import Path; from lerobot_bavo.eval.run import read_episode_records as r
print(sum(bool(e["success"]) for e in r(Path(sys.argv[1]))))' "$1/episodes.jsonl"
}
SELF_FILTER=1 DATA=dartsf512 TASK=$T bash scripts/train_task.sh data || { stamp data failed; exit 1; }
for m in ${METHODS:-afar maniflow}; do
    SEED=1000 DATA=dartsf512 TASK=$T STEPS=5000 STOP_AT=4000 BATCH=128 LR=1e-3 WARMUP=200 SAVE_FREQ=500 THREADS=2 \
        TAG=_p128_od50_lr1e3 bash scripts/train_task.sh recipe-train "$m"
    TRAIN=outputs/train/${T}_${m}_p128_od50_lr1e3_dartsf512_s1000
    [ -d "$TRAIN/checkpoints/004000" ] || { stamp "$m: step 4000 not reached"; exit 1; }
    for v in lr1e3=$TRAIN/checkpoints/004000/pretrained_model recipe=checkpoints/${m}_${T}_sf; do
        OMP_NUM_THREADS=1 bavo-eval --policy "${v#*=}" --tasks "$T" --conditions clean,stage --episodes 20 --seed 1000 \
            --workers 2 --videos 0 --output-dir "outputs/eval/val_${T}_${m}_${v%%=*}"
    done
    a=$(successes "outputs/eval/val_${T}_${m}_lr1e3") b=$(successes "outputs/eval/val_${T}_${m}_recipe")
    stamp "$m: validation successes lr 1e-3 $a, recipe $b (of 40)"
    if [ "$a" -lt "$b" ]; then stamp "$m: under the gate, not run on the test seeds"; continue; fi
    ship=checkpoints/${m}_${T}_sf_lr1e3 evaldir=outputs/eval/grid_table/runs/$m-self-filter-lr1e-3/s1000/$T
    [ -d "$ship" ] || python scripts/ship_checkpoint.py --run "$TRAIN" --step 004000 --output "$ship"
    OMP_NUM_THREADS=1 bavo-eval --policy "$ship" --tasks "$T" --conditions clean,stage,random --episodes 40 \
        --seed 2000 --workers 2 --videos 0 --output-dir "$evaldir"
    python scripts/ship_checkpoint.py --checkpoint "$ship" --step 004000 --eval "$evaldir/results.json" --output "$ship"
    stamp "$m: tested, $ship"
done
