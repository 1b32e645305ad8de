"""The fork server (tests/support/forkserver.py): a forked child is the program ``python -m``
runs, as the rest of the suite assumes. Each case runs the same command both ways and
compares what a test can see: exit code, standard output and error, process group."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support import forkserver
from tests.support.ros import ROOT, wait_for

PROBE = "tests.support.forkserver_probe"
TIMEOUT_S = 60.0


@pytest.fixture(autouse=True)
def forking(monkeypatch: pytest.MonkeyPatch) -> None:
    """These cases are about the fork server: on whatever BRIDGE_TESTS_FORKSERVER says."""
    monkeypatch.setattr(forkserver, "ENABLED", True)


def popen_run(args: list[str], env: dict[str, str], cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", PROBE, *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=TIMEOUT_S,
    )


@pytest.mark.parametrize(
    "args",
    [["exit", "0"], ["exit", "7"], ["raise"], ["interrupt"]],
    ids=lambda a: a[0] + "".join(a[1:]),
)
def test_a_forked_run_is_the_same_as_python_m(args: list[str], tmp_path: Path) -> None:
    """Exit code (an uncaught KeyboardInterrupt: killed by SIGINT, -2), output, the
    traceback's last line; argv, environment and working directory are the request's."""
    env = {**os.environ, "PROBE": "forked"}
    # PYTHONPATH: the probe is found from another working directory, as with python -m.
    env["PYTHONPATH"] = str(ROOT)
    forked = forkserver.run_module(PROBE, args, TIMEOUT_S, env=env, cwd=tmp_path)
    plain = popen_run(args, env, tmp_path)
    assert (forked.returncode, forked.stdout) == (plain.returncode, plain.stdout)
    assert f"argv={args} cwd={tmp_path} PROBE='forked'" in forked.stdout
    assert "main=__main__" in forked.stdout
    assert forked.stderr.splitlines()[-1] == plain.stderr.splitlines()[-1]
    assert "forkserver" not in forked.stderr.splitlines()[-1]


def test_sigint_reaches_the_program_and_its_exit_code_comes_back(tmp_path: Path) -> None:
    """SIGINT is the program's (Python's default handler), not the server's; a process
    group of its own when asked (the simulators are killed with their socat by group)."""
    out = (tmp_path / "out").open("wb")
    proc = forkserver.python_module(PROBE, ["wait"], stdout=out, process_group=True)
    assert isinstance(proc, forkserver.ForkedProcess)
    assert os.getpgid(proc.pid) != os.getpgid(0)
    wait_for(
        lambda: b"group leader=True" in (tmp_path / "out").read_bytes(), TIMEOUT_S, "the probe"
    )
    assert proc.poll() is None
    with pytest.raises(subprocess.TimeoutExpired):
        proc.wait(0.1)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(TIMEOUT_S) == 3
    assert proc.poll() == 3
    out.close()
    assert (tmp_path / "out").read_text().endswith("interrupted\n")


def test_a_child_whose_test_let_go_of_it_is_killed(tmp_path: Path) -> None:
    """A test process that drops its end (it died, or forgot the child) leaves no child
    running: the server SIGKILLs it."""
    out = (tmp_path / "out").open("wb")
    proc = forkserver.python_module(PROBE, ["wait"], stdout=out)
    assert isinstance(proc, forkserver.ForkedProcess)
    wait_for(lambda: b"group leader" in (tmp_path / "out").read_bytes(), TIMEOUT_S, "the probe")
    proc._status.close()

    def gone() -> bool:
        # Reaped between the open and the read, the read fails with ESRCH
        # (ProcessLookupError), not FileNotFoundError: both mean gone.
        try:
            with open(f"/proc/{proc.pid}/stat") as stat:
                return stat.read().split(") ", 1)[1].startswith("Z")  # reaped soon
        except (FileNotFoundError, ProcessLookupError):
            return True

    wait_for(gone, TIMEOUT_S, f"child {proc.pid} to be killed")
    out.close()
