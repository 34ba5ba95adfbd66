#!/usr/bin/env bash
# System libraries that pip cannot install but the project needs at run time:
#   FFmpeg's shared libraries  - torchcodec, LeRobot's video decoder. Without them every LeRobot command
#                                prints ~100 lines of libtorchcodec traceback and falls back to pyav.
#   OSMesa (libOSMesa.so)      - MuJoCo's offscreen OpenGL without a GPU (MUJOCO_GL=osmesa), used by the
#                                test that checks the ray-cast depth camera against a real OpenGL render.
# Installs what is missing with apt-get when it can (root, or password-less sudo); otherwise fails and names
# the packages. Called by scripts/setup.sh; usable on its own.
#   scripts/system_libs.sh           # install what is missing
#   scripts/system_libs.sh --check   # only report; exit 1 if something is missing
# LEROBOT_FOCAL_SKIP_SYSTEM_LIBS=1 turns a failure into a warning (e.g. no root on a shared machine): video
# decoding then falls back to pyav, and the OpenGL comparison test skips only while that variable is set.
set -euo pipefail

# ldconfig's output is read whole before grep: `ldconfig -p | grep -q` fails at random under pipefail (grep
# exits at the first match, ldconfig then dies of SIGPIPE). ldconfig lives in /sbin, which a Debian user's PATH
# lacks: without it every library would read as missing.
has_lib() {
    local libs
    libs="$(PATH="$PATH:/usr/sbin:/sbin" ldconfig -p 2>/dev/null || true)"
    grep -qE "$1" <<<"$libs"
}

# torchcodec supports FFmpeg 4 to 7 (libavutil 56 to 59); the Debian/Ubuntu package "ffmpeg" brings them.
ffmpeg_ok() { has_lib 'libavutil\.so\.(56|57|58|59) ' && has_lib 'libavformat\.so\.' && has_lib 'libavdevice\.so\.'; }
osmesa_ok() { has_lib 'libOSMesa\.so'; }

missing_packages() {
    local pkgs=()
    ffmpeg_ok || pkgs+=(ffmpeg)
    osmesa_ok || pkgs+=(libosmesa6)
    echo "${pkgs[@]:-}"
}

missing="$(missing_packages)"
if [ -z "$missing" ]; then
    echo "[setup] system libraries ok: FFmpeg (torchcodec), OSMesa (MuJoCo offscreen rendering)"
    exit 0
fi
if [ "${1:-}" = "--check" ]; then
    echo "missing system packages: $missing (install: apt-get install $missing, or run scripts/setup.sh)" >&2
    exit 1
fi

# apt's "debconf: delaying package configuration" note is noise; real errors still reach stderr.
quiet_debconf() { grep -v '^debconf: ' >&2 || true; }

as_root=()
if [ "$(id -u)" -ne 0 ]; then
    if command -v sudo >/dev/null 2>&1 && sudo -n true 2>/dev/null; then as_root=(sudo -n); else as_root=(none); fi
fi
if command -v apt-get >/dev/null 2>&1 && [ "${as_root[0]:-}" != none ]; then
    echo "[setup] installing system packages: $missing"
    apt_install() { "${as_root[@]}" env DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends "$@"; }
    # First try with the package lists as they are; its errors are dropped, since empty or stale lists (a fresh
    # container: "E: Unable to locate package") are what the update and retry fix. Neither attempt may end the
    # script under set -e: whether the libraries arrived is checked below, and a failure still reaches the
    # LEROBOT_FOCAL_SKIP_SYSTEM_LIBS warning or the error naming the packages.
    # shellcheck disable=SC2086
    if ! apt_install $missing >/dev/null 2>&1; then
        # shellcheck disable=SC2086
        { "${as_root[@]}" apt-get update -qq; apt_install $missing; } 2>&1 >/dev/null | quiet_debconf || true
    fi
    missing="$(missing_packages)"
    if [ -z "$missing" ]; then
        echo "[setup] system libraries ok: FFmpeg (torchcodec), OSMesa (MuJoCo offscreen rendering)"
        exit 0
    fi
fi

if [ "${LEROBOT_FOCAL_SKIP_SYSTEM_LIBS:-0}" = 1 ]; then
    echo "[setup] warning: continuing without $missing (LEROBOT_FOCAL_SKIP_SYSTEM_LIBS=1): LeRobot decodes video" \
         "with pyav after a torchcodec traceback, and tests/envs/test_pointcloud.py's OpenGL comparison is skipped" >&2
    exit 0
fi
echo "error: missing system packages: $missing" >&2
case " $missing " in *" ffmpeg "*) echo "  ffmpeg: FFmpeg 4-7 shared libraries for torchcodec (LeRobot's video decoder)" >&2 ;; esac
case " $missing " in *" libosmesa6 "*) echo "  libosmesa6: OSMesa, MuJoCo's offscreen OpenGL without a GPU" >&2 ;; esac
echo "Fix: sudo apt-get install $missing (other distributions: the FFmpeg and OSMesa libraries), then rerun;" >&2
echo "or set LEROBOT_FOCAL_SKIP_SYSTEM_LIBS=1 to continue without them." >&2
exit 1
