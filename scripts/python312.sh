# Sourced by scripts/setup.sh and scripts/test_lerobot_main.sh: find a Python ≥ 3.12 and create a venv with it.
# Defines is_py312 PYTHON, find_python (prints the interpreter; honours $PYTHON) and ensure_venv DIR.

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

# Create DIR as a Python ≥ 3.12 venv unless it already is one (then nothing happens).
ensure_venv() {
    local venv="$1"
    if [ ! -x "$venv/bin/python" ] || ! is_py312 "$venv/bin/python"; then
        if [ -n "${PYTHON:-}" ] && ! is_py312 "$PYTHON"; then
            local version; version="$("$PYTHON" --version 2>/dev/null || echo 'it does not run')"
            echo "error: PYTHON=$PYTHON is not a Python ≥ 3.12 interpreter ($version)." >&2
            echo "Fix: point PYTHON at a Python 3.12 binary, or unset it to let this script look for one." >&2
            exit 1
        fi
        if ! PY="$(find_python)"; then
            echo "error: LeRobot ≥ 0.5 needs Python ≥ 3.12 and none was found." >&2
            echo "Fix: install Python 3.12 (e.g. 'pyenv install 3.12') or run with PYTHON=/path/to/python3.12." >&2
            exit 1
        fi
        echo "[setup] creating $venv with $PY ($("$PY" --version))"
        rm -rf "$venv"
        "$PY" -m venv "$venv"
        "$venv/bin/python" -m pip install --quiet --upgrade pip
    fi
}
