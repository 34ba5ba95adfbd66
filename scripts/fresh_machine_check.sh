#!/usr/bin/env bash
# Check scripts/setup.sh on a machine state nobody prepared by hand: a bare Debian root made by debootstrap
# (minbase + git, ca-certificates and a compiler, as a fresh Debian machine has them), the committed HEAD cloned
# into it, setup.sh run there (which must install the apt libraries itself), then a pytest selection.
# A developer's check, not part of the test suite: it needs root, debootstrap and a few GB of downloads.
#
#   sudo scripts/fresh_machine_check.sh                       # default selection (system libraries, OpenGL, video)
#   sudo scripts/fresh_machine_check.sh -- tests/policy -x     # any pytest arguments after --
#   ROOT=/path/to/dir KEEP=1 sudo -E scripts/fresh_machine_check.sh   # where the root goes; KEEP=1 keeps it
#
# What is carried in from the host, and why (each is a setting of the network or of the user's machine, not
# something the project installs):
#   - the host's CA certificates and pip configuration: on a network behind a TLS-inspecting proxy every machine
#     needs them, and pip must behave as it does on the host;
#   - a Python 3.12: Debian bookworm's own is 3.11, and the README asks for a Python ≥ 3.12 installed beforehand.
#     PYTHON312_ROOT (default: pyenv's root, ~/.pyenv) is bind-mounted read-only at the same path.
# The Debian mirror is read from the host's apt sources (MIRROR overrides it); SUITE defaults to bookworm.
set -euo pipefail
cd "$(dirname "$0")/.."
REPO="$(pwd)"

ROOT="${ROOT:-$REPO/outputs/fresh_machine}"
SUITE="${SUITE:-bookworm}"
PYTHON312_ROOT="${PYTHON312_ROOT:-$HOME/.pyenv}"
PYTEST_ARGS=(tests/test_system_libs.py tests/envs/test_pointcloud.py tests/datasets/test_salvage.py
             tests/datasets/test_fast_reader.py tests/policy/test_cli_dataset_stats.py)
if [ "${1:-}" = "--" ]; then shift; PYTEST_ARGS=("$@"); fi

die() { echo "error: $*" >&2; exit 1; }
[ -d "$PYTHON312_ROOT/versions" ] && ls -d "$PYTHON312_ROOT"/versions/3.12* >/dev/null 2>&1 \
    || die "no Python 3.12 under $PYTHON312_ROOT/versions. Fix: pyenv install 3.12, or set PYTHON312_ROOT."
[ "$(id -u)" -eq 0 ] || die "debootstrap and chroot need root. Fix: run with sudo."
command -v debootstrap >/dev/null || die "debootstrap is missing. Fix: apt-get install debootstrap."
if [ -z "${MIRROR:-}" ]; then
    MIRROR="$(cat /etc/apt/sources.list.d/*.sources 2>/dev/null | awk '/^URIs:/ {print $2; exit}')"
    [ -n "$MIRROR" ] || MIRROR="$(awk '/^deb / {print $2; exit}' /etc/apt/sources.list 2>/dev/null || true)"
    [ -n "$MIRROR" ] || die "no Debian mirror in the host's apt sources. Fix: set MIRROR=<debian mirror URL>."
fi

# The mounts are slaves of the host's: unmounting them here must never unmount the host's /dev/pts.
cleanup() {
    for m in "$ROOT$PYTHON312_ROOT" "$ROOT/sys" "$ROOT/proc" "$ROOT/dev"; do
        mountpoint -q "$m" && umount -R "$m" || true
    done
    if [ "${KEEP:-0}" != 1 ]; then rm -rf --one-file-system "$ROOT"; fi
}
trap cleanup EXIT

step() { echo "[fresh] $(date +%T) $*"; }
if [ ! -x "$ROOT/bin/bash" ]; then
    step "debootstrap $SUITE (minbase) into $ROOT"
    mkdir -p "$ROOT"
    debootstrap --variant=minbase \
        --include=git,ca-certificates,build-essential,libssl3,libffi8,libsqlite3-0,zlib1g,libbz2-1.0,liblzma5,libreadline8 \
        "$SUITE" "$ROOT" "$MIRROR" >"$ROOT.debootstrap.log" 2>&1 \
        || die "debootstrap failed; see $ROOT.debootstrap.log"
fi
mount -t proc proc "$ROOT/proc"
mount -t sysfs sys "$ROOT/sys"
mount --rbind /dev "$ROOT/dev" && mount --make-rslave "$ROOT/dev"
mkdir -p "$ROOT$PYTHON312_ROOT"
mount --bind "$PYTHON312_ROOT" "$ROOT$PYTHON312_ROOT" && mount -o remount,bind,ro "$ROOT$PYTHON312_ROOT"
cp /etc/resolv.conf "$ROOT/etc/resolv.conf"
cp /usr/local/share/ca-certificates/*.crt "$ROOT/usr/local/share/ca-certificates/" 2>/dev/null || true
# The host's bundle file sits in /usr/local/share/ca-certificates beside the single certificates: rehash warns.
chroot "$ROOT" update-ca-certificates 2>&1 >/dev/null | { grep -v '^rehash: warning' >&2 || true; }
[ -f /etc/pip.conf ] && cp /etc/pip.conf "$ROOT/etc/pip.conf"
[ -d /etc/xdg/pip ] && mkdir -p "$ROOT/etc/xdg" && cp -r /etc/xdg/pip "$ROOT/etc/xdg/"

step "cloning HEAD ($(git rev-parse --short HEAD)) into the root; uncommitted changes are not checked"
rm -rf "$ROOT/project" && git clone -q "$REPO" "$ROOT/project"

# Only the host's network and pip settings cross into the chroot's environment, not its PATH or venv.
env_keep=(HOME="$HOME" PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin HF_HUB_OFFLINE=1)
# setup.sh finds pyenv's Pythons under ~/.pyenv by itself; elsewhere it is told where the 3.12 is.
if [ "$PYTHON312_ROOT" != "$HOME/.pyenv" ]; then
    env_keep+=(PYTHON="$(ls -d "$PYTHON312_ROOT"/versions/3.12*/bin/python3 | sort -rV | head -1)")
fi
for v in $(compgen -e | grep -E '^(PIP_|SSL_CERT_|REQUESTS_CA_BUNDLE$|CURL_CA_BUNDLE$|https?_proxy$|HTTPS?_PROXY$|no_proxy$|NO_PROXY$)'); do
    env_keep+=("$v=${!v}")
done
in_root() { chroot "$ROOT" /usr/bin/env -i "${env_keep[@]}" /bin/bash -c "cd /project && $1"; }

step "scripts/setup.sh"
start=$SECONDS
in_root "./scripts/setup.sh"
step "setup.sh ok in $((SECONDS - start)) s"
step "pytest ${PYTEST_ARGS[*]}"
in_root ".venv/bin/python -m pytest -q -p no:cacheprovider ${PYTEST_ARGS[*]}"
step "fresh-machine check passed"
