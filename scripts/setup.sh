#!/usr/bin/env bash
# Create (or refresh) the project's virtual environment in .venv with Python 3.12.
# Idempotent: re-installs only when pyproject.toml changed. Used by scripts/demo.sh and
# scripts/test.sh; safe to run by hand.
set -euo pipefail
cd "$(dirname "$0")/.."
# Another apt (unattended upgrades, a second set-up) holds its lock: wait for it instead of failing.
APT_WAIT="-o DPkg::Lock::Timeout=300"

find_python() {
    local candidates=()
    [ -n "${BAVO_PYTHON:-}" ] && candidates+=("$BAVO_PYTHON")
    candidates+=(python3.12)
    if command -v pyenv >/dev/null 2>&1; then
        local prefix
        prefix=$(pyenv prefix 3.12.1 2>/dev/null || true)
        [ -n "$prefix" ] && candidates+=("$prefix/bin/python3.12")
    fi
    for d in "$HOME"/.pyenv/versions/3.12.*; do
        [ -x "$d/bin/python3.12" ] && candidates+=("$d/bin/python3.12")
    done
    for c in "${candidates[@]}"; do
        if command -v "$c" >/dev/null 2>&1 && "$c" -c 'import sys; sys.exit(sys.version_info[:2] != (3, 12))' 2>/dev/null; then
            command -v "$c"
            return 0
        fi
    done
    return 1
}

if [ ! -x .venv/bin/python ]; then
    if ! PY=$(find_python); then
        echo "error: Python 3.12 not found (LeRobot 0.6.1 needs it)." >&2
        echo "       Install it, e.g. 'pyenv install 3.12.1', or point BAVO_PYTHON at a python3.12." >&2
        exit 1
    fi
    echo "[setup] creating .venv with $PY"
    "$PY" -m venv .venv
fi

# Headless rendering needs EGL and Mesa's software rasteriser.
if ! ldconfig -p 2>/dev/null | grep -q 'libEGL.so.1'; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "[setup] installing libegl1 libgl1-mesa-dri (headless MuJoCo rendering)"
        apt-get update -qq $APT_WAIT && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $APT_WAIT libegl1 libgl1-mesa-dri
    else
        echo "error: libEGL not found; install the Debian packages libegl1 and libgl1-mesa-dri." >&2
        exit 1
    fi
fi

# LeRobot's video decoding (torchcodec) loads the system FFmpeg libraries: without them every LeRobot CLI
# prints a long libtorchcodec traceback and `lerobot-info` fails (OSError: libavutil.so.*).
if ! ldconfig -p 2>/dev/null | grep -q 'libavutil.so'; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "[setup] installing ffmpeg (FFmpeg libraries for LeRobot's torchcodec video decoding)"
        apt-get update -qq $APT_WAIT && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $APT_WAIT ffmpeg
    else
        echo "warning: FFmpeg libraries not found; install the Debian package ffmpeg (LeRobot's CLIs need it" \
             "to decode videos, and print a torchcodec traceback without it)." >&2
    fi
fi

stamp=.venv/.bavo-install-stamp
extras="test,ray"  # the test suite runs the Ray executor tests too (a local Ray on loopback)
want=$( (cat pyproject.toml; echo "$extras") | sha256sum | cut -d' ' -f1)
if [ ! -f "$stamp" ] || [ "$(cat "$stamp")" != "$want" ] || ! .venv/bin/python -c 'import lerobot_bavo' 2>/dev/null; then
    echo "[setup] installing lerobot-bavo and its dependencies into .venv (first run downloads PyTorch; several minutes)"
    if ! { .venv/bin/python -m pip install -q --upgrade pip && .venv/bin/python -m pip install -q -e ".[$extras]"; }; then
        # pip's own message for a full disk is one OSError line among many; say what to free and where
        free_venv=$(df -Ph .venv | awk 'NR==2 {print $4}')
        free_tmp=$(df -Ph "${TMPDIR:-/tmp}" | awk 'NR==2 {print $4}')
        echo "error: installing into .venv failed (above). A first install takes about 7 GB (PyTorch with CUDA);" \
             "free now: $free_venv where .venv is, $free_tmp in ${TMPDIR:-/tmp} (pip's build space)." >&2
        exit 1
    fi
    echo "$want" > "$stamp"
fi
