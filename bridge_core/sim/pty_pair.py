"""A pair of linked pseudo-terminals from socat: a serial line on one machine, for the
serial simulators' ``--pty`` and for tests."""

from __future__ import annotations

import shutil
import subprocess
import tempfile
import time
from pathlib import Path


class PtyPair:
    """Two linked pseudo-terminals from socat: ``link`` for the bridge, one for the server."""

    def __init__(self, link: Path) -> None:
        socat = shutil.which("socat")
        if socat is None:
            raise RuntimeError("--pty needs socat (apt-get install socat)")
        self._tmp = tempfile.TemporaryDirectory()
        self.link = link
        self.device_end = Path(self._tmp.name) / "device"
        self.proc = subprocess.Popen(
            [socat, f"pty,raw,echo=0,link={link}", f"pty,raw,echo=0,link={self.device_end}"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        deadline = time.monotonic() + 10
        while not (link.exists() and self.device_end.exists()):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.close()
                raise RuntimeError("socat did not create the pty pair")
            time.sleep(0.01)

    def close(self) -> None:
        end_socat(self.proc)
        self._tmp.cleanup()


SOCAT_TERM_WAIT_S = 5.0  # socat 1.7.4 now and then misses a SIGTERM (seen in CI): then SIGKILL


def end_socat(proc: subprocess.Popen[bytes], term_wait_s: float = SOCAT_TERM_WAIT_S) -> None:
    """Stop a socat pty pair: SIGTERM, and SIGKILL if it has not gone ``term_wait_s``
    later, so the ptys vanish either way."""
    if proc.poll() is not None:
        return
    proc.terminate()
    try:
        proc.wait(term_wait_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
