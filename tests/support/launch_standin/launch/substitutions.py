"""Stand-ins of ``launch.substitutions`` (see the package docstring)."""

from __future__ import annotations

from typing import Any


class LaunchConfiguration:
    def __init__(self, variable_name: str, *, default: Any = None) -> None:
        self.variable_name = variable_name
        self.default = default

    def perform(self, context: Any) -> str:
        value = context.launch_configurations.get(self.variable_name, self.default)
        if value is None:
            raise KeyError(f"launch configuration {self.variable_name!r} is not set")
        return str(value)
