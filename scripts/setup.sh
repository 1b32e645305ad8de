#!/usr/bin/env bash
# Set up (or refresh) the development environment in .venv at the repo root:
#   - system packages the project needs (socat; a C/C++ compiler, cmake and Python headers
#     to build msg_defs), installed with apt-get only when missing;
#   - .venv with this project installed editable with its `ros` and `dev` extras (ROS 2
#     Jazzy from the PyPI wheels, pytest, ruff, mypy);
#   - the msg_defs interface package built and installed into .venv.
# Idempotent: .venv/.setup-stamp records a hash of the inputs of each part, and a part whose
# inputs did not change is skipped, so a repeated run is a quick no-op:
#   env      pyproject.toml, this script, the Python version, which packages exist
#   msg_defs msg_defs/** (except msg_defs/build), this script
# Set PYTHON to choose the interpreter (>= 3.11; default python3).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
VENV="$ROOT/.venv"
STAMP="$VENV/.setup-stamp"
# msg_defs's CMake build directory, kept between builds (see the msg_defs step).
MSG_DEFS_BUILD="$VENV/build/msg_defs"
LOG="$VENV/setup.log"
PY="${PYTHON:-python3}"

log() { printf 'setup: %s\n' "$*"; }
die() { printf 'setup: ERROR: %s\n' "$*" >&2; exit 1; }

# Run a step with its output going to $LOG; show the tail of the log when it fails.
step() {
    local what="$1" start=$SECONDS; shift
    log "$what"
    printf '\n==== %s: %s\n' "$what" "$*" >>"$LOG"
    if ! "$@" >>"$LOG" 2>&1; then
        printf 'setup: ERROR: %s failed; last lines of %s:\n' "$what" "$LOG" >&2
        tail -n 60 "$LOG" >&2
        exit 1
    fi
    log "  ... $((SECONDS - start)) s"
}

# One set-up at a time per checkout (test runs may be started in parallel).
if command -v flock >/dev/null 2>&1; then
    LOCK="${TMPDIR:-/tmp}/modbus-ros-bridges-setup-$(printf '%s' "$ROOT" | cksum | cut -d' ' -f1).lock"
    exec 9>"$LOCK"
    flock 9
fi

# --- Hashes of the inputs ----------------------------------------------------------------
hash_files() {  # sha256 over the contents and names of the files under the given paths
    find "$@" -path msg_defs/build -prune -o -type f -print0 \
        | LC_ALL=C sort -z | xargs -0 sha256sum | sha256sum | cut -d' ' -f1
}
env_hash() {
    {
        "$PY" --version 2>&1
        for p in */__init__.py; do echo "package ${p%/__init__.py}"; done
        hash_files pyproject.toml scripts/setup.sh scripts/ament_index.py ros
    } | sha256sum | cut -d' ' -f1
}
ENV_HASH="env $(env_hash)"
MSG_HASH="msg_defs $(hash_files msg_defs scripts/setup.sh)"
stamped() { [[ -f "$STAMP" ]] && grep -qxF "$1" "$STAMP"; }
msg_defs_installed() {
    compgen -G "$VENV/lib/python3*/site-packages/msg_defs/msg/__init__.py" >/dev/null
}

if [[ -x "$VENV/bin/python" ]] && stamped "$ENV_HASH" && stamped "$MSG_HASH" \
    && msg_defs_installed; then
    log "up to date ($VENV)"
    exit 0
fi

if [[ -x "$VENV/bin/python" ]] && ! "$VENV/bin/python" -c 'import sys' >/dev/null 2>&1; then
    log "removing broken $VENV"
    rm -rf "$VENV"
fi
mkdir -p "$VENV"
: >"$LOG"
touch "$STAMP"

# --- System packages ---------------------------------------------------------------------
command -v "$PY" >/dev/null 2>&1 || die "$PY not found; install Python >= 3.11 or set PYTHON"
"$PY" -c 'import sys; sys.exit(sys.version_info < (3, 11))' \
    || die "$("$PY" --version 2>&1) is too old; Python >= 3.11 is needed (set PYTHON)"
PYVER="$("$PY" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')"

apt_pkgs=()
command -v socat >/dev/null 2>&1 || apt_pkgs+=(socat)
command -v c++ >/dev/null 2>&1 || apt_pkgs+=(g++)
command -v cmake >/dev/null 2>&1 || apt_pkgs+=(cmake)
"$PY" -c 'import ensurepip, venv' >/dev/null 2>&1 || apt_pkgs+=("python$PYVER-venv")
"$PY" -c 'import os, sys, sysconfig
sys.exit(not os.path.isfile(os.path.join(sysconfig.get_config_var("INCLUDEPY"), "Python.h")))' \
    || apt_pkgs+=("python$PYVER-dev")
