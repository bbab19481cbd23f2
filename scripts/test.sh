#!/usr/bin/env bash
# The default test suite (excludes tests marked `slow`; run those with: scripts/test.sh -m slow).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export OPENBLAS_NUM_THREADS=1 MUJOCO_GL="${MUJOCO_GL:-egl}" HF_HUB_OFFLINE=1
exec .venv/bin/python -m pytest "$@"
