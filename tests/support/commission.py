"""The operator of ``bridge_commission`` in the tests (tests/<bridge>/test_<bridge>_commission.py
run the tool in-process with ``read_line`` and ``say``): a script of answers, each given
at its cue, and the report's verdicts by check."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from bridge_core.runtime.commission_run import PROMPT

from .ros import WAIT_S, wait_for


class Script:
    """The operator: each line is given once its condition holds (a prompt was said, or a
    callable of the simulator's state, polled); None is the end of the input. After the
    last line the input stays open (nothing typed) until ``close``. ``on_say`` sees every
    line the tool says (a test may change the simulator at a given point of the run)."""

    def __init__(self, *steps: tuple[Callable[[], bool] | str, str | None]) -> None:
        self.said: list[str] = []
        self.on_say: Callable[[str], None] = lambda _line: None
        self._steps = list(steps)
        self._changed = threading.Condition()
        self._prompts_seen = 0
        self._prompts_used = 0
        self._closed = threading.Event()

    def close(self) -> None:
        self._closed.set()

    def say(self, line: str) -> None:
        self.on_say(line)
        with self._changed:
            self.said.append(line)
            self._prompts_seen += PROMPT in line
            self._changed.notify_all()

    def read_line(self) -> str | None:
        if not self._steps:
            self._closed.wait()
            return None
        when, line = self._steps.pop(0)
        if callable(when):
            wait_for(when, WAIT_S, "the operator's cue")
            return line
        with self._changed:
            self._changed.wait_for(lambda: self._prompts_seen > self._prompts_used, WAIT_S)
            self._prompts_used += 1
        return line


def answers(*lines: str | None) -> Script:
    """One answer per prompt, in order."""
    return Script(*(("prompt", line) for line in lines))


def verdicts(report: dict[str, Any]) -> dict[str, str]:
    """The JSON report's verdict of each check, by key."""
    return {check["key"]: check["verdict"] for check in report["checks"]}
