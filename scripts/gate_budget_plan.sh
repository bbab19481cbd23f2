#!/usr/bin/env bash
# The planned A-FAR runs of the 400 Stage + 200 Random-time Cube Handoff variant at peak lr 1e-3 with the fusion
# gate's learning rate at 1x the peak lr instead of the `cpu_fast` preset's 10x, which gives the gate the paper's
# learning-rate budget back (docs/results/learning_rate.md, "Plan: A-FAR's fusion gate at the paper's
# learning-rate budget on the 400 + 200 data"): the variant's own data (`mixs400r200sf`, unchanged), then per
# training seed in SEEDS the steps of `scripts/cube_variant_plan.sh` with `--policy.fusion_gate_lr_scale=1`
# (train, ship to checkpoints/afar_cube_handoff_mixs400r200sfgate1_b2x_lr1e3[_s<seed>], test, card, validation on
# seeds 1000-1039), and for seed 1000 the plan's gate: Stage on validation seeds 1040-1119 too, then the gate read
# (Clean >= 20 and Random-time >= 10 of 40, Stage >= 78 of the 120 validation episodes 1000-1119). Run again
# after a stop: finished steps are skipped, a killed training resumes from its last save.
#
#   SEEDS=1000 bash scripts/gate_budget_plan.sh          # seed 1000 and the gate
#   SEEDS="1001 1002" bash scripts/gate_budget_plan.sh   # only if the gate passed
set -euo pipefail
cd "$(dirname "$0")/.."
export OPENBLAS_NUM_THREADS=1 MUJOCO_GL="${MUJOCO_GL:-egl}" HF_HUB_OFFLINE=1
BIN="${BIN-.venv/bin/}"
C=checkpoints/afar_cube_handoff_mixs400r200sfgate1_b2x_lr1e3
DATA=mixs400r200sf FLAVOUR=gate1 GRID_METHOD=afar-self-filter-stage400+random200-2x-lr1e-3-gate1 \
    NOTES=docs/results/learning_rate/card_notes_afar_cube_mix600gate1_b2x.md bash scripts/cube_variant_plan.sh \
    --policy.fusion_gate_lr_scale=1
case " ${SEEDS:-1000} " in *" 1000 "*) ;; *) exit 0 ;; esac
"${BIN}bavo-eval" --policy "$C" --tasks cube_handoff --conditions stage --episodes 80 --seed 1040 --workers 2 \
    --videos 0 --output-dir "outputs/eval/val2_$(basename "$C")"
"${BIN}python" scripts/validation_gate.py "outputs/eval/val_$(basename "$C")/episodes.jsonl" \
    "outputs/eval/val2_$(basename "$C")/episodes.jsonl" --label "gate_budget seed 1000" --clean-min 20 \
    --random-min 10 --stage-min 78
