"""Test-wide isolation: a ROS domain per test process, discovery on localhost only.

Set before anything imports rclpy, and inherited by every child process a test starts.
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bridge_core.wire.ports import free_port  # noqa: E402 (needs the path above)

# Fast DDS accepts domain ids 0-101 (and 215-232) with default ports; 1-100 by pid.
DOMAIN_IDS = 100
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % DOMAIN_IDS))
COLCON_TESTS = "tests/core/test_colcon_build.py"
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


def xdist_worker(config: pytest.Config) -> int | None:
    """This process's index among pytest-xdist's workers (``gw3`` -> 3), None if not one."""
    workerinput = getattr(config, "workerinput", None)
    if workerinput is None:
        return None
    return int(str(workerinput["workerid"]).removeprefix("gw"))


def pytest_configure(config: pytest.Config) -> None:
    """A ROS domain of its own for each xdist worker (they inherit the runner's): the
    runner's id plus the worker's index, so the workers of one run never share one."""
    worker = xdist_worker(config)
    if worker is not None:
        runner = int(os.environ["ROS_DOMAIN_ID"])
        os.environ["ROS_DOMAIN_ID"] = str((runner + worker) % DOMAIN_IDS + 1)


def shared_fixture(definition: Any) -> bool:
    """One of our fixtures (not pytest's, such as ``tmp_path_factory``) that outlives a test."""
    return bool(definition.baseid) and definition.scope != "function"


def worker_group(item: pytest.Item) -> str:
    """The tests one worker runs together (``--dist loadgroup``): those that share a
    module-scoped fixture (a bridge process, the demo) with the same parameters; any other
    test on its own (its nodeid), so a module of long independent cases spreads out. The
    colcon tests each alone, so they come last (below), their build at nice 19 meanwhile
    (tests/support/colcon.py)."""
    fixture_info = getattr(item, "_fixtureinfo", None)
    if item.nodeid.startswith(COLCON_TESTS):
        # Each alone: xdist hands out its larger groups first and the tests alone in their
        # order, so these (last in it) come last, when their build has had the longest.
        return item.nodeid
    if fixture_info is None or not any(
        shared_fixture(definitions[-1]) for definitions in fixture_info.name2fixturedefs.values()
    ):
        return item.nodeid
    module = item.nodeid.split("::", 1)[0]
    callspec = getattr(item, "callspec", None)
    if callspec is None:
        return module
    scoped = sorted(
        f"{name}={callspec.indices[name]}"  # the module-scoped fixtures' parameters only
        for name, definitions in fixture_info.name2fixturedefs.items()
        if name in callspec.params and shared_fixture(definitions[-1])
    )
    return f"{module}[{','.join(scoped)}]" if scoped else module


@pytest.hookimpl(trylast=True)  # after xdist's own, which no longer takes effect
def pytest_collection_modifyitems(session: pytest.Session, items: list[pytest.Item]) -> None:
    """The colcon tests last in the collection (in one process their build runs in the
    background meanwhile). Under xdist, each test in its worker group (``--dist
    loadgroup``): xdist hands out the colcon tests' group early, whatever its place.

    xdist 3.8 tells its scheduler a test's group by appending ``@group`` to the nodeid it
    reports, through ``item._nodeid``; pytest 9.2 builds the nodeid from ``item._id``, so
    that append is lost and every test is scheduled alone
    (https://github.com/pytest-dev/pytest-xdist/issues/1386, fix pending in its pull
    request 1388, which sets the structured id as done here). A pytest or xdist that
    changes this again fails here at collection, not silently."""
    items.sort(key=lambda item: item.nodeid.startswith(COLCON_TESTS))
    if xdist_worker(session.config) is None:
        return
    from _pytest.nodeid import NodeId

    for item in items:
        group = worker_group(item)
        if group == item.nodeid:
            continue  # a test alone: xdist's scope for a nodeid without a group
        item._id = NodeId.parse(f"{item.nodeid}@{group}")
        if not item.nodeid.endswith(f"@{group}"):
            raise pytest.UsageError(f"{item.nodeid}: cannot give it its xdist group {group}")


def pytest_collection_finish(session: pytest.Session) -> None:
    """Without xdist: start the colcon build now when its tests will run
    (tests/support/colcon.py). Under xdist the controller starts it (below)."""
    if xdist_worker(session.config) is not None:
        return
    if any(item.nodeid.startswith(COLCON_TESTS) for item in session.items):
        from .support.colcon import colcon_build

        colcon_build()


@pytest.hookimpl(optionalhook=True)
def pytest_configure_node(node: Any) -> None:
    """xdist controller, for each worker it starts: where the session's colcon build goes
    (its workspace is made now, the build started once a worker has collected its tests)."""
    from .support.colcon import WORKSPACE_INPUT, session_build

    node.workerinput[WORKSPACE_INPUT] = str(session_build().workspace)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_node_collection_finished(node: Any, ids: list[str]) -> None:
    """xdist controller: start the colcon build as soon as a worker has collected the
    colcon tests (the worker that takes them waits for the build's end)."""
    from .support.colcon import session_build

    build = session_build()
    if build.process is None and any(nodeid.startswith(COLCON_TESTS) for nodeid in ids):
        build.start()


def pytest_sessionfinish(session: pytest.Session) -> None:
    from .support.colcon import remove_colcon_build

    remove_colcon_build()
