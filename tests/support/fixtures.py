"""The one client fixture of the ROS tests, made by a factory: a module says
``client = client_fixture("my_client", diagnostics=True, log=True)`` instead of writing the
same ``with ros_client(...) as c: ... yield c`` again."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Literal

import pytest
from diagnostic_msgs.msg import DiagnosticArray

from .ros import Client, ros_client


def client_fixture(
    name: str = "test_client",
    *,
    diagnostics: bool = False,
    log: bool = False,
    scope: Literal["function", "module"] = "function",
) -> Callable[[], Iterator[Client]]:
    """A fixture named ``client``: a ``Client`` named ``name``, subscribed to
    ``/diagnostics`` and/or the log (``/rosout``) when asked, closed after its ``scope``
    (a module's tests share one; ``function``: a fresh one per test, carrying no earlier
    test's subscriptions, discovery or log history)."""

    @pytest.fixture(scope=scope, name="client")
    def client() -> Iterator[Client]:
        with ros_client(name) as c:
            if diagnostics:
                c.subscribe(DiagnosticArray, "/diagnostics")
            if log:
                c.subscribe_log()
            yield c

    return client
