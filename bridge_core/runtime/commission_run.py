"""``bridge_commission``'s two phases, in plain Python (the command line, the parameters
and the signals are ``bridge_core.ros.commission``'s).

The read-only phase writes nothing and says so in its first line: it connects, times
``samples`` short reads (reply times: the ``timeout_s`` and poll rate recommended), lets
the bridge read its facts (``Commissioning.setup``), reads every readable row of the map
alone (the refusals listed), then runs every read-only check. The guided phase takes the
guided checks one at a time (none when the parameters say ``read_only: true``, as the
bridge refuses every write then): it prints what will move, how far and how to stop it, and
runs the step only when the operator types ``yes`` (anything else: "not run"). While a
step runs, any line (Enter, ``s``) or the end of the input stops it; the step's stop is
sent on every way out of it (its end, an error, Ctrl-C, SIGTERM, stdin closed).
"""

from __future__ import annotations

import dataclasses
import queue
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from ..wire.channel import Priority, RegisterIO
from ..wire.errors import DeviceException, LinkError
from ..wire.registers import Table
from .commission import (
    Check,
    Commissioning,
    Finding,
    Kind,
    Probe,
    Refusal,
    Report,
    Result,
    RowScan,
    Verdict,
    carried_poll_rate_hz,
    finish_recommendations,
    recommend_poll_rate_hz,
    recommend_timeout_s,
    reply_times,
)
from .parameters import POLL_RATE_RANGE_HZ

FIRST_LINE = "read-only phase: nothing is written to the device"
YES = "yes"
STOP_KEYS = "Enter or s"  # what the prompt names: any line stops a running step
PROMPT = f"type {YES} to run it, anything else skips it: "
STOP_WAIT_S = 0.05  # how often a step's wait looks at the stop key (``Operator.wait``)
# Rows in a row without a reply: the device is gone (each waited ``timeout_s``), the scan
# ends and the report says why (``DEVICE_LOST``).
SCAN_NO_REPLY_LIMIT = 3
DEVICE_LOST = "the device stopped answering"
EOF = None  # what a line source returns at the end of its input
# Why no guided step runs when the parameters given say read_only: true (the bridge would
# refuse every write; the tool does the same rather than write behind that setting).
READ_ONLY_REFUSAL = "read_only is true: nothing written (start without it to run the step)"


