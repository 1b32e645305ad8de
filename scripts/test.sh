#!/usr/bin/env bash
# Set up the environment (scripts/setup.sh, a quick no-op when nothing changed), then run
# pytest from the repo root; arguments are passed to pytest. ruff and mypy check the
# Python packages, tests/ and bench/ first (ruff only for launch/, ros/ and scripts/), and
# ruff format --check the whole tree (LINT=0 skips them).
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

bash scripts/setup.sh

# Keep ROS discovery on this machine (tests start nodes of their own).
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST

# The Python packages: bridge_core and every bridge (bridge_core.runtime.entries: the
# modbus_bridges.interface entry points of pyproject.toml).
mapfile -t PACKAGES < <(.venv/bin/python -c 'from bridge_core.runtime.entries import bridge_packages
print("bridge_core", *bridge_packages().values(), sep="\n")')
((${#PACKAGES[@]} > 1)) || { echo "test: no bridges found in pyproject.toml" >&2; exit 1; }

# The packages and tests compiled to bytecode once, into their __pycache__ (ignored by
# git): where Python is told not to write it (PYTHONDONTWRITEBYTECODE, as on the CI
# machine), each of the suite's ~500 processes would compile them again (~0.1 CPU-s each).
.venv/bin/python -m compileall -q -j 0 "${PACKAGES[@]}" tests bench >/dev/null

if [[ "${LINT:-1}" == 1 ]]; then
    # mypy's cache is kept per machine, not per checkout: mypy checks each cached module
    # against the hash of its source (a file of another path or time but the same text is
    # taken as is), so a fresh clone checks only what differs from the last run here:
    # ~1 s instead of ~11 s on 2 cores. MYPY_CACHE_DIR chooses another place.
    export MYPY_CACHE_DIR="${MYPY_CACHE_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/modbus-ros-bridges/mypy}"
    pkgs=()
    for p in "${PACKAGES[@]}"; do
        [[ -d "$p" ]] && pkgs+=("$p")
    done
    if ((${#pkgs[@]})); then
        echo "test: ruff check ${pkgs[*]}"
        .venv/bin/ruff check "${pkgs[@]}"
        echo "test: mypy ${pkgs[*]}"
        .venv/bin/mypy "${pkgs[@]}"
    fi
    extra=()
    for p in tests bench; do
        [[ -d "$p" ]] && extra+=("$p")
    done
    if ((${#extra[@]})); then
        echo "test: ruff check ${extra[*]}"
        .venv/bin/ruff check "${extra[@]}"
        echo "test: mypy ${extra[*]}"
        .venv/bin/mypy "${extra[@]}"
    fi
    echo "test: ruff check launch ros scripts"
    .venv/bin/ruff check launch ros scripts
    echo "test: ruff format --check"
    .venv/bin/ruff format --check
fi

# The 15 slowest tests are printed at the end of every run. The tests run in
# $TEST_WORKERS pytest-xdist worker processes (default 4: most tests wait on sockets, ptys
# and ROS discovery; 4 was 3 while each node process spent ~0.75 CPU-s importing, when two
# MOTEC bus tests missed their real-time margins beside two CPU burners. 5 were the default
# for a few runs on 2026-12-06: 342-390 s idle, but two of four runs beside two burners and
# one idle run failed on load-sensitive tests, so back to 4; docs/testing.md), grouped so
# that tests sharing a module-scoped fixture stay on one worker (tests/conftest.py);
# TEST_WORKERS=0 runs them in this process.
rc=0
.venv/bin/python -m pytest --durations=15 -n "${TEST_WORKERS:-4}" --dist loadgroup "$@" || rc=$?
if ((rc == 5)); then
    echo "test: pytest collected no tests; treating that as a failure" >&2
    exit 1
fi
exit "$rc"
