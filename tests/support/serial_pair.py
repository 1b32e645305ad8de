"""A real pseudo-terminal pair from Debian's socat, for RTU tests."""

from __future__ import annotations

import shutil
import subprocess
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def socat_pair() -> Iterator[tuple[str, str, subprocess.Popen[bytes]]]:
    """Two linked ptys: bytes written to one come out of the other."""
    socat = shutil.which("socat")
    if socat is None:
        raise RuntimeError("socat is missing: scripts/setup.sh installs it (apt-get install socat)")
    with tempfile.TemporaryDirectory() as tmp:
        a, b = Path(tmp) / "bridge", Path(tmp) / "device"
        proc = subprocess.Popen(
            [socat, f"pty,raw,echo=0,link={a}", f"pty,raw,echo=0,link={b}"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        try:
            deadline = time.monotonic() + 10
            while not (a.exists() and b.exists()):
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError("socat did not create the pty pair")
                time.sleep(0.01)
            yield str(a), str(b), proc
        finally:
            proc.terminate()
            proc.wait(5)
