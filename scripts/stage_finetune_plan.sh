#!/usr/bin/env bash
# Issue 27's Stage fine-tune of the 400 Stage + 200 Random-time Cube Handoff A-FARs (docs/results/learning_rate.md,
# "Plan: a short Stage-only fine-tune of the 400 + 200 variant"). Each run starts from the shipped checkpoint of
# its training seed (checkpoints/afar_cube_handoff_mixs400r200sf_b2x_lr1e3[_s<seed>]: weights, EMA and
# normalisation statistics), with a fresh AdamW and schedule (peak lr 1e-4, 100 warm-up steps, cosine to 0 at
# step 1,500, batch 128: 192 K samples, checkpoints every 500 steps, two torch threads), on the Stage episodes
# 0-399 of the same training view (`--dataset.episodes`; the view's statistics, so normalisation is unchanged).
# No new demonstration. METHOD=maniflow runs ManiFlow's same steps from its own 400 + 200 checkpoints (validation
# logs under outputs/eval/val_ftstage_maniflow_*, shipped as checkpoints/maniflow_..._ftstage[_s<seed>]).
#
#   bash scripts/stage_finetune_plan.sh choose        # seed 1000: fine-tune, validate steps 500 / 1000 / 1500 on
#                                                     # seeds 1000-1039 (all conditions), the chosen one on Stage
#                                                     # 1040-1119 too; prints the table, the choice and the gate
#   STEP=<chosen> SEEDS="1000 1001 1002" bash scripts/stage_finetune_plan.sh test
#                                                     # fine-tune each seed (skipped when done), ship step STEP to
#                                                     # checkpoints/afar_cube_handoff_mixs400r200sf_b2x_lr1e3_ftstage[_s<seed>]
#                                                     # and test it on seeds 2000-2039 where the grid finds it
#
# VARIANT=square runs the same steps for "Plan: the cube grasped square to the table" instead: the fine-tune reads the
# 200 square-grasp Stage episodes (600-799) of the view `scripts/cube_mix_data.sh mixs400r200sq200sf` builds, its
# logs and runs are tagged _ftsquare, its gate is Stage >= 90 of 120, and it ships as
# checkpoints/<method>_cube_handoff_mixs400r200sf_b2x_lr1e3_ftsquare[_s<seed>].
#
# ~10 min per fine-tune and ~4 min per 40-episode evaluation with two workers on the 2-core machine. Run it again
# after a stop: a finished fine-tune is skipped, a killed one resumes from its last checkpoint, bavo-eval resumes
# from its last finished episode.
set -euo pipefail
cd "$(dirname "$0")/.."
export OPENBLAS_NUM_THREADS=1 MUJOCO_GL="${MUJOCO_GL:-egl}" HF_HUB_OFFLINE=1
BIN="${BIN-.venv/bin/}"
T=cube_handoff DATA=mixs400r200sf  # DATA: the view the starting checkpoints were trained on
METHOD=${METHOD:-afar}
case "$METHOD" in afar|maniflow) ;; *) echo "stage_finetune_plan: METHOD is afar or maniflow, not '$METHOD'" >&2; exit 2 ;; esac
# the episodes the fine-tune reads: scripts/mix_views.py keeps its sources' order, and cube_mix_data.sh gives the
# four Stage collections first, then the two Random-time ones, then (mixs400r200sq200sf) the two square-grasp ones
# (the view's bavo_collection.json, `mixed_from`, lists them)
case "${VARIANT:-stage}" in
    stage) TAG=_ftstage FT_DATA=$DATA GATE=78 first=0 last=399 grid_suffix=stage-finetune notes_suffix=ftstage ;;
    square) TAG=_ftsquare FT_DATA=mixs400r200sq200sf GATE=90 first=600 last=799 grid_suffix=square-finetune
            notes_suffix=ftsquare ;;
    *) echo "stage_finetune_plan: VARIANT is stage or square, not '$VARIANT'" >&2; exit 2 ;;
esac
GRID_METHOD=$METHOD-self-filter-stage400+random200-2x-lr1e-3-$grid_suffix
NOTES=docs/results/learning_rate/card_notes_${METHOD}_cube_mix600_$notes_suffix.md
V=val$TAG$([ "$METHOD" = afar ] || echo "_$METHOD")  # the validation logs' prefix (A-FAR's came first)
export V
stage_episodes="[$(seq -s, $first $last)]"