if ((${#apt_pkgs[@]})); then
    SUDO=()
    if [[ "$(id -u)" != 0 ]]; then
        command -v sudo >/dev/null 2>&1 || die "need root or sudo to apt-get install ${apt_pkgs[*]}"
        SUDO=(sudo)
    fi
    step "apt-get update" "${SUDO[@]}" apt-get update
    step "apt-get install ${apt_pkgs[*]}" "${SUDO[@]}" env DEBIAN_FRONTEND=noninteractive \
        apt-get install -y --no-install-recommends "${apt_pkgs[@]}"
fi

# --- Virtual environment and the project ---------------------------------------------------
VPY="$VENV/bin/python"
PIP=("$VPY" -m pip --disable-pip-version-check)
# uv installs the packages (pip took 45-60 s for the ~200 wheels on the 2-core machine,
# downloading them again each time; uv 7 s with an empty cache, ~2 s with its cache). uv
# reads its own settings (uv.toml, UV_* variables), not pip's configuration.
UV_VERSION=0.13.8
UV=("$VENV/bin/uv" pip)
# --compile-bytecode: uv leaves the .pyc files out unless asked (pip writes them), and on a
# machine that tells Python not to write them (PYTHONDONTWRITEBYTECODE) every process would
# then compile rclpy, numpy and the message packages from source again.
UV_INSTALL=(install --compile-bytecode --python "$VPY")
# The venv starts without pip (ensurepip took 4-5 s of a fresh clone's set-up): the
# interpreter's own pip installs uv into it when it can install into another environment
# (pip >= 22.3, --python: ~2 s), else the venv gets pip first, as before. pip itself comes
# only when msg_defs is built (below).
BASE_PIP_OK=0
"$PY" -c 'import sys
from importlib.metadata import version
sys.exit(tuple(int(p) for p in version("pip").split(".")[:2]) < (22, 3))' >/dev/null 2>&1 \
    && BASE_PIP_OK=1
if [[ ! -x "$VPY" ]]; then
    venv_args=()
    if ((BASE_PIP_OK)); then venv_args=(--without-pip); fi
    step "creating .venv with $("$PY" --version 2>&1)" "$PY" -m venv "${venv_args[@]}" "$VENV"
fi
if ! "$VENV/bin/uv" --version 2>/dev/null | grep -qxF "uv $UV_VERSION"; then
    if ((BASE_PIP_OK)); then
        step "installing uv $UV_VERSION into .venv" "$PY" -m pip --disable-pip-version-check \
            --python "$VPY" install "uv==$UV_VERSION"
    else
        "$VPY" -m pip --version >/dev/null 2>&1 || step "installing pip into .venv" "$VPY" -m ensurepip
        step "installing uv $UV_VERSION into .venv" "${PIP[@]}" install "uv==$UV_VERSION"
    fi
fi

if ! stamped "$ENV_HASH"; then
    # msg_defs is built with --no-build-isolation, so its build requirements are installed
    # into the venv (most of them are ROS wheels the runtime needs anyway). Measured here:
    # ~30 s per msg_defs build this way, ~55 s with pip's default isolated build (which
    # installs ~60 ROS wheels into a throw-away environment every time); a plain
    # `pip install ./msg_defs` works too. The list is read from msg_defs/pyproject.toml so
    # the two never drift apart.
    mapfile -t BUILD_REQS < <("$VPY" -c '
import tomllib
with open("msg_defs/pyproject.toml", "rb") as f:
    print("\n".join(tomllib.load(f)["build-system"]["requires"]))')
    ((${#BUILD_REQS[@]})) || die "no build requirements found in msg_defs/pyproject.toml"
    step "installing modbus-ros-bridges[ros,dev] (editable) and msg_defs build requirements" \
        "${UV[@]}" "${UV_INSTALL[@]}" -e ".[ros,dev]" "${BUILD_REQS[@]}"
    step "marking the bridges in the ament index (ros2 run)" "$VPY" scripts/ament_index.py
    { grep '^msg_defs ' "$STAMP" || true; echo "$ENV_HASH"; } >"$STAMP.new"
    mv "$STAMP.new" "$STAMP"
fi

# --- msg_defs ----------------------------------------------------------------------------
# Rebuilt when its sources changed, or when it no longer imports (e.g. the env step above
# replaced the ROS wheels it was built against).
#
# What rclpy needs only (MSG_DEFS_PYTHON_ONLY: the C type supports and the Python
# bindings, not the C++ ones), with no optimisation flags, as colcon builds by default
# (CMAKE_BUILD_TYPE empty), as a unity build (CMAKE_UNITY_BUILD: the generated sources of a
# target compiled a few at a time, their shared headers read once). Measured on 2 idle
# cores: 113 CPU-s and 76 s, 88 CPU-s and 64-79 s as a unity build (the wall time is
# rosidl's code generators, Python run one after the other), ~155 s for the whole package
# as a Release build. The CMake build directory stays in $MSG_DEFS_BUILD: a later build
# compiles only what changed, and the colcon test (tests/support/colcon.py) builds
# msg_defs there, adding the C++ type supports, so no file is compiled twice.
# scikit-build-core runs make without -j (it sets a parallel level only for Ninja): one
# compiler per core.
#
# The wheel is kept in $MSG_DEFS_CACHE under a hash of everything it is built from (the
# msg_defs sources, the build options, the Python and the venv's packages: the ROS wheels
# and numpy whose headers the bindings compile against), so a fresh clone on a machine that
# built the same msg_defs before installs it in a second instead of ~70 s (as pip keeps
# the wheels it builds from source distributions). MSG_DEFS_CACHE= (empty) builds anyway.
MSG_DEFS_OPTIONS=(-C cmake.build-type= -C cmake.define.MSG_DEFS_PYTHON_ONLY=ON
    -C cmake.define.CMAKE_UNITY_BUILD=ON)
MSG_DEFS_CACHE="${MSG_DEFS_CACHE-${XDG_CACHE_HOME:-$HOME/.cache}/modbus-ros-bridges/msg_defs}"
if ! stamped "$MSG_HASH" || ! msg_defs_installed \
    || ! "$VPY" -c 'import msg_defs.msg, msg_defs.srv, msg_defs.action' >/dev/null 2>&1; then
    wheel_key="$({
        hash_files msg_defs
        echo "${MSG_DEFS_OPTIONS[*]}"
        "$VPY" -c 'import sys, sysconfig; print(sys.version, sysconfig.get_platform())'
        # (not pip: it is added only for a build, below, and builds the same wheel)
        "${UV[@]}" freeze --python "$VPY" | grep -v -i -e '^msg[-_]defs' -e '^-e ' -e '^pip=='
    } | sha256sum | cut -c1-32)"
    cached=""
    if [[ -n "$MSG_DEFS_CACHE" ]]; then
        cached="$(compgen -G "$MSG_DEFS_CACHE/$wheel_key/msg_defs-*.whl" | head -n 1 || true)"
    fi
    if [[ -n "$cached" ]]; then
        step "installing msg_defs built before (${cached/#$HOME/\~})" \
            "${UV[@]}" "${UV_INSTALL[@]}" --reinstall --no-deps "$cached"
    else
        "$VPY" -m pip --version >/dev/null 2>&1 \
            || step "installing pip into .venv" "$VENV/bin/uv" pip install --python "$VPY" pip
        wheels="$VENV/build/msg_defs-wheel"
        rm -rf "$wheels"
        step "building msg_defs" \
            env CMAKE_BUILD_PARALLEL_LEVEL="${CMAKE_BUILD_PARALLEL_LEVEL:-$(nproc)}" \
            "${PIP[@]}" wheel --no-build-isolation --no-deps -w "$wheels" \
            -C build-dir="$MSG_DEFS_BUILD" "${MSG_DEFS_OPTIONS[@]}" ./msg_defs
        built="$(compgen -G "$wheels/msg_defs-*.whl" | head -n 1)"
        step "installing msg_defs into .venv" \
            "${UV[@]}" "${UV_INSTALL[@]}" --reinstall --no-deps "$built"
        if [[ -n "$MSG_DEFS_CACHE" ]]; then
            # Into place whole or not at all (two set-ups may run at once on one machine).
            mkdir -p "$MSG_DEFS_CACHE"
            tmp="$(mktemp -d "$MSG_DEFS_CACHE/.new.XXXXXX")"
            cp "$built" "$tmp/" && mv -T "$tmp" "$MSG_DEFS_CACHE/$wheel_key" 2>/dev/null \
                || rm -rf "$tmp"
        fi
    fi
    step "checking msg_defs" "$VPY" -c '
import msg_defs.msg, msg_defs.srv
from rclpy.serialization import deserialize_message, serialize_message
m = msg_defs.msg.R6State(mode=2, io_board_inputs=[1, 2])
assert deserialize_message(serialize_message(m), msg_defs.msg.R6State) == m'
    { grep '^env ' "$STAMP" || true; echo "$MSG_HASH"; } >"$STAMP.new"
    mv "$STAMP.new" "$STAMP"
fi

log "done ($VENV)"
