#!/usr/bin/env bash
# The planned A-FAR runs of the 200 Stage + 200 Random-time Cube Handoff variant at peak lr 1e-3 with occluder
# dropout sparing the view-recovery frames (docs/results/learning_rate.md, "Plan: occluder dropout that spares
# the recovery frames, on the Stage + Random-time variant"): the variant's own data (`mixsr400sf`, unchanged),
# then per training seed in SEEDS the steps of `scripts/cube_variant_plan.sh` with
# `--policy.occluder_dropout_in_recovery=false` (train, ship to
# checkpoints/afar_cube_handoff_mixsr400sfodr_b2x_lr1e3[_s<seed>], test, card, validation beside the 200 + 200
# variant). Run again after a stop: finished steps are skipped, a killed training resumes from its last save.
#
#   SEEDS=1000 bash scripts/dropout_recovery_plan.sh
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=mixsr400sf FLAVOUR=odr GRID_METHOD=afar-self-filter-stage+random-400-dropout-spares-recovery-2x-lr1e-3 \
    NOTES=docs/results/learning_rate/card_notes_afar_cube_mix400odr_b2x.md exec bash scripts/cube_variant_plan.sh \
    --policy.occluder_dropout_in_recovery=false
