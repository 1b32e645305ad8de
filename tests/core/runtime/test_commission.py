"""``bridge_commission``'s model and phases without a device (runtime.commission,
runtime.commission_run): reply-time statistics and what they recommend, the report's
three files, and the guided phase's rules (only ``yes`` runs a step, its stop goes out on
every way out). The tool against the R6 simulator: tests/r6/test_r6_commission.py."""

from __future__ import annotations

import json
import queue
import signal
import threading
import time
from typing import Any, cast

import pytest
import yaml  # type: ignore[import-untyped]

from bridge_core.runtime.commission import (
    TIMEOUT_FLOOR_S,
    Check,
    Commissioning,
    Finding,
    Guided,
    Kind,
    Probe,
    Report,
    Result,
    Verdict,
    carried_poll_rate_hz,
    percentile,
    recommend_poll_rate_hz,
    recommend_timeout_s,
    reply_times,
)
from bridge_core.runtime.commission_run import (
    DEVICE_LOST,
    Operator,
    commission,
    guided_phase,
    run_step,
)
from bridge_core.wire.channel import RegisterIO
from bridge_core.wire.errors import LinkTimeout
from bridge_core.wire.registers import DeviceLimits, Register, RegisterMap, ValueType

MAP = RegisterMap("t", (Register("a", 0, ValueType.U16, "test row"),), DeviceLimits())


class FakeIO:
    """Answers every read with zeros."""

    def read_registers(self, address: int, count: int, *_args: Any, **_kw: Any) -> list[int]:
        return [0] * count


IO = cast(RegisterIO, FakeIO())  # reads only: the rest of RegisterIO is never called


def test_percentiles_and_reply_times() -> None:
    samples = [i / 1000 for i in range(1, 101)]  # 1..100 ms
    assert percentile(sorted(samples), 50.0) == 0.050
    assert percentile(sorted(samples), 99.0) == 0.099
    times = reply_times(samples, failures=2)
    assert (times.count, times.failures, times.max_s) == (102, 2, 0.100)
    assert "p50 50.00 ms" in times.text


def test_the_timeout_follows_the_slowest_reply_within_its_bounds() -> None:
    fast = reply_times([0.001] * 10)
    assert recommend_timeout_s(fast, 0.01) == TIMEOUT_FLOOR_S
    slow = reply_times([0.040, 0.0501])  # 3 x 50.1 ms = 150.3 ms, rounded up
    assert recommend_timeout_s(slow, 0.01) == 0.16
    dead = reply_times([9.0])
    assert recommend_timeout_s(dead, 0.01) == 10.0  # TIMEOUT_MAX_S


def test_the_poll_rate_is_the_bridges_unless_the_line_carries_less() -> None:
    times = reply_times([0.005] * 10)  # 11 requests a poll: 55 ms, 18.2 Hz carried
    carried = carried_poll_rate_hz(times, 11)
    assert carried == pytest.approx(18.18, abs=0.01)
    assert recommend_poll_rate_hz(carried, 50.0, 0.1) == 9.0
    assert recommend_poll_rate_hz(1000.0, 50.0, 0.1) == 50.0


def test_a_check_is_read_only_or_guided_and_keys_do_not_repeat() -> None:
    guided = Guided("x", "y", lambda p: Finding(Verdict.CONFIRMED, ""), lambda p: "")
    with pytest.raises(ValueError, match="not both"):
        Check("k", "t", (1,), "", read=lambda p: Finding(Verdict.CONFIRMED, ""), guided=guided)
    assert Check("k", "t", (1,), "").kind is Kind.MANUAL
    with pytest.raises(ValueError, match="repeat"):
        Commissioning("t", "n", MAP, (Check("k", "t", (1,), ""),) * 2, lambda io: None, lambda p: 1)


def test_the_report_files() -> None:
    report = Report("r6", "r6_bridge", "tcp://h:502 unit 1", {"firmware": "x"})
    report.link = {"host": "h", "port": 502}
    report.recommended = {"timeout_s": 0.1, "m_boards": False}
    report.results = [Result(Check("k", "Title", (3,), ""), Finding(Verdict.CONTRADICTED, "saw"))]
    params = yaml.safe_load(report.params_yaml())
    assert params == {
        "/**/r6_bridge": {
            "ros__parameters": {"host": "h", "port": 502, "timeout_s": 0.1, "m_boards": False}
        }
    }
    data = json.loads(report.json_text())
    assert data["checks"][0]["verdict"] == "contradicted"
    assert "| Title | 3 | manual | **contradicted** |" in report.markdown()


class Steps:
    """A guided step that records what ran, and a line source fed by the test."""

    def __init__(
        self, raise_in_run: BaseException | None = None, enter_in_run: bool = False
    ) -> None:
        self.enter_in_run = enter_in_run  # the operator presses Enter once it runs
        self.ran = 0
        self.stops = 0
        self.raise_in_run = raise_in_run
        self.lines: queue.Queue[str | None] = queue.Queue()

    def run(self, probe: Probe) -> Finding:
        self.ran += 1
        if self.raise_in_run is not None:
            raise self.raise_in_run
        if self.enter_in_run:
            self.lines.put("")
        stopped = probe.wait(5.0)
        return Finding(Verdict.UNCLEAR if stopped else Verdict.CONFIRMED, "ran")

    def send_stop(self, _probe: Probe) -> str:
        self.stops += 1
        return "stopped"

    def commissioning(self) -> Commissioning:
        step = Guided("it moves", "the pendant", self.run, self.send_stop)
        return Commissioning(
            "t", "n", MAP, (Check("g", "G", (1,), "", guided=step),), lambda io: None, lambda p: 1
        )


