"""One spec per node parameter: type, default, range or choices, start-up-only or live.

Plain Python (the node base turns a spec into a ``ParameterDescriptor``): a start-up-only
parameter is declared ``read_only`` so ``ros2 param set`` is refused with a reason instead
of answering "successful" and changing nothing; a live one is validated here and applied
by the node's set-parameters callback. An integer given for a double parameter
(``-p poll_rate_hz:=20``) is taken as that double.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

ParameterValue = bool | int | float | str | list[bool] | list[int] | list[float] | list[str]


@dataclass(frozen=True)
class ParameterSpec:
    name: str
    default: ParameterValue
    description: str
    low: float | None = None  # numeric range (inclusive), checked by ROS and by validate()
    high: float | None = None
    choices: tuple[str, ...] = ()  # allowed strings (case-insensitive), e.g. parity
    live: bool = False  # may change at run time (applied by the node), else read-only
    item_positive: bool = False  # every item of a double array must be > 0 and finite
    kind: type = field(init=False)

    def __post_init__(self) -> None:
        kind: type
        if isinstance(self.default, bool):
            kind = bool
        elif isinstance(self.default, int):
            kind = int
        elif isinstance(self.default, float):
            kind = float
        elif isinstance(self.default, str):
            kind = str
        elif isinstance(self.default, list):
            kind = list
        else:
            raise TypeError(f"parameter {self.name}: unsupported default {self.default!r}")
        object.__setattr__(self, "kind", kind)
        if (self.low is None) != (self.high is None):
            raise ValueError(f"parameter {self.name}: give both ends of the range or neither")
        if self.low is not None and self.kind not in (int, float):
            raise ValueError(f"parameter {self.name}: a range needs a number")
        reason = self.validate(self.default)
        if reason is not None:
            raise ValueError(f"parameter {self.name}: default refused: {reason}")

    def coerce(self, value: ParameterValue) -> ParameterValue:
        """An integer for a double parameter becomes that double (and int lists likewise)."""
        if self.kind is float and isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        default = self.default
        if (
            isinstance(default, list)
            and default
            and isinstance(default[0], float)
            and isinstance(value, list)
            and all(isinstance(item, int | float) and not isinstance(item, bool) for item in value)
        ):
            return [float(item) for item in value]
        return value

    def validate(self, value: ParameterValue) -> str | None:
        """None if ``value`` is acceptable, else the reason (one line)."""
        if (
            self.low is not None
            and self.high is not None
            and not _within(value, self.low, self.high)
        ):
            return f"{self.name} {value!r} outside {self.low:g}..{self.high:g}"
        if self.choices and (
            not isinstance(value, str) or value.upper() not in {c.upper() for c in self.choices}
        ):
            return f"{self.name} {value!r} is not one of {', '.join(self.choices)}"
        if self.item_positive and isinstance(value, list):
            for item in value:
                if (
                    not isinstance(item, int | float)
                    or isinstance(item, bool)
                    or not math.isfinite(item)
                    or item <= 0
                ):
                    return f"{self.name}: every value must be positive and finite, got {item!r}"
        return None

    def type_hint(self, given: object) -> str:
        """Why a value of the wrong type was given, where the reason is known: ROS reads a
        parameter value as YAML, so ``-p parity:=N`` (N, n, no, off ...) arrives as false."""
        if self.kind is str and isinstance(given, bool):
            example = self.choices[0] if self.choices else "text"
            return (
                f" (ROS read the value as the boolean {str(given).lower()}: quote it, "
                f"-p \"{self.name}:='{example}'\")"
            )
        return ""


def _within(value: object, low: float, high: float) -> bool:
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(value)
        and low <= value <= high
    )


def padded(values: Sequence[float], count: int, default: float) -> list[float]:
    """A per-joint list parameter cut or padded with ``default`` to ``count`` items."""
    out = [float(v) for v in values][:count]
    return out + [default] * (count - len(out))


__all__ = ["ParameterSpec", "ParameterValue", "padded"]
