"""A stand-in for ROS 2 ``launch`` (not among the PyPI wheels): just enough of its API for
this repository's launch files to be evaluated by tests/support/launch_run.py. Each class
records its arguments; nothing is started here."""

from __future__ import annotations

from typing import Any


class LaunchContext:
    def __init__(self, arguments: dict[str, str] | None = None) -> None:
        self.launch_configurations: dict[str, str] = dict(arguments or {})


class LaunchDescription:
    def __init__(self, entities: list[Any] | None = None) -> None:
        self.entities = list(entities or [])


__all__ = ["LaunchContext", "LaunchDescription"]
