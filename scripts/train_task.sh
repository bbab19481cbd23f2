#!/usr/bin/env bash
# The CPU recipe behind docs/results/ (the ladder on Cube Handoff, the shipped A-FAR checkpoints), one stage at a
# time, for any BAVO-Bench task (TASK, default cube_handoff). Every training is a plain `lerobot-train` call:
# resumable (re-run the same stage), checkpointed every SAVE_FREQ steps. On a GPU use the same commands with
# DEVICE=cuda (and, for the paper's scale, PRESET=paper STEPS=100000).
#
#   bash scripts/train_task.sh collect      # 100 Stage demonstrations (bavo-collect), 3.6-5.1 min on an idle 2-core machine
#   bash scripts/train_task.sh views        # the `points` and `state` training views
#   bash scripts/train_task.sh state        # rung 1: privileged-state ManiFlow
#   bash scripts/train_task.sh maniflow     # rung 2: point-cloud ManiFlow
#   bash scripts/train_task.sh afar         # rung 3: A-FAR (same budget and seed as rung 2)
#   bash scripts/train_task.sh eval RUN     # bavo-eval of outputs/train/RUN on the validation seeds (clean + stage)
#   bash scripts/train_task.sh test RUN STEP  # bavo-eval on the 40 test seeds 2000-2039, clean + stage + random
#   bash scripts/train_task.sh eval-policy POLICY OUTPUT_DIR FIRST_SEED [bavo-eval args...]  # a policy folder on
#                                             # 40 seeds from FIRST_SEED (1000: validation), all conditions, no videos
#   bash scripts/train_task.sh data         # collect (once; a marker records it) + views
#   bash scripts/train_task.sh recipe-train METHOD  # the recipe's training arguments, stopped after STOP_AT
#                                             # (or after TRAIN_SECONDS; run again to resume)
#   bash scripts/train_task.sh recipe METHOD  # collect + views + the shipped recipe for METHOD (afar|maniflow),
#                                             # stopped after step STOP_AT (4000), shipped to
#                                             # checkpoints/<method>_<task> and evaluated on the 40 test seeds in
#                                             # outputs/eval/grid_table/runs/<method>/s<SEED>/<task> (its episode
#                                             # log copied to docs/results/grid_table); resumable
#   bash scripts/train_task.sh ship-test RUN STEP FOLDER EVAL_DIR  # ship step STEP of outputs/train/RUN to
#                                             # FOLDER (inference weights), test it on seeds 2000-2039 in
#                                             # EVAL_DIR and write its card (with NOTES); `recipe` ends with it
#   SELF_FILTER=1 bash scripts/train_task.sh recipe METHOD  # the same on self-filtered clouds (the robot's own
#                                             # body dropped, 512 stored points: docs/results/self_filter.md),
#                                             # data variant dartsf512, shipped to checkpoints/<method>_<task>_sf,
#                                             # evaluated in outputs/eval/grid_table/runs/<method>-self-filter/...
#   SELF_FILTER=1 LR=1e-3 THREADS=2 GATE=1 bash scripts/train_task.sh recipe METHOD  # the recipe at another
#                                             # peak lr (docs/results/learning_rate.md): run, folder and grid entry
#                                             # get _lr1e3 / -lr1e-3; GATE=1 first validates it and the recipe's
#                                             # checkpoint of the same seed (seeds 1000-1019, clean + stage) and
#                                             # ships and tests it only with at least the recipe's successes
#
# The shipped A-FARs (checkpoints/afar_<task>: step 4000 of a 5000-step cosine schedule, fixed in advance):
#   TASK=block_stacking bash scripts/train_task.sh recipe afar
# which is, for each task:
#   DATA=dart STEPS=5000 BATCH=128 LR=3e-4 WARMUP=200 SAVE_FREQ=500 THREADS=1 TAG=_p128_od50 \
#     bash scripts/train_task.sh afar --policy.points_per_step=128 --policy.n_action_steps=12 \
#     --policy.occluder_dropout=0.5 --policy.binary_action_levels="$(python -m lerobot_bavo.datasets.action_levels \
#     --root outputs/datasets/bavo_<task>_dart_points)"   # [-1.0,1.0] except Drawer Stowing's [-1.0,-0.1,0.4,1.0]
# A killed run resumes from its last checkpoint when the same command is run again (same variables: they name
# the run folder, outputs/train/<task>_<method><TAG>_dart_s<SEED>).
#
# Arguments after the stage go to lerobot-train (e.g. `afar --policy.points_per_step=128`).
# Environment overrides: TASK, DEMOS, BIN, TRAIN_SECONDS, STEPS, BATCH, LR, WARMUP, SAVE_FREQ, PRESET, SEED, DEVICE, THREADS, EPISODES, FROM,
# TAG (a suffix of the run name, e.g. TAG=_b256 gives outputs/train/cube_handoff_maniflow_state_b256_s1000), STOP_AT,
# WORKERS (collection and evaluation processes, default 2), GATE (recipe: 1 validates before shipping), NOTES
# (recipe, ship-test: a Markdown file for the card, ship_checkpoint.py --notes), and DATA: empty for the noise-free demonstrations
# (outputs/datasets/bavo_<task>), `dart` for the DART-style ones collected with `--execution-noise $NOISE`
# (default 0.01 rad; outputs/datasets/bavo_<task>_dart, runs get a _dart suffix); SELF_FILTER=1 collects with
# `--n-points 512 --self-filter` (use it with DATA=dartsf512, as `recipe` does); CLEAN_CONTACTS=1 adds
# `--execution-noise-clean-contacts` (no noise in the expert's approach, grasp and release phases).
set -euo pipefail
cd "$(dirname "$0")/.."
export OPENBLAS_NUM_THREADS=1 MUJOCO_GL="${MUJOCO_GL:-egl}" HF_HUB_OFFLINE=1
export OMP_NUM_THREADS="${THREADS:-1}"
TASK="${TASK:-cube_handoff}"
BIN="${BIN-.venv/bin/}"  # where the project's commands are; BIN= (empty) takes them from PATH (a GPU machine)
DEMOS="${DEMOS:-100}"    # demonstrations `collect` records (the paper's 100; fewer only for smoke tests)
DATA="${DATA:-}"
WORKERS="${WORKERS:-2}"
STOP_AT="${STOP_AT:-4000}"
NOISE="${NOISE:-0.01}"
SELF_FILTER="${SELF_FILTER:-}"
CLEAN_CONTACTS="${CLEAN_CONTACTS:-}"  # 1: no execution noise in the expert's contact phases (approach, grasp, release)
DS=outputs/datasets/bavo_${TASK}${DATA:+_$DATA}
REPO=local/bavo_${TASK}${DATA:+_$DATA}
STEPS="${STEPS:-8000}"
BATCH="${BATCH:-64}"
SAVE_FREQ="${SAVE_FREQ:-1000}"
PRESET="${PRESET:-cpu_fast}"
SEED="${SEED:-1000}"
DEVICE="${DEVICE:-cpu}"
EPISODES="${EPISODES:-20}"
LR="${LR:-}"          # empty: the policy's preset (1e-4, the paper's)
WARMUP="${WARMUP:-}"  # empty: the preset's 500 warm-up steps
RUN_TAG="${TAG:-}"   # as given: a stage that starts another hands this on (that one appends the data variant)
TAG="${RUN_TAG}${DATA:+_$DATA}"
FROM="${FROM:-}"      # a pretrained_model folder to fine-tune (e.g. checkpoints/afar_cube_handoff); empty: from scratch

