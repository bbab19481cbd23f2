#!/usr/bin/env bash
# Ruff, then the default test suite on two workers (excludes tests marked `slow`; run those with:
# scripts/test.sh -m slow).
set -euo pipefail
cd "$(dirname "$0")/.."
# Another apt (unattended upgrades, a second set-up) holds its lock: wait for it instead of failing.
APT_WAIT="-o DPkg::Lock::Timeout=300"
bash scripts/setup.sh
# The browser tests (bavo-teleop's page, driven by key presses) need Debian's chromium; they skip, saying so,
# without it. Installed here, not in setup.sh, because only the tests need it.
if ! command -v chromium >/dev/null 2>&1 && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "[test] installing chromium (headless browser tests of bavo-teleop)"
    apt-get update -qq $APT_WAIT && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $APT_WAIT chromium >/dev/null || \
        echo "warning: chromium could not be installed; the browser tests will be skipped" >&2
fi
# Lint first (the configuration is in pyproject.toml): a finding fails the test command.
.venv/bin/ruff check lerobot_bavo lerobot_env_bavo tests benchmarks scripts
export OPENBLAS_NUM_THREADS=1 OPENBLAS_CORETYPE="${OPENBLAS_CORETYPE:-Haswell}" MUJOCO_GL="${MUJOCO_GL:-egl}" HF_HUB_OFFLINE=1
# Two pytest workers (pytest-xdist), one test module each at a time (`--dist loadfile`: a module's fixtures are
# built once, its tests stay in order): the suite is mostly single-threaded rollouts and subprocess start-ups, so on
# CI's two cores this nearly halves its wall time. TEST_WORKERS=0 runs it in one process (e.g. under a debugger).
exec .venv/bin/python -m pytest -n "${TEST_WORKERS:-2}" --dist loadfile "$@"
