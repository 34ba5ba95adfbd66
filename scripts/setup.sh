#!/usr/bin/env bash
# Set up lerobot_focal on a fresh machine: find Python ≥ 3.12, create .venv, install the package with its
# simulation, robot and development extras. Idempotent: a second run only re-checks the install.
#   PYTHON=/path/to/python3.12 ./scripts/setup.sh   # to choose the interpreter
#   VENV=/path/to/venv ./scripts/setup.sh            # to choose where the venv goes (default: ./.venv)
set -euo pipefail
cd "$(dirname "$0")/.."
VENV="${VENV:-.venv}"

is_py312() { "$1" -c 'import sys; raise SystemExit(sys.version_info < (3, 12))' >/dev/null 2>&1; }

find_python() {
    local candidates=()
    [ -n "${PYTHON:-}" ] && candidates+=("$PYTHON")
    candidates+=(python3.13 python3.12)
    if command -v pyenv >/dev/null 2>&1; then
        # pyenv's shim refuses to run a version that is not selected; ask pyenv for the real binaries.
        local root; root="$(pyenv root)"
        candidates+=($(ls -d "$root"/versions/3.1[2-9]*/bin/python3 2>/dev/null | sort -rV))
    fi
    candidates+=(/root/.pyenv/versions/3.12*/bin/python3 /usr/local/bin/python3.12 /usr/bin/python3.12 python3)
    for c in "${candidates[@]}"; do
        if command -v "$c" >/dev/null 2>&1 && is_py312 "$c"; then command -v "$c"; return 0; fi
    done
    return 1
}

# System libraries, installed with apt when missing and we are root (otherwise a warning says what to install):
# - OSMesa: MuJoCo renders offscreen (depth for point clouds, pixels, eval videos) through EGL or OSMesa;
#   neither needs a GPU.
# - FFmpeg's shared libraries: LeRobot decodes dataset videos with torchcodec, which loads them at import;
#   without them every lerobot-* command prints a long traceback and falls back to the slower pyav.
missing=()
ldconfig -p 2>/dev/null | grep -q -E "libOSMesa\.so|libEGL\.so" || missing+=(libosmesa6 libgl1)
ldconfig -p 2>/dev/null | grep -q "libavutil\.so" || missing+=(ffmpeg)
if [ ${#missing[@]} -gt 0 ]; then
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "[setup] apt-get install ${missing[*]}"
        apt-get install -y -q --no-install-recommends "${missing[@]}" >/dev/null \
            || echo "[setup] warning: apt-get install ${missing[*]} failed" >&2
    else
        echo "[setup] warning: missing system packages: ${missing[*]} (Debian names); install them for rendering and video decoding" >&2
    fi
fi

if [ ! -x "$VENV/bin/python" ] || ! is_py312 "$VENV/bin/python"; then
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
    echo "[setup] checking lerobot_focal[sim,robot,dev] in $VENV"
else
    echo "[setup] installing lerobot_focal[sim,robot,dev] into $VENV (first time: ~4 min, ~6 GB: PyPI's torch is a CUDA build)"
fi
"$VENV/bin/python" -m pip install --quiet --progress-bar off -e ".[sim,robot,dev]" 2>&1 | { grep -v "^WARNING: Location" || true; }
if ! out="$("$VENV/bin/python" -c 'import lerobot, lerobot_policy_focal; print(lerobot.__version__)' 2>&1)"; then
    echo "$out" >&2; echo "error: the install in $VENV does not import; see above." >&2; exit 1
fi
echo "[setup] ok: lerobot $(echo "$out" | tail -1) + lerobot_focal in $VENV"
