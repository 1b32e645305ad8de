#!/usr/bin/env bash
# Set everything up (scripts/setup.sh), then run the bridges against their simulators and
# print live state until Ctrl-C (or for --duration SECONDS). Everything stays on this
# machine: the demo limits ROS discovery to localhost itself.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
bash "$ROOT/scripts/setup.sh"
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
cd "$ROOT"
exec "$ROOT/.venv/bin/python" -m bridge_core.ros.demo "$@"
