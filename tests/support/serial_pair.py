"""A real pseudo-terminal pair from Debian's socat, for RTU tests."""

from __future__ import annotations

import subprocess
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from bridge_core.sim.pty_pair import PtyPair
from bridge_core.sim.serving import Simulator

# A pty's bytes wait for the kernel's flip-buffer worker: beside the suite and two CPU
# burners on the 2-core test machine, bench/stall_probe.py saw a byte echoed through a
# socat pair (and through one pty alone) take up to 2.07 s, all ptys at once, while
# loopback TCP took at most 54 ms (burners alone, or with the colcon build: 12 ms). A test
# whose subject is not the reply timeout gives a pty link this one, past such a stall.
PTY_REPLY_TIMEOUT_S = 5.0


@contextmanager
def socat_pair() -> Iterator[tuple[str, str, subprocess.Popen[bytes]]]:
    """Two linked ptys: bytes written to one come out of the other."""
    with tempfile.TemporaryDirectory() as tmp:
        pair = PtyPair(Path(tmp) / "bridge")
        try:
            yield str(pair.link), str(pair.device_end), pair.proc
        finally:
            pair.close()


@contextmanager
def served_on_pty(simulator: Simulator, baudrate: int) -> Iterator[str]:
    """``simulator`` serving the device end of a fresh pty pair; yields the bridge's end.

    The simulator is stopped (and the pair closed) on the way out.
    """
    with socat_pair() as (bridge_end, device_end, _):
        simulator.start_serial(device_end, baudrate)
        try:
            yield bridge_end
        finally:
            simulator.stop()
