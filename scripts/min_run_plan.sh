#!/usr/bin/env bash
# Issue 27's plan for `binary_min_run` 12 on the 400 Stage + 200 Random-time Cube Handoff family
# (docs/results/learning_rate.md, "Plan: gripper switches shorter than one executed chunk held back at
# inference"). Each checkpoint is copied with the setting written into its config (outputs/min_run/<name>; the
# shipped folders are not touched) and evaluated beside its committed as-shipped logs. Both methods alike.
#
#   bash scripts/min_run_plan.sh gate   # the six checkpoints before the fine-tune, validation seeds 1000-1039,
#                                       # all three conditions; prints the pooled paired counts and the gate
#   bash scripts/min_run_plan.sh test   # only after the gate passed: the six fine-tuned checkpoints, then the six
#                                       # before it, test seeds 2000-2039, all three conditions, paired per family
#
# ~4 min per 120-episode evaluation with two workers on the 2-core machine. Run it again after a stop: a copy
# already made is kept, bavo-eval resumes from its last finished episode.
set -euo pipefail
cd "$(dirname "$0")/.."
export OPENBLAS_NUM_THREADS=1 MUJOCO_GL="${MUJOCO_GL:-egl}" HF_HUB_OFFLINE=1
BIN="${BIN-.venv/bin/}"
T=cube_handoff MIN_RUN=12
RUNS=docs/results/grid_table/runs

suffix() { [ "$1" = 1000 ] && echo "" || echo "_s$1"; }
name_of() { echo "${1}_${T}_mixs400r200sf_b2x_lr1e3${2}$(suffix "$3")"; }  # METHOD TAG SEED
grid_method_of() { echo "$1-self-filter-stage400+random200-2x-lr1e-3$([ -n "$2" ] && echo -stage-finetune)"; }

with_min_run() {  # with_min_run NAME: the shipped checkpoint copied with the setting (made once)
    local out=outputs/min_run/$1
    if [ ! -f "$out/config.json" ]; then
        "${BIN}python" scripts/ship_checkpoint.py --checkpoint "checkpoints/$1" --step last --task $T \
            --point-frame base --binary-min-run $MIN_RUN --output "$out" > /dev/null
    fi
    echo "$out"
}

evaluate() {  # evaluate POLICY OUTPUT_DIR FIRST_SEED: 40 seeds from FIRST_SEED, all three conditions
    TASK=$T BIN=$BIN bash scripts/train_task.sh eval-policy "$1" "$2" "$3"
}

case "${1:-}" in
    gate)
        pairs=()
        for method in afar maniflow; do
            for seed in 1000 1001 1002; do
                name=$(name_of $method "" $seed)
                evaluate "$(with_min_run "$name")" "outputs/eval/val_min_run/$name" 1000
                # the committed as-shipped logs are named task first: cube_handoff_<method>_mixs400r200sf_..._val
                pairs+=("outputs/eval/val_min_run/$name/episodes.jsonl=docs/results/learning_rate/${T}_${method}_${name#"${method}_${T}_"}_val.jsonl.gz")
            done
        done
        "${BIN}python" scripts/paired_outcomes.py "${pairs[@]}" --min-gain stage=12 --max-loss clean=12 \
            --max-loss random=12 ;;
    test)
        for tag in _ftstage ""; do
            for method in afar maniflow; do
                pairs=()
                for seed in 1000 1001 1002; do
                    name=$(name_of $method "$tag" $seed)
                    evaluate "$(with_min_run "$name")" "outputs/eval/test_min_run/$name" 2000
                    pairs+=("outputs/eval/test_min_run/$name/episodes.jsonl=$RUNS/$(grid_method_of $method "$tag")/s$seed/$T/episodes.jsonl.gz")
                done
                echo "== $method${tag:+ fine-tuned}, binary_min_run $MIN_RUN (A) against as shipped (B), test seeds"
                "${BIN}python" scripts/paired_outcomes.py "${pairs[@]}"
            done
        done ;;
    *)
        sed -n 2,13p "$0"; exit 2 ;;
esac
