#!/usr/bin/env bash
# Set up lerobot_focal on a fresh machine: install the system libraries it needs (scripts/system_libs.sh),
# find Python ≥ 3.12, create .venv, install the package with its simulation, robot and development extras.
# Idempotent: a second run only re-checks the install.
#   PYTHON=/path/to/python3.12 ./scripts/setup.sh   # to choose the interpreter
#   VENV=/path/to/venv ./scripts/setup.sh            # to choose where the venv goes (default: ./.venv)
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${VENV:-.venv}"

is_py312() { "$1" -c 'import sys; raise SystemExit(sys.version_info < (3, 12))' >/dev/null 2>&1; }

# Python 3.12 first: it is what LeRobot 0.6 and every pinned dependency here (mujoco, ur-rtde, metaworld)
# were tested with; a newer 3.x only if no 3.12 exists.
find_python() {
    local candidates=()
    [ -n "${PYTHON:-}" ] && candidates+=("$PYTHON")
    local root=""
    # pyenv's shim refuses to run a version that is not selected; look for the real binaries instead.
    command -v pyenv >/dev/null 2>&1 && root="$(pyenv root)"
    [ -z "$root" ] && [ -d "$HOME/.pyenv" ] && root="$HOME/.pyenv"
    candidates+=(python3.12)
    [ -n "$root" ] && candidates+=($(ls -d "$root"/versions/3.12*/bin/python3 2>/dev/null | sort -rV))
    candidates+=(/usr/local/bin/python3.12 /usr/bin/python3.12 python3.13)
    [ -n "$root" ] && candidates+=($(ls -d "$root"/versions/3.1[3-9]*/bin/python3 2>/dev/null | sort -rV))
    candidates+=(python3)
    for c in "${candidates[@]}"; do
        if command -v "$c" >/dev/null 2>&1 && is_py312 "$c"; then command -v "$c"; return 0; fi
    done
    return 1
}

# FFmpeg (torchcodec) and OSMesa (MuJoCo offscreen rendering): apt-get installs them, or this stops naming them.
./scripts/system_libs.sh

if [ ! -x "$VENV/bin/python" ] || ! is_py312 "$VENV/bin/python"; then
    if [ -n "${PYTHON:-}" ] && ! is_py312 "$PYTHON"; then
        version="$("$PYTHON" --version 2>/dev/null || echo 'it does not run')"
        echo "error: PYTHON=$PYTHON is not a Python ≥ 3.12 interpreter ($version)." >&2
        echo "Fix: point PYTHON at a Python 3.12 binary, or unset it to let this script look for one." >&2
        exit 1
    fi
    if ! PY="$(find_python)"; then
        echo "error: LeRobot ≥ 0.5 needs Python ≥ 3.12 and none was found." >&2
        echo "Fix: install Python 3.12 (e.g. 'pyenv install 3.12') or run with PYTHON=/path/to/python3.12." >&2
        exit 1
    fi
    echo "[setup] creating $VENV with $PY ($("$PY" --version))"
    rm -rf "$VENV"
    "$PY" -m venv "$VENV"
    "$VENV/bin/python" -m pip install --quiet --upgrade pip
fi

# Always run pip: on a set-up venv it only checks that pyproject's requirements are still met (seconds).
if "$VENV/bin/python" -c 'import lerobot' >/dev/null 2>&1; then
    echo "[setup] checking lerobot_focal[sim,robot,dev,ray] in $VENV"
else
    echo "[setup] installing lerobot_focal[sim,robot,dev,ray] into $VENV (first time: ~4 min, ~6 GB: PyPI's torch is a CUDA build)"
fi
"$VENV/bin/python" -m pip install --quiet --progress-bar off -e ".[sim,robot,dev,ray]" 2>&1 | { grep -v "^WARNING: Location" || true; }
if ! out="$("$VENV/bin/python" -c 'import lerobot, lerobot_policy_focal; print(lerobot.__version__)' 2>&1)"; then
    echo "$out" >&2; echo "error: the install in $VENV does not import; see above." >&2; exit 1
fi
echo "[setup] ok: lerobot $(echo "$out" | tail -1) + lerobot_focal in $VENV"
