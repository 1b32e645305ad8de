"""Test-wide isolation: a ROS domain per test process, discovery on localhost only.

Set before anything imports rclpy, and inherited by every child process a test starts.
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bridge_core.wire.ports import free_port  # noqa: E402 (needs the path above)

# Fast DDS accepts domain ids 0-101 (and 215-232) with default ports; 1-100 by pid.
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.pop("ROS_LOCALHOST_ONLY", None)
# Ctrl-C as a terminal gives it, whatever the runner left: a shell that starts the suite in
# the background without job control sets SIGINT to ignored, every child inherits that,
# and the tests that send SIGINT to a node or the demo would see it do nothing. Python's
# handler is reset to the default at exec, so the children get Ctrl-C back too.
signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def port() -> int:
    return free_port()


def pytest_collection_finish(session: pytest.Session) -> None:
    """Start the colcon build now when its tests will run (tests/support/colcon.py)."""
    if any(item.nodeid.startswith("tests/test_colcon_build.py") for item in session.items):
        from .support.colcon import colcon_build

        colcon_build()


def pytest_sessionfinish(session: pytest.Session) -> None:
    from .support.colcon import remove_colcon_build

    remove_colcon_build()