class Operator:
    """The operator's input: lines from ``read_line`` (``sys.stdin.readline`` without its
    newline; None at the end of the input), taken by a thread of their own so a running
    step sees a stop key at once. At a prompt the next line is the answer; while a step
    runs, any line or the end of the input asks it to stop."""

    def __init__(self, read_line: Callable[[], str | None]) -> None:
        self._lines: queue.Queue[str | None] = queue.Queue()
        self._read_line = read_line
        self.closed = False  # the input ended
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, name="operator", daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while True:
            line = self._read_line()
            self._lines.put(line)
            if line is EOF:
                return

    def ask(self, prompt: str, say: Callable[[str], None]) -> str | None:
        """The answer (stripped), or None when the input ended."""
        if self.closed:
            return None
        say(prompt)
        line = self._lines.get()
        if line is EOF:
            self.closed = True
            return None
        return line.strip()

    def start_step(self) -> None:
        self._stop.clear()
        while not self._lines.empty():  # typed ahead: not a stop of this step
            if self._lines.get_nowait() is EOF:
                self.closed = True

    def stop_requested(self) -> bool:
        """Any line typed since the step started, or the input's end (Ctrl-C and SIGTERM
        raise ``KeyboardInterrupt`` in the main thread instead)."""
        if self.closed:
            return True
        try:
            line = self._lines.get_nowait()
        except queue.Empty:
            return self._stop.is_set()
        if line is EOF:
            self.closed = True
        self._stop.set()
        return True

    def wait(self, seconds: float) -> bool:
        """Wait ``seconds`` unless a stop is asked for (True: asked)."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            if self.stop_requested():
                return True
            time.sleep(min(STOP_WAIT_S, max(deadline - time.monotonic(), 0.0)))
        return self.stop_requested()


# ---------------------------------------------------------------- read-only phase
def measure_replies(io: RegisterIO, ping: Callable[[RegisterIO], object], samples: int) -> Any:
    """``samples`` timed pings: their ``ReplyTimes``. Raises ``LinkError`` when the first
    one gets no reply (the device is not there)."""
    times: list[float] = []
    failures = 0
    for k in range(samples):
        started = time.perf_counter()
        try:
            ping(io)
        except LinkError:
            if k == 0:
                raise
            failures += 1
            continue
        times.append(time.perf_counter() - started)
    return reply_times(times, failures)


def scan_rows(commissioning: Commissioning, probe: Probe) -> RowScan:
    """Every readable row of the map, each alone (a string row: its whole length).
    ``SCAN_NO_REPLY_LIMIT`` rows in a row without a reply raise the last ``LinkError``."""
    scan = RowScan()
    silent = 0
    for reg in commissioning.register_map:
        if not reg.access.readable:
            continue
        try:
            if reg.table in (Table.COIL, Table.DISCRETE_INPUT):
                bits = probe.io.read_bits(reg.address, 1, reg.table, Priority.COMMAND)
                scan.answered[reg.name] = [int(b) for b in bits]
            else:
                scan.answered[reg.name] = probe.io.read_registers(
                    reg.address, reg.count, reg.table, Priority.COMMAND
                )
        except DeviceException as err:
            scan.refused.append(
                Refusal(
                    reg.name,
                    reg.address,
                    reg.table.value,
                    err.name,
                    commissioning.refusal_reason(reg, probe),
                )
            )
        except LinkError as err:
            silent += 1
            if silent >= SCAN_NO_REPLY_LIMIT:
                raise
            scan.refused.append(
                Refusal(reg.name, reg.address, reg.table.value, f"no reply ({err})", None)
            )
            continue
        silent = 0
    return scan


def run_read(check: Check, probe: Probe) -> Finding:
    assert check.read is not None
    try:
        return check.read(probe)
    except LinkError as err:
        return Finding(Verdict.UNCLEAR, f"a read failed: {err}")


def read_phase(
    commissioning: Commissioning,
    probe: Probe,
    report: Report,
    samples: int,
    timeout_low_s: float = 0.0,
) -> None:
    """Everything that only reads; raises ``LinkError`` if the device never answers.
    ``timeout_low_s``: the least ``timeout_s`` the bridge takes (its spec's)."""
    report.reply = times = measure_replies(probe.io, commissioning.ping, samples)
    probe.say(f"reply times: {times.text}")
    commissioning.setup(probe)
    report.facts.update(probe.facts)
    for key, value in probe.facts.items():
        probe.say(f"{key}: {value}")
    probe.rows = report.rows = scan_rows(commissioning, probe)
    probe.say(
        f"rows read: {len(probe.rows.answered)} answered, {len(probe.rows.refused)} refused "
        f"({len(probe.rows.unexpected)} unexpected)"
    )
    for refusal in probe.rows.unexpected:
        probe.say(f"  refused, not expected: {refusal.name} ({refusal.address}): {refusal.error}")
    requests = commissioning.requests_per_poll(probe)
    carried = carried_poll_rate_hz(times, requests)
    report.recommended["timeout_s"] = recommend_timeout_s(times, timeout_low_s)
    default_rate = float(probe.values.get("poll_rate_hz", POLL_RATE_RANGE_HZ[1]))
    report.recommended["poll_rate_hz"] = recommend_poll_rate_hz(
        carried, default_rate, POLL_RATE_RANGE_HZ[0]
    )
    report.facts["poll the line carries"] = (
        f"{carried:.1f} Hz ({requests} requests a poll at the median reply, one at a time)"
    )
    for check in commissioning.checks:
        if check.kind is Kind.READ:
            finding = run_read(check, probe)
            report.results.append(Result(check, finding))
            probe.say(f"{_label(commissioning, check)}: {finding.verdict.value}: {finding.seen}")


def _label(commissioning: Commissioning, check: Check) -> str:
    number = commissioning.checks.index(check) + 1
    return f"[{number}] {check.title}"


# ---------------------------------------------------------------- guided phase
def guided_phase(
    commissioning: Commissioning, probe: Probe, report: Report, operator: Operator | None
) -> None:
    """Each guided check after the operator's ``yes``; None (``--read-only``): none."""
    for check in commissioning.checks:
        if check.kind is not Kind.GUIDED:
            continue
        assert check.guided is not None
        label = _label(commissioning, check)
        if operator is None:
            report.results.append(Result(check, Finding(Verdict.NOT_RUN, "--read-only")))
            continue
        if probe.values.get("read_only") is True:
            # The bridge's own read_only: every write refused, so no step is offered.
            report.results.append(Result(check, Finding(Verdict.NOT_RUN, READ_ONLY_REFUSAL)))
            probe.say(f"{label}: not run ({READ_ONLY_REFUSAL})")
            continue
        step = check.guided
        numbers = ", ".join(map(str, check.decisions))
        probe.say(f"{label} (decision{'s' if len(check.decisions) > 1 else ''} {numbers})")
        probe.say(f"  what moves: {step.moves}")
        probe.say(f"  to stop it: {STOP_KEYS} here, or {step.stop_how}")
        answer = operator.ask(f"  {PROMPT}", probe.say)
        if answer != YES:
            why = "stdin closed" if answer is None else f"the operator answered {answer!r}"
            report.results.append(Result(check, Finding(Verdict.NOT_RUN, why)))
            probe.say(f"{label}: not run ({why})")
            continue
        operator.start_step()
        finding = run_step(step.run, step.send_stop, probe)
        report.results.append(Result(check, finding))
        probe.say(f"{label}: {finding.verdict.value}: {finding.seen}")


def run_step(
    run: Callable[[Probe], Finding], send_stop: Callable[[Probe], str], probe: Probe
) -> Finding:
    """One guided step; its stop goes out however the step ends (a ``KeyboardInterrupt``,
    Ctrl-C or SIGTERM, goes on up after it); the finding says what the stop read back.

    The step and its stop run on a thread of their own, so a Ctrl-C (raised in the main
    thread) never lands inside one of their Modbus transactions: cut short there, it could
    leave the link unable to send the stop (seen: the start written, no stop). The main
    thread waits; a ``KeyboardInterrupt`` there asks the step to stop (its ``probe.wait``
    and ``probe.stop_requested`` say so at once), waits for the stop to go out, then goes
    on up."""
    interrupted = threading.Event()
    done = threading.Event()  # not Thread.join: a KeyboardInterrupt in join can leave
    # the thread reported dead while it runs (a known CPython bug, bpo-45274)
    outcome: dict[str, Any] = {}
    asked, waited = probe.stop_requested, probe.wait

    def stop_requested() -> bool:
        return interrupted.is_set() or asked()

    def wait(seconds: float) -> bool:
        deadline = time.monotonic() + seconds
        while not stop_requested():
            left = deadline - time.monotonic()
            if left <= 0:
                return False
            if waited(min(left, STOP_WAIT_S)):
                return True
        return True

    def step() -> None:
        try:
            outcome["finding"] = run(probe)
        except LinkError as err:
            outcome["finding"] = Finding(Verdict.UNCLEAR, f"the step failed: {err}")
        except BaseException as err:  # KeyboardInterrupt from the step itself, or a bug
            outcome["error"] = err
        finally:
            try:
                said = send_stop(probe)
            except LinkError as err:
                said = f"the stop failed: {err}: stop it on the device"
            except BaseException as err:
                said = f"the stop failed: {err!r}: stop it on the device"
            outcome["said"] = said
            probe.say(f"  stop sent: {said}")
            done.set()

    probe.stop_requested, probe.wait = stop_requested, wait
    worker = threading.Thread(target=step, name="guided step", daemon=True)
    try:
        started = False
        while True:  # the interrupt may land anywhere, start() too: caught around all of it
            try:
                if not started:
                    started = True
                    worker.start()
                while not done.is_set():
                    done.wait(STOP_WAIT_S)
                break
            except KeyboardInterrupt:
                interrupted.set()
                outcome.setdefault("error", KeyboardInterrupt())
    finally:
        probe.stop_requested, probe.wait = asked, waited
    if "error" in outcome:
        raise outcome["error"]
    finding: Finding = outcome["finding"]
    return dataclasses.replace(finding, seen=f"{finding.seen}; then the stop: {outcome['said']}")


def not_run(commissioning: Commissioning, report: Report, why: str) -> None:
    """Every check without a result: not run (``why``); manual checks say so."""
    done = {r.check.key for r in report.results}
    for check in commissioning.checks:
        if check.key in done:
            continue
        reason = "a manual check: see the decisions page" if check.kind is Kind.MANUAL else why
        report.results.append(Result(check, Finding(Verdict.NOT_RUN, reason)))


def commission(
    commissioning: Commissioning,
    probe: Probe,
    report: Report,
    *,
    samples: int,
    operator: Operator | None,
    timeout_low_s: float = 0.0,
) -> Report:
    """Both phases, then the report's recommendations. Ctrl-C or SIGTERM
    (``KeyboardInterrupt``), or a device that stops answering, ends the run with what was
    found so far (``interrupted``); one that never answered raises ``LinkError``."""
    probe.say(FIRST_LINE)
    try:
        read_phase(commissioning, probe, report, samples, timeout_low_s)
        guided_phase(commissioning, probe, report, operator)
    except KeyboardInterrupt:
        report.interrupted = "Ctrl-C or SIGTERM"
    except LinkError as err:
        if report.reply is None:
            raise  # never answered: no report (the command line says so)
        report.interrupted = f"{DEVICE_LOST} ({err})"
    not_run(commissioning, report, report.interrupted or "not reached")
    order = {c.key: k for k, c in enumerate(commissioning.checks)}
    report.results.sort(key=lambda r: order[r.check.key])
    finish_recommendations(report)
    return report


def verdict_lines(report: Report) -> Sequence[str]:
    return [f"{r.finding.verdict.value:>14}  {r.check.title}" for r in report.results]


__all__ = [
    "DEVICE_LOST",
    "FIRST_LINE",
    "PROMPT",
    "Operator",
    "commission",
    "guided_phase",
    "measure_replies",
    "read_phase",
    "run_step",
    "scan_rows",
    "verdict_lines",
]
