#!/usr/bin/env bash
# Run the plugin's contract and CLI tests against another LeRobot, e.g. a checkout of LeRobot's main branch, in a
# venv of its own (the project's .venv keeps CI's LeRobot 0.6.1). See docs/compatibility.md.
#
#   scripts/test_lerobot_main.sh /path/to/lerobot            # a LeRobot source tree (holds pyproject.toml, src/lerobot)
#   scripts/test_lerobot_main.sh /path/to/lerobot -k card    # extra arguments go to pytest
#   VENV=/path/to/venv PYTHON=/path/to/python3.12 scripts/test_lerobot_main.sh ...
#
# Builds the venv the first time (~3 min, ~6 GB: the torch wheel LeRobot pins is a CUDA build), installs that
# LeRobot from the tree and this plugin editable in one resolve, so the plugin's `lerobot<0.7` pin has to admit
# the tree's version; reinstalls LeRobot only when the tree changed. Then runs the tests listed in TESTS below.
set -euo pipefail
if [ $# -lt 1 ] || [ ! -f "$1/pyproject.toml" ] || [ ! -d "$1/src/lerobot" ]; then
    echo "usage: $0 <lerobot source tree> [pytest args...]  (the tree holds pyproject.toml and src/lerobot)" >&2
    exit 2
fi
TREE="$(cd "$1" && pwd)"; shift
cd "$(dirname "$0")/.."
VENV="${VENV:-.venv-lerobot-main}"

. scripts/python312.sh
./scripts/system_libs.sh
ensure_venv "$VENV"

# The extras this plugin's tests use: training + diffusion (the policy), metaworld (focal_metaworld env),
# gamepad (the virtual F710); the plugin's own sim, robot and dev extras.
# The stamp covers the tree and the plugin's own pyproject.toml (a new test dependency, such as pytest-xdist, reinstalls).
tree_stamp="$(cd "$TREE" && find pyproject.toml src -type f -not -path '*.egg-info/*' -printf '%P %s %T@\n' | sort)"
stamp="$(printf '%s\n%s\n' "$tree_stamp" "$(sha256sum pyproject.toml)" | sha256sum | cut -c1-16)"
previous="$(cat "$VENV/.lerobot-tree" 2>/dev/null || true)"
if [ "$previous" != "$TREE $stamp" ]; then
    echo "[lerobot-main] installing LeRobot from $TREE and lerobot_focal[sim,robot,dev] into $VENV"
    log="$VENV/pip-install.log"
    # Building the tree prints setuptools' deprecation notices: into the log, which is shown if pip fails.
    if ! "$VENV/bin/python" -m pip install --progress-bar off \
        "lerobot[training,diffusion,metaworld,gamepad] @ file://$TREE" -e ".[sim,robot,dev]" >"$log" 2>&1; then
        tail -40 "$log" >&2; echo "error: pip could not install $TREE with lerobot_focal (log: $log)" >&2; exit 1
    fi
    # pip keeps an installed LeRobot of the same version: a changed tree is reinstalled explicitly.
    if [ -n "$previous" ] && ! "$VENV/bin/python" -m pip install --progress-bar off --force-reinstall --no-deps \
        "$TREE" >>"$log" 2>&1; then
        tail -40 "$log" >&2; echo "error: pip could not reinstall $TREE (log: $log)" >&2; exit 1
    fi
    echo "$TREE $stamp" > "$VENV/.lerobot-tree"
fi
version="$("$VENV/bin/python" -c 'import lerobot, lerobot_policy_focal; print(lerobot.__version__)' | tail -1)"
echo "[lerobot-main] LeRobot $version from $TREE in $VENV"

# The plugin contract, the policy's LeRobot interface (save/load, model card, EMA), lerobot-train / -eval / -rollout
# as real processes, --ema.enable, AMP and the compile switch.
TESTS=(
    tests/test_plugin_contract.py
    tests/policy/test_policy.py
    tests/policy/test_cli.py
    tests/policy/test_cli_config_errors.py
    tests/policy/test_hub_push.py::test_train_pushes_a_folder_that_loads_back_with_a_focal_model_card
    tests/policy/test_lerobot_compat.py
    tests/policy/test_amp_compile.py
    tests/envs/test_registration.py
    tests/envs/test_train_eval_cli.py::test_collect_train_eval_metaworld
    tests/robots/test_ur10e_loop.py::test_train_focal_then_rollout_drives_the_sim_arm
)
exec "$VENV/bin/python" -m pytest -p no:cacheprovider "${TESTS[@]}" "$@"