run_name() {  # run_name KIND: the run folder of a training stage (outputs/train/<name>)
    echo "${TASK}_$1${TAG}_s$SEED"
}

train() {  # train NAME TYPE VIEW [extra lerobot-train args...]
    local name=$1 type=$2 view=$3
    shift 3
    local out=outputs/train/$name
    if [ -f "$out/checkpoints/last/pretrained_model/train_config.json" ]; then
        echo "[train] resuming $out"
        ${BIN}lerobot-train --config_path="$out/checkpoints/last/pretrained_model/train_config.json" \
            --resume=true 2>&1 | tee -a "outputs/train/$name.log"
        return
    fi
    mkdir -p outputs/train
    local policy_args=(--policy.type="$type" --policy.preset="$PRESET")
    # FROM: start from a checkpoint's weights, EMA and processors (its config; fresh optimiser and schedule)
    [ -n "$FROM" ] && policy_args=(--policy.path="$FROM")
    ${BIN}lerobot-train "${policy_args[@]}" \
        --dataset.repo_id="${REPO}_$view" --dataset.root="${DS}_$view" \
        --policy.device="$DEVICE" --policy.push_to_hub=false --num_workers=0 \
        --batch_size="$BATCH" --steps="$STEPS" --save_freq="$SAVE_FREQ" --log_freq=50 --seed="$SEED" \
        --output_dir="$out" --wandb.enable=false ${LR:+--policy.optimizer_lr="$LR"} \
        ${WARMUP:+--policy.scheduler_warmup_steps="$WARMUP"} "$@" 2>&1 | tee "outputs/train/$name.log"
}

seeds_eval() {  # seeds_eval FIRST_SEED POLICY OUTPUT_DIR [bavo-eval args...]: 40 episodes from seed FIRST_SEED
    # (1000: the validation seeds, 2000: the test seeds), all three conditions; later bavo-eval args win
    local seed=$1 policy=$2 out=$3
    shift 3
    ${BIN}bavo-eval --policy "$policy" --tasks "$TASK" --conditions clean,stage,random --episodes 40 \
        --seed "$seed" --workers "$WORKERS" --output-dir "$out" "$@"
}

