#!/usr/bin/env bash
# The main job: a short end-to-end demo of BAVO-Bench (see `bavo-demo --help`).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
# One BLAS / OpenMP (torch) thread unless you choose otherwise: torch's default of one per core makes an
# episode many times slower when anything else uses the CPU.
export OPENBLAS_NUM_THREADS="${OPENBLAS_NUM_THREADS:-1}" OMP_NUM_THREADS="${OMP_NUM_THREADS:-1}" \
    MUJOCO_GL="${MUJOCO_GL:-egl}"
exec .venv/bin/bavo-demo "$@"
