"""Device personalities: a simulator that plays a real device, not the manual's ideal one.

Why: our simulators follow our own readings of the manuals, answer at the manual's minimum
delay and obey every write, so a bridge that takes a write's acknowledgement for a motion
done, or gives up on a device that answers late, passes every test. Each switch here
makes a simulator behave as a real device may (docs/tools.md, "Device personalities"):

- ``--reply-delay-ms MIN[:MAX]``: each reply waits a delay drawn in [MIN, MAX]. RTU: after
  the request's last byte (the line stays busy meanwhile); TCP: a network round trip, half
  each way, requests in flight overlapping and kept in order (``tcp_serving``).
- ``--ignore NAME[,NAME...]``: the named motion writes are acknowledged on the wire as the
  manual says (FC 05 / 06 echo the request) and change nothing: not stored, no behaviour.
  Each simulator lists its names (``SimulatedDevice.IGNORABLE``).
- ``--nagle`` (TCP): the device leaves Nagle's algorithm on for its replies.

The same switches for in-process use: ``Simulator.set_reply_delay``,
``Simulator.ignore``, ``Simulator.nagle``.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

# Limits of the personality switches (a delay past this is a dead device, not a late one).
MAX_REPLY_DELAY_MS = 10_000.0


@dataclass(frozen=True)
class DelayRange:
    """A reply delay drawn per reply in [low_s, high_s]."""

    low_s: float
    high_s: float

    @property
    def text(self) -> str:
        low, high = self.low_s * 1000, self.high_s * 1000
        return f"{low:g} ms" if low == high else f"{low:g}-{high:g} ms"


def delay_range_ms(text: str) -> DelayRange:
    """argparse type of ``--reply-delay-ms``: ``MIN`` or ``MIN:MAX`` in milliseconds."""
    parts = text.split(":")
    try:
        if len(parts) > 2:
            raise ValueError
        low = float(parts[0])
        high = float(parts[1]) if len(parts) == 2 else low
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"{text!r} is not MIN or MIN:MAX in milliseconds (e.g. 35:300)"
        ) from None
    if not (0.0 <= low <= high <= MAX_REPLY_DELAY_MS):
        raise argparse.ArgumentTypeError(
            f"{text!r}: need 0 <= MIN <= MAX <= {MAX_REPLY_DELAY_MS:g} ms"
        )
    return DelayRange(low / 1000, high / 1000)


def ignore_names(names: Mapping[str, str]) -> type[str] | object:
    """argparse type of ``--ignore``: a comma-separated subset of ``names``."""

    def parse(text: str) -> frozenset[str]:
        chosen = frozenset(n.strip() for n in text.split(",") if n.strip())
        unknown = sorted(chosen - set(names))
        if unknown or not chosen:
            raise argparse.ArgumentTypeError(
                f"unknown motion write {', '.join(unknown) or repr(text)}; "
                f"this simulator's names: {', '.join(sorted(names))}"
            )
        return chosen

    return parse


def add_delay_argument(
    parser: argparse.ArgumentParser, default_ms: float | None, what: str
) -> None:
    """``--reply-delay-ms MIN[:MAX]`` (a ``DelayRange``; None when not given and
    ``default_ms`` is None: the simulator keeps its own)."""
    default = None if default_ms is None else DelayRange(default_ms / 1000, default_ms / 1000)
    said = "the device's own" if default_ms is None else f"{default_ms:g}"
    parser.add_argument(
        "--reply-delay-ms",
        type=delay_range_ms,
        default=default,
        metavar="MIN[:MAX]",
        help=f"{what}; MIN:MAX draws each reply's delay in that range (default {said})",
    )


def add_ignore_argument(parser: argparse.ArgumentParser, names: Mapping[str, str]) -> None:
    listing = "; ".join(f"{name}: {what}" for name, what in sorted(names.items()))
    parser.add_argument(
        "--ignore",
        type=ignore_names(names),  # type: ignore[arg-type]
        default=frozenset(),
        metavar="NAME[,NAME...]",
        help="acknowledge these motion writes as the manual says and change nothing "
        f"(a device that does not obey): {listing}",
    )


def chosen_ignore(args: argparse.Namespace) -> Iterable[str]:
    return tuple(getattr(args, "ignore", ()) or ())


__all__ = [
    "MAX_REPLY_DELAY_MS",
    "DelayRange",
    "add_delay_argument",
    "add_ignore_argument",
    "chosen_ignore",
    "delay_range_ms",
    "ignore_names",
]
