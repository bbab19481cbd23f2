#!/usr/bin/env bash
# The main job: a short end-to-end demo of BAVO-Bench (see `bavo-demo --help`).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export OPENBLAS_NUM_THREADS=1 MUJOCO_GL="${MUJOCO_GL:-egl}"
exec .venv/bin/bavo-demo "$@"
