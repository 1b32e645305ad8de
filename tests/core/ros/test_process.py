"""bridge_core/ros/process.py: a command line rcl refuses is one line and exit code 2;
only the first signal interrupts, and at once whichever thread takes it.

rclpy.init raises before any node exists, so ``spin_node`` runs here in the test's own
process (the exit-2 path of a whole bridge process is tests/core/ros/test_contract.py's)."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import pytest
from rclpy.node import Node

from bridge_core.ros.process import EXIT_CONFIGURATION_ERROR, _ThreadEnd, spin_node

ROOT = Path(__file__).resolve().parents[3]


def never_built() -> Node:
    raise AssertionError("a node was built for a command line rcl refused")


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--ros-args", "--help"], "'--help'"),
        (["--ros-args", "-p", "host"], "'-p host'"),
        (["--ros-args", "-p", "host:=[1,"], "'-p host:=[1,'"),
        (["--ros-args", "-r", "bad"], "'-r bad'"),
        (["--ros-args", "--params-file", "{missing}"], "missing.yaml"),
        (["--ros-args", "--params-file", "{malformed}"], "malformed.yaml"),
    ],
    ids=["unknown", "parameter", "value", "remap", "missing-file", "malformed-yaml"],
)
def test_a_refused_command_line_is_one_line_and_exit_2(
    args: list[str], named: str, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    malformed = tmp_path / "malformed.yaml"
    malformed.write_text("r6_bridge:\n  ros__parameters: [host: 1\n")
    paths = {"missing": str(tmp_path / "missing.yaml"), "malformed": str(malformed)}
    code = spin_node(never_built, [arg.format(**paths) for arg in args])
    out, err = capfd.readouterr()
    lines = [line for line in (out + err).splitlines() if line.strip()]
    assert code == EXIT_CONFIGURATION_ERROR, lines
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    assert named in lines[0] and "Traceback" not in lines[0], lines
    assert ", at /" not in lines[0], lines  # rcl's source places are dropped


# In a process of its own: the handlers are the process's.
SIGNALS_TWICE = """
import os, signal, time
from bridge_core.ros.process import interrupt_on_signals
interrupt_on_signals()
raised = []
for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGINT):
    try:
        os.kill(os.getpid(), sig)
        time.sleep(0.01)  # the handler runs here at the latest
    except KeyboardInterrupt:
        raised.append(sig.name)
print(raised)
"""


def test_only_the_first_signal_interrupts() -> None:
    """A second Ctrl-C (or a SIGTERM after it) while the bridge is already stopping raises
    nothing: raised in the exit's ``finally``, it would cut the stops short."""
    result = subprocess.run(
        [sys.executable, "-c", SIGNALS_TWICE],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "['SIGINT']", result.stdout


# The signal goes to the executor's thread, not the main one (the kernel may hand a
# process's signal to any thread): the main thread must still raise at once.
SIGNAL_TO_THE_SPIN_THREAD = """
import os, signal, threading, time
import rclpy
from rclpy.executors import MultiThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from bridge_core.ros.process import _spin_until_interrupted, interrupt_on_signals

rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
interrupt_on_signals()
executor = MultiThreadedExecutor()
# A timer, as a bridge's poll has: the woken spin thread ends at its next callback.
node = Node("signal_probe")
node.create_timer(0.05, lambda: None)
executor.add_node(node)


def send() -> None:
    spinner = None
    while spinner is None:
        time.sleep(0.01)
        spinner = next((t for t in threading.enumerate() if t.name == "executor"), None)
    signal.pthread_kill(spinner.ident, signal.SIGINT)
    time.sleep(NOT_RAISED_S)
    print("not raised", flush=True)
    os._exit(3)


threading.Thread(target=send, daemon=True).start()
try:
    _spin_until_interrupted(executor)
except KeyboardInterrupt:
    print("raised", flush=True)
executor.shutdown()
node.destroy_node()
rclpy.try_shutdown()
"""
NOT_RAISED_S = 10.0  # how long the script waits for the main thread before it says no
WAIT_S = 30.0
LATE_WORD_S = 3.0  # when a wait that missed the thread's word is woken


def test_a_signal_taken_by_another_thread_still_interrupts_at_once() -> None:
    """SIGINT handled by the spin thread: the main thread, waiting for the executor to end,
    still raises KeyboardInterrupt (it waited in Thread.join until the next signal)."""
    script = SIGNAL_TO_THE_SPIN_THREAD.replace("NOT_RAISED_S", repr(NOT_RAISED_S))
    result = subprocess.run(
        [sys.executable, "-c", script],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=60 + NOT_RAISED_S,
    )
    assert result.stdout.strip() == "raised", (result.returncode, result.stdout, result.stderr)
    assert result.returncode == 0, result.stderr


def test_the_wait_ends_at_the_threads_word_while_it_still_runs() -> None:
    """The spin thread says it ended a moment before it has: the main thread's wait ends
    at its word (a wait that looked at ``is_alive()`` then went back to sleep for good:
    a fatal error's exit hung beside two CPU burners)."""
    ended = _ThreadEnd()
    release = threading.Event()

    def work() -> None:
        ended.tell()
        release.wait(WAIT_S)

    def later() -> None:  # bounds a wait that missed the word: wakes it with the thread gone
        release.set()
        worker.join()
        ended.tell()

    worker = threading.Thread(target=work)
    timer = threading.Timer(LATE_WORD_S, later)
    with ended:
        worker.start()
        timer.start()
        ended.wait()
        assert worker.is_alive(), "the wait ended only once the thread had"
    release.set()
    timer.cancel()
    worker.join()
    timer.join()


# A signal the process got and no thread has taken yet (blocked here, as it is for the
# instant before a thread runs its handler): a poll that finds its link closed by the
# same Ctrl-C must count the process as exiting.
SIGNAL_PENDING = """
import os, signal
# Blocked before the import: the threads rclpy's import starts inherit the mask (one that
# did not would take the signal).
signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
from bridge_core.ros.process import _exit_signal_pending
before = _exit_signal_pending()
os.kill(os.getpid(), signal.SIGINT)
print(before, _exit_signal_pending())
"""


def test_a_signal_not_yet_taken_counts_as_exiting() -> None:
    result = subprocess.run(
        [sys.executable, "-c", SIGNAL_PENDING], cwd=ROOT, capture_output=True, text=True, timeout=60
    )
    assert result.stdout.split() == ["False", "True"], (result.stdout, result.stderr)


def test_a_signal_the_wakeup_fd_got_counts_as_exiting() -> None:
    """The C handler ran (its byte is on the wakeup fd) but the Python one not yet: the
    byte tells; the thread's own word (0) does not."""
    ended = _ThreadEnd()
    assert not ended.signalled()
    ended.tell()  # the thread's word
    assert not ended.signalled()
    ended._writer.send(bytes([2]))  # what the C handler writes for SIGINT
    assert ended.signalled()
    ended.__exit__()
