#!/usr/bin/env bash
# Set up lerobot_focal on a fresh machine: install the system libraries it needs (scripts/system_libs.sh),
# find Python ≥ 3.12, create .venv, install the package with its simulation, robot, development, ray and async extras.
# Idempotent: a second run only re-checks the install.
#   PYTHON=/path/to/python3.12 ./scripts/setup.sh   # to choose the interpreter
#   VENV=/path/to/venv ./scripts/setup.sh            # to choose where the venv goes (default: ./.venv)
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${VENV:-.venv}"

. scripts/python312.sh

# FFmpeg (torchcodec) and OSMesa (MuJoCo offscreen rendering): apt-get installs them, or this stops naming them.
./scripts/system_libs.sh

ensure_venv "$VENV"

# Always run pip: on a set-up venv it only checks that pyproject's requirements are still met (seconds).
if "$VENV/bin/python" -c 'import lerobot' >/dev/null 2>&1; then
    echo "[setup] checking lerobot_focal[sim,robot,dev,ray,async] in $VENV"
else
    echo "[setup] installing lerobot_focal[sim,robot,dev,ray,async] into $VENV (first time: ~4 min, ~6 GB: PyPI's torch is a CUDA build)"
fi
"$VENV/bin/python" -m pip install --quiet --progress-bar off -e ".[sim,robot,dev,ray,async]" 2>&1 | { grep -v "^WARNING: Location" || true; }
if ! out="$("$VENV/bin/python" -c 'import lerobot, lerobot_policy_focal; print(lerobot.__version__)' 2>&1)"; then
    echo "$out" >&2; echo "error: the install in $VENV does not import; see above." >&2; exit 1
fi
echo "[setup] ok: lerobot $(echo "$out" | tail -1) + lerobot_focal in $VENV"
