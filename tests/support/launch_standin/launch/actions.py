"""Stand-ins of ``launch.actions`` (see the package docstring)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


class DeclareLaunchArgument:
    def __init__(
        self,
        name: str,
        *,
        default_value: Any = None,
        description: str = "no description given",
        choices: list[str] | None = None,
    ) -> None:
        self.name = name
        self.default_value = default_value
        self.description = description
        self.choices = choices


class ExecuteProcess:
    def __init__(self, *, cmd: list[Any], **kwargs: Any) -> None:
        self.cmd = cmd
        self.kwargs = kwargs


class OpaqueFunction:
    def __init__(self, *, function: Callable[..., Any], **kwargs: Any) -> None:
        self.function = function
        self.kwargs = kwargs
