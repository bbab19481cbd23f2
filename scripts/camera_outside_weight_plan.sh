#!/usr/bin/env bash
# The planned A-FAR runs of the 200 Stage + 200 Random-time Cube Handoff variant at peak lr 1e-3 with the
# Random-time demonstrations' camera commands weighing 0.25 outside their view recoveries
# (docs/results/learning_rate.md, "Plan: the Random-time camera commands weighted down outside their
# recoveries"): its data (`scripts/cube_mix_data.sh mixsr400sfco25`), then per training seed in SEEDS the steps
# of `scripts/cube_variant_plan.sh` with `--policy.sample_weights=true` on the camera arm's dims (train, ship to
# checkpoints/afar_cube_handoff_mixsr400sfco25_b2x_lr1e3[_s<seed>], test, card, validation beside the 200 + 200
# variant). Run again after a stop: finished steps are skipped, a killed training resumes from its last save.
#
#   SEEDS=1000 bash scripts/camera_outside_weight_plan.sh
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=mixsr400sfco25 GRID_METHOD=afar-self-filter-stage+random-400-camera-weight-outside-recovery-2x-lr1e-3 \
    NOTES=docs/results/learning_rate/card_notes_afar_cube_mix400co25_b2x.md exec bash scripts/cube_variant_plan.sh \
    --policy.sample_weights=true "--policy.loss_weight_dims=[14,15,16,17,18,19,20]"