def guided(steps: Steps, *lines: str | None, values: dict[str, Any] | None = None) -> Finding:
    for line in lines:
        steps.lines.put(line)
    operator = Operator(steps.lines.get)
    probe = Probe(IO, values or {}, say=lambda _line: None)
    probe.stop_requested, probe.wait = operator.stop_requested, operator.wait
    report = Report("t", "n", "here")
    guided_phase(steps.commissioning(), probe, report, operator)
    steps.lines.put(None)
    return report.results[0].finding


@pytest.mark.parametrize("answer", ["no", "y", "YES ", "", None])
def test_only_yes_runs_a_step(answer: str | None) -> None:
    steps = Steps()
    finding = guided(steps, answer)
    assert finding.verdict is Verdict.NOT_RUN
    assert (steps.ran, steps.stops) == (0, 0)


def test_read_only_offers_no_step_even_after_yes() -> None:
    """The bridge's read_only parameter given to the tool: no step runs, nothing is sent."""
    steps = Steps()
    finding = guided(steps, "yes", values={"read_only": True})
    assert finding.verdict is Verdict.NOT_RUN and "read_only" in finding.seen
    assert (steps.ran, steps.stops) == (0, 0)
    writable = Steps(enter_in_run=True)
    guided(writable, "yes", values={"read_only": False})
    assert (writable.ran, writable.stops) == (1, 1)


def test_yes_runs_it_a_line_stops_it_and_the_stop_goes_out() -> None:
    steps = Steps(enter_in_run=True)
    finding = guided(steps, "yes", "")  # a line typed ahead is no stop; Enter while it runs is
    assert finding.verdict is Verdict.UNCLEAR
    assert (steps.ran, steps.stops) == (1, 1)


def test_ctrl_c_in_a_step_sends_its_stop_and_ends_the_run() -> None:
    steps = Steps(raise_in_run=KeyboardInterrupt())
    steps.lines.put("yes")
    operator = Operator(steps.lines.get)
    report = Report("t", "n", "here")
    probe = Probe(IO, {}, say=lambda _line: None)
    commission(steps.commissioning(), probe, report, samples=10, operator=operator)
    steps.lines.put(None)
    assert steps.stops == 1
    assert report.interrupted
    assert report.results[0].finding.verdict is Verdict.NOT_RUN
    assert report.recommended["timeout_s"] == TIMEOUT_FLOOR_S


class Transaction:
    """A step whose run is inside a (slow) Modbus transaction when Ctrl-C comes."""

    def __init__(self) -> None:
        self.started = threading.Event()
        self.completed = False
        self.stops = 0

    def run(self, probe: Probe) -> Finding:
        self.started.set()
        time.sleep(0.3)  # the transaction: a KeyboardInterrupt here would cut it short
        self.completed = True
        stopped = probe.wait(5.0)
        return Finding(Verdict.UNCLEAR if stopped else Verdict.CONFIRMED, "ran")

    def send_stop(self, _probe: Probe) -> str:
        self.stops += 1
        return "stopped"


def test_ctrl_c_never_lands_inside_a_steps_transaction() -> None:
    """SIGINT while the step's transaction is under way: the transaction ends whole (the
    step runs on a thread of its own, the main thread only waits), the step is asked to
    stop, its stop goes out, and the interrupt goes on up."""
    step = Transaction()
    probe = Probe(IO, {}, say=lambda _line: None)

    def interrupt() -> None:
        step.started.wait(5.0)
        signal.raise_signal(signal.SIGINT)  # Python's handler runs in the main thread

    threading.Thread(target=interrupt, daemon=True).start()
    with pytest.raises(KeyboardInterrupt):
        run_step(step.run, step.send_stop, probe)
    assert step.completed and step.stops == 1


class DyingIO:
    """Answers ``answers`` reads, then never again (a cable pulled)."""

    def __init__(self, answers: int) -> None:
        self.left = answers

    def read_registers(self, address: int, count: int, *_args: Any, **_kw: Any) -> list[int]:
        if self.left <= 0:
            raise LinkTimeout("no reply within 0.5 s")
        self.left -= 1
        return [0] * count


ROWS = RegisterMap(
    "t", tuple(Register(f"r{i}", i, ValueType.U16, "test row") for i in range(5)), DeviceLimits()
)


@pytest.mark.parametrize("answers", [0, 10])
def test_a_device_that_stops_answering_ends_the_run(answers: int) -> None:
    """Never answered: ``LinkError`` (no report). Gone after the reply times: the row scan
    gives up after SCAN_NO_REPLY_LIMIT silent rows and the report says why."""
    commissioning = Commissioning(
        "t", "n", ROWS, (), lambda io: io.read_registers(0, 1), lambda p: 1
    )
    probe = Probe(cast(RegisterIO, DyingIO(answers)), {}, say=lambda _line: None)
    report = Report("t", "n", "here")
    if not answers:
        with pytest.raises(LinkTimeout):
            commission(commissioning, probe, report, samples=10, operator=None)
        return
    commission(commissioning, probe, report, samples=10, operator=None)
    assert report.interrupted.startswith(DEVICE_LOST)
