#!/usr/bin/env bash
# The planned A-FAR runs of the 400 Stage + 200 Random-time Cube Handoff variant at peak lr 1e-3
# (docs/results/learning_rate.md, "Plan: more Stage demonstrations in the lr 1e-3 variant"): its data
# (`scripts/cube_mix_data.sh mixs400r200sf`), then per training seed in SEEDS the steps of
# `scripts/cube_variant_plan.sh` (train, ship to checkpoints/afar_cube_handoff_mixs400r200sf_b2x_lr1e3[_s<seed>],
# test, card, validation beside the 200 + 200 variant). Run again after a stop: finished steps are skipped.
#
#   SEEDS=1000 bash scripts/stage_tilt_plan.sh
#   METHOD=maniflow SEEDS=1000 bash scripts/stage_tilt_plan.sh   # ManiFlow's same runs (its grid method and card notes)
set -euo pipefail
cd "$(dirname "$0")/.."
METHOD=${METHOD:-afar}
export METHOD
DATA=mixs400r200sf GRID_METHOD=$METHOD-self-filter-stage400+random200-2x-lr1e-3 \
    NOTES=docs/results/learning_rate/card_notes_${METHOD}_cube_mix600_b2x.md exec bash scripts/cube_variant_plan.sh