test_eval() {  # test_eval POLICY OUTPUT_DIR [bavo-eval args...]: the 40 test seeds 2000-2039, all conditions
    seeds_eval 2000 "$@"
}

val_eval() {  # val_eval POLICY OUTPUT_DIR [bavo-eval args...]: EPISODES validation seeds from 1000, clean + stage
    local policy=$1 out=$2
    shift 2
    ${BIN}bavo-eval --policy "$policy" --tasks "$TASK" --conditions clean,stage --episodes "$EPISODES" \
        --seed 1000 --output-dir "$out" "$@"
}

successes() {  # successes EVAL_DIR: successful episodes of its episodes.jsonl (the eval package's own reader)
    ${BIN}python -c 'import sys; from pathlib import Path; from lerobot_bavo.eval.run import read_episode_records as r
print(sum(bool(e["success"]) for e in r(Path(sys.argv[1]))))' "$1/episodes.jsonl"
}

case "${1:-}" in
    collect)
        ${BIN}bavo-collect --task "$TASK" --condition stage --episodes "$DEMOS" --repo-id "$REPO" \
            --root "$DS" --workers "$WORKERS" ${DATA:+--execution-noise "$NOISE"} \
            ${CLEAN_CONTACTS:+--execution-noise-clean-contacts} \
            ${SELF_FILTER:+--n-points 512 --self-filter} ;;
    views)
        for v in points state; do
            [ -d "${DS}_$v" ] || ${BIN}python -m lerobot_bavo.datasets.views --root "$DS" --view "$v"
        done ;;
    state) train "$(run_name maniflow_state)" maniflow state "${@:2}" ;;
    maniflow) train "$(run_name maniflow)" maniflow points "${@:2}" ;;
    afar) train "$(run_name afar)" afar points "${@:2}" ;;
    eval)
        run=${2:?usage: eval RUN [STEP]}
        step=${3:-last}
        val_eval "outputs/train/$run/checkpoints/$step/pretrained_model" "outputs/eval/${run}_$step" \
            --workers 1 --videos 2 ;;
    test)
        run=${2:?usage: test RUN STEP}
        step=$(printf %06d "${3:?usage: test RUN STEP}")
        test_eval "outputs/train/$run/checkpoints/$step/pretrained_model" "outputs/eval/${run}_${step}_test" ;;
    eval-policy)  # eval-policy POLICY OUTPUT_DIR FIRST_SEED [bavo-eval args...]: what the plan scripts evaluate
        seeds_eval "${4:?usage: eval-policy POLICY OUTPUT_DIR FIRST_SEED [bavo-eval args...]}" "$2" "$3" \
            --videos 0 "${@:5}" ;;
    data)  # collect (bavo-collect resumes a killed collection; the marker beside the dataset says it finished)
        # and the training views
        [ -f "$DS.collected" ] || { bash "$0" collect && touch "$DS.collected"; }
        bash "$0" views ;;
    recipe-train)  # the shipped recipe's training arguments, stopped once step STOP_AT is saved, or after
        # TRAIN_SECONDS (0, default: no bound; a later call resumes from the last checkpoint)
        method=${2:?usage: recipe-train afar|maniflow [lerobot-train args...]}
        case "$method" in afar|maniflow) ;; *) echo "recipe-train: afar or maniflow, not '$method'" >&2; exit 2 ;; esac
        run=$(run_name "$method")
        ckpt=$(printf %06d "$STOP_AT")
        [ -d "outputs/train/$run/checkpoints/$ckpt" ] && { echo "[recipe-train] $run: step $STOP_AT saved"; exit 0; }
        # the gripper levels the demonstrations hold (part-open ones too: Drawer Stowing's 0.45 and 0.7)
        levels=$(${BIN}python -m lerobot_bavo.datasets.action_levels --root "${DS}_points")
        TAG="$RUN_TAG" bash "$0" "$method" --policy.points_per_step=128 --policy.n_action_steps=12 \
            --policy.occluder_dropout=0.5 --policy.binary_action_levels="$levels" "${@:3}" &
        pid=$! t0=$SECONDS
        while kill -0 "$pid" 2>/dev/null; do
            # LeRobot moves `last` once a checkpoint is completely written
            if [ "$(readlink "outputs/train/$run/checkpoints/last" 2>/dev/null)" = "$ckpt" ] \
                || { [ "${TRAIN_SECONDS:-0}" -gt 0 ] && [ $((SECONDS - t0)) -ge "$TRAIN_SECONDS" ]; }; then
                pkill -INT -P "$pid" -f lerobot-train || true; sleep 10; pkill -P "$pid" -f lerobot-train || true
                break
            fi
            sleep 5
        done
        wait "$pid" || true
        echo "[recipe-train] $run: last checkpoint $(readlink "outputs/train/$run/checkpoints/last" 2>/dev/null || echo none)" ;;
    recipe)
        method=${2:?usage: recipe afar|maniflow}
        case "$method" in afar|maniflow) ;; *) echo "recipe: afar or maniflow, not '$method'" >&2; exit 2 ;; esac
        # the data variant, the shipped folder's suffix and the grid entry's suffix
        data=dart suffix="" entry=""
        [ -n "$SELF_FILTER" ] && data=dartsf512 suffix=_sf entry=-self-filter
        # another peak lr than the recipe's 3e-4 is a variant: 1e-3 gives _lr1e3 (run, folder) and -lr1e-3 (grid)
        lr=${LR:-3e-4} lrtag=""
        [ "$lr" = 3e-4 ] || lrtag=_lr${lr//-/}
        export DATA=$data STEPS=5000 BATCH=128 LR=$lr WARMUP=200 SAVE_FREQ=500 THREADS=${THREADS:-1} \
            TAG=_p128_od50$lrtag EPISODES=20
        seedsuffix=""  # the first training seed's folders; others get a suffix
        [ "$SEED" = 1000 ] || seedsuffix=_s$SEED
        # GATE=1's reference: the recipe's checkpoint of the same training seed (checked before any work)
        reference="checkpoints/${method}_${TASK}$suffix$seedsuffix"
        if [ -n "${GATE:-}" ]; then
            [ -n "$lrtag" ] || { echo "[recipe] GATE=1 compares a variant with the recipe: set LR" >&2; exit 2; }
            [ -d "$reference" ] || { echo "[recipe] GATE=1: no recipe checkpoint $reference" >&2; exit 2; }
        fi
        bash "$0" data
        run="${TASK}_${method}_p128_od50${lrtag}_${data}_s$SEED"
        ckpt=$(printf %06d "$STOP_AT")
        # the 5000-step schedule stopped once step STOP_AT is saved (the compared point, fixed in advance)
        bash "$0" recipe-train "$method"
        [ -d "outputs/train/$run/checkpoints/$ckpt" ] || { echo "[recipe] $run: step $STOP_AT not saved" >&2; exit 1; }
        if [ -n "${GATE:-}" ]; then
            # the validation gate of docs/results/learning_rate.md: at least the successes of the recipe's
            # checkpoint of the same seed, on the same seeds and machine
            val="outputs/eval/val_${TASK}_${method}"
            OMP_NUM_THREADS=1 val_eval "outputs/train/$run/checkpoints/$ckpt/pretrained_model" \
                "$val${lrtag}$seedsuffix" --workers "$WORKERS" --videos 0
            OMP_NUM_THREADS=1 val_eval "$reference" "${val}_recipe$seedsuffix" --workers "$WORKERS" --videos 0
            a=$(successes "$val${lrtag}$seedsuffix") b=$(successes "${val}_recipe$seedsuffix")
            echo "[recipe] $run: validation successes $a, recipe $b (of 40)"
            [ "$a" -ge "$b" ] || { echo "[recipe] $run: under the gate, not shipped or tested"; exit 0; }
        fi
        # evaluated where `bavo-eval --grid configs/grid_table.yaml` finds it (runs/<method>/s<SEED>/<task>)
        bash "$0" ship-test "$run" "$STOP_AT" "checkpoints/${method}_${TASK}$suffix$lrtag$seedsuffix" \
            "outputs/eval/grid_table/runs/$method$entry${lrtag:+-lr${lr}}/s$SEED/$TASK"
        ${BIN}python scripts/grid_runs.py save ;;  # the episode logs to commit (docs/results/grid_table)
    ship-test)  # ship the inference weights, test the shipped folder, then write its card with the results
        run=${2:?usage: ship-test RUN STEP FOLDER EVAL_DIR}
        ckpt=$(printf %06d "${3:?usage: ship-test RUN STEP FOLDER EVAL_DIR}")
        ship=${4:?usage: ship-test RUN STEP FOLDER EVAL_DIR}
        evaldir=${5:?usage: ship-test RUN STEP FOLDER EVAL_DIR}
        ${BIN}python scripts/ship_checkpoint.py --run "outputs/train/$run" --step "$ckpt" --output "$ship"
        test_eval "$ship" "$evaldir" --videos 0
        ${BIN}python scripts/ship_checkpoint.py --checkpoint "$ship" --step "$ckpt" --eval "$evaldir/results.json" \
            ${NOTES:+--notes "$NOTES"} --output "$ship" ;;
    *)
        sed -n 2,45p "$0"; exit 2 ;;
esac