suffix() { [ "$1" = 1000 ] && echo "" || echo "_s$1"; }
run_of() { echo "${T}_${METHOD}${TAG}_${FT_DATA}_s$1"; }  # train_task.sh appends the data it reads

finetune() {  # finetune SEED: the 1,500-step fine-tune of that seed's shipped checkpoint (skipped when saved)
    local seed=$1
    [ -d "outputs/train/$(run_of "$seed")/checkpoints/001500" ] && return
    FROM="checkpoints/${METHOD}_${T}_${DATA}_b2x_lr1e3$(suffix "$seed")" SEED=$seed DATA=$FT_DATA TASK=$T STEPS=1500 \
        BATCH=128 LR=1e-4 WARMUP=100 SAVE_FREQ=500 THREADS=2 TAG=$TAG BIN=$BIN \
        bash scripts/train_task.sh "$METHOD" --dataset.episodes="$stage_episodes"
}

evaluate() {  # evaluate POLICY OUTPUT_DIR CONDITIONS EPISODES FIRST_SEED
    TASK=$T BIN=$BIN bash scripts/train_task.sh eval-policy "$1" "$2" "$5" --conditions "$3" --episodes "$4"
}

case "${1:-}" in
    choose)
        finetune 1000
        for step in 000500 001000 001500; do
            evaluate "outputs/train/$(run_of 1000)/checkpoints/$step/pretrained_model" \
                "outputs/eval/${V}_s1000_$step" clean,stage,random 40 1000
        done
        # the rule fixed in the plan: Random-time >= 10 and Clean >= 20 of 40; then the most Stage successes,
        # a tie to the earlier step
        chosen=$("${BIN}python" - <<'PY'
import os
import sys
from pathlib import Path

from lerobot_bavo.eval.run import condition_successes, read_episode_records

best = None
for step in ("000500", "001000", "001500"):
    rows = read_episode_records(Path(f"outputs/eval/{os.environ['V']}_s1000_{step}/episodes.jsonl"))
    n = {c: condition_successes(rows, c)[0] for c in ("clean", "stage", "random")}
    eligible = n["random"] >= 10 and n["clean"] >= 20
    print(f"| step {int(step)} | {n['clean']} / 40 | {n['stage']} / 40 | {n['random']} / 40 | "
          f"{'yes' if eligible else 'no'} |", file=sys.stderr)
    if eligible and (best is None or n["stage"] > best[1]):
        best = (step, n["stage"])
print(best[0] if best else "none")
PY
)
        echo "[stage_finetune] chosen step: $chosen"
        [ "$chosen" = none ] && { echo "[stage_finetune] no step passes Random-time >= 10 and Clean >= 20"; exit 0; }
        evaluate "outputs/train/$(run_of 1000)/checkpoints/$chosen/pretrained_model" \
            "outputs/eval/${V/val/val2}_s1000_$chosen" stage 80 1040
        # the gate: Stage >= GATE of the 120 validation episodes (Clean and Random-time were the choice's rule)
        "${BIN}python" scripts/validation_gate.py "outputs/eval/${V}_s1000_$chosen/episodes.jsonl" \
            "outputs/eval/${V/val/val2}_s1000_$chosen/episodes.jsonl" --label "stage_finetune step $chosen" \
            --stage-min $GATE
        ;;
    test)
        step=${STEP:?set STEP to the chosen step (500, 1000 or 1500)}
        case "$step" in 500|1000|1500) ;; *) echo "STEP: 500, 1000 or 1500, not '$step'" >&2; exit 2 ;; esac
        for seed in ${SEEDS:-1000}; do
            finetune "$seed"
            S=$(suffix "$seed")
            TASK=$T NOTES=$NOTES BIN=$BIN bash scripts/train_task.sh ship-test "$(run_of "$seed")" "$step" \
                "checkpoints/${METHOD}_${T}_${DATA}_b2x_lr1e3$TAG$S" "outputs/eval/grid_table/runs/$GRID_METHOD/s$seed/$T"
        done ;;
    *)
        sed -n 2,20p "$0"; exit 2 ;;
esac
