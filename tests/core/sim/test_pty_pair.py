"""The socat pty pair: it goes away on close, even when SIGTERM is not enough."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from bridge_core.sim.pty_pair import PtyPair, end_socat

IGNORES_SIGTERM = (
    "import signal, sys, time\n"
    "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
    "print('ready', flush=True)\n"
    "time.sleep(60)\n"
)


def test_a_process_that_misses_sigterm_is_killed() -> None:
    proc = subprocess.Popen([sys.executable, "-c", IGNORES_SIGTERM], stdout=subprocess.PIPE)
    assert proc.stdout is not None
    assert proc.stdout.readline() == b"ready\n"  # its SIGTERM handler is set
    end_socat(proc, term_wait_s=0.2)
    assert proc.returncode == -9
    proc.stdout.close()


def test_close_removes_both_ends(tmp_path: Path) -> None:
    pair = PtyPair(tmp_path / "bridge")
    assert pair.link.exists() and pair.device_end.exists()
    pair.close()
    assert pair.proc.returncode is not None
    assert not pair.link.exists() and not pair.device_end.exists()
