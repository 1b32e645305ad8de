"""A free local TCP port, for a simulator and its bridge to meet on (demo, tests, benches).

ROS- and pymodbus-free, so tests and benches import it without either.
"""

from __future__ import annotations

import socket


def free_port() -> int:
    """A TCP port nothing listens on at 127.0.0.1 now (the OS's pick for a bind to port 0).

    Free when this returns, not reserved: the caller's simulator binds it soon after.
    """
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])
