"""Services of the bridge nodes, made from the rows of ``<bridge>/interface.py``: one
guarded command per request.

A bridge lists each service once, as a ``Service`` row (name, type, text: what the
generated reference pages show). Its node gives a table from each row's name to the
``Command`` that answers it (for a pattern such as ``~/motor_{motor}/move_by``, a function
of the placeholders, called once per value with it as a keyword argument), and
``BridgeNode.command_services`` (a ``ServiceHost``; not ``services``, which rclpy's Node
has) creates every service of the rows in one loop, with the row's type. A row without
a handler, or a handler without a row, is an error at start-up (``bound_rows``); actions
are made the same way (``node_actions.ActionHost.create``).

The guard itself (refusals, halts, what a reply says went out) is ``BridgeNode.run_command``.
A service that stops motion runs in the node's stop group (or a reentrant one for a
service that both stops and starts), never behind another command. The host also owns
what its services set moving: their stops on a halt, retried while the link is down.
"""

from __future__ import annotations

import importlib
import itertools
import string
import threading
from collections.abc import Callable, Hashable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Generic, Protocol, TypeVar, cast

from rclpy.callback_groups import (
    CallbackGroup,
    MutuallyExclusiveCallbackGroup,
    ReentrantCallbackGroup,
)

from ..runtime.motion_ledger import StopResult
from ..wire.errors import ConfigurationError, DeviceException, NotConfirmed

if TYPE_CHECKING:
    from .node_base import BridgeNode

T = TypeVar("T")
# A halt's stop of a service's motion that failed is tried again this often (a probe of a
# dead line each time: the streams' deadman retries at 0.05 s).
PENDING_STOP_RETRY_S = 0.25
# (axis, its stop): what a command sets moving, for the node's motion ledger.
Started = tuple[Hashable, Callable[[], object]]


class Row(Protocol):
    """A ``Service`` or ``Action`` row of ``bridge_core.runtime.interface``."""

    @property
    def name(self) -> str: ...
    @property
    def type(self) -> str: ...


RowT = TypeVar("RowT", bound=Row)


@dataclass(frozen=True)
class Command(Generic[T]):
    """What a service does per request.

    ``describe(request)`` names the command in the reply message, ``action(request)``
    does it through the device layer, ``fill(response, result)`` copies a result into
    the response on success. ``stop`` (or ``stop(request)``, e.g. a disable): the command
    ends motion, so it is tried even while the link is down (``run_command``), and the
    service runs in the stop group, never behind another command. ``starts(request)``:
    (axis, its stop) when the request sets an axis moving (the node's halts stop it), None
    when it does not; ``stops_axes(request)``: the axes an acknowledged request stopped.
    """

    describe: Callable[[Any], str]
    action: Callable[[Any], T]
    writes: bool = True
    stop: bool | Callable[[Any], bool] = False
    fill: Callable[[Any, T], None] | None = None
    starts: Callable[[Any], Started | None] | None = None
    stops_axes: Callable[[Any], Iterable[Hashable]] | None = None


def trigger(
    what: str,
    action: Callable[[], T],
    *,
    stop: bool = False,
    starts: Started | None = None,
    stops_axes: Iterable[Hashable] = (),
    fill: Callable[[Any, T], None] | None = None,
) -> Command[T]:
    """A command whose request carries nothing (std_srvs/Trigger): ``what``, always."""
    return Command(
        lambda _request: what,
        lambda _request: action(),
        stop=stop,
        fill=fill,
        starts=None if starts is None else lambda _request: starts,
        stops_axes=lambda _request: stops_axes,
    )


def bound_rows(
    rows: Sequence[RowT], handlers: Mapping[str, Any], expansion: Mapping[str, Sequence[object]]
) -> list[tuple[RowT, str, Any]]:
    """(row, name, handler) for each name of each row: a pattern's handler called with
    its placeholders' values (keyword arguments), once per combination. Raises
    ``ConfigurationError`` naming every row without a handler and every handler without
    a row."""
    missing = [row.name for row in rows if row.name not in handlers]
    unlisted = sorted(set(handlers) - {row.name for row in rows})
    if missing or unlisted:
        raise ConfigurationError(
            "the node's handlers do not match its interface rows: "
            + "; ".join(
                part
                for part in (
                    f"no handler for {', '.join(missing)}" if missing else "",
                    f"no row for {', '.join(unlisted)}" if unlisted else "",
                )
                if part
            )
        )
    bound: list[tuple[RowT, str, Any]] = []
    for row in rows:
        handler = handlers[row.name]
        keys = [key for _, key, _, _ in string.Formatter().parse(row.name) if key]
        for values in itertools.product(*(expansion[key] for key in keys)):
            given = dict(zip(keys, values, strict=True))
            bound.append((row, row.name.format(**given), handler(**given) if keys else handler))
    return bound


def interface_type(name: str) -> Any:
    """The message class a row names ("std_srvs/srv/Trigger")."""
    package, kind, type_name = name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), type_name)


class ServiceHost:
    """The command services of one ``BridgeNode`` and the motions they started."""

    def __init__(self, node: BridgeNode[Any], log_period_s: float) -> None:
        self.node = node
        self.log_period_s = log_period_s  # a pending stop that still fails: WARN this often
        # Runs only while a stop is pending (``stop_all`` wakes it, the retry that finds
        # none left puts it to sleep): a timer that fired 4 times a second for nothing
        # cost every node a wait-set rebuild of its executor each time (a third of an
        # idle three-drive MOTEC process's CPU).
        self._retry = node.create_timer(
            PENDING_STOP_RETRY_S,
            self.retry_pending_stops,
            callback_group=MutuallyExclusiveCallbackGroup(),  # never in a stop service's way
        )
        self._retry.cancel()
        self._retry_lock = threading.Lock()  # pending() and the timer's state, together

    def create(
        self,
        rows: Sequence[Row],
        handlers: Mapping[str, Command[Any] | Callable[..., Command[Any]]],
        expansion: Mapping[str, Sequence[object]] | None = None,
    ) -> None:
        """A service per name of each row (``expansion``: each placeholder's values),
        answered by the ``Command`` its handler gives (``bound_rows``)."""
        for row, name, command in bound_rows(rows, handlers, expansion or {}):
            if not isinstance(command, Command):
                raise ConfigurationError(f"{row.name}: its handler gave {command!r}, no Command")
            self.add(interface_type(row.type), name, command)

    def add(self, srv_type: Any, name: str, command: Command[T]) -> None:
        """A service that runs one guarded command per request."""
        node = self.node

        def handle(request: Any, response: Any) -> Any:
            stop = command.stop
            ok, message, result = node.run_command(
                command.describe(request),
                lambda: command.action(request),
                writes=command.writes,
                stop=stop(request) if callable(stop) else stop,
                starts=command.starts(request) if command.starts is not None else None,
                stops_axes=command.stops_axes(request) if command.stops_axes is not None else (),
            )
            response.success, response.message = ok, message
            if ok and command.fill is not None:
                command.fill(response, cast(T, result))  # ok: the action's result
            return response

        group: CallbackGroup = node.command_group
        if callable(command.stop):
            # Stops and non-stops in one service (enable true / false): reentrant, so a
            # non-stop waiting for its turn holds no group a stop needs.
            group = ReentrantCallbackGroup()
        elif command.stop:
            group = node.stop_group
        node.create_service(srv_type, name, handle, callback_group=group)

    # ------------------------------------------------------------ their motions' stops
    def send_pending_stops(self) -> None:
        """Before the first poll after a (re)connect: a stop that failed while the link
        was down goes out; if it fails again the link is still down (raised: the poller
        says so, and tries again)."""
        motions, logger = self.node.service_motions, self.node.get_logger()
        for stopped in motions.retry_pending():
            if isinstance(stopped.error, DeviceException):
                # Answered: the device refused the stop. Said loudly, not retried for ever
                # (polls must go on); the motion may still run.
                motions.stopped(stopped.axis)
                logger.error(
                    f"{stopped.what}: the device refused its pending stop: {stopped.error}"
                )
            elif isinstance(stopped.error, NotConfirmed):
                # Answered, and the device does not show it: said loudly, kept for the
                # next halt, not retried for ever (polls must go on).
                logger.error(
                    f"{stopped.what}: its pending stop went out, not confirmed: {stopped.error}"
                )
            elif stopped.error is not None:
                raise stopped.error  # still down: the poller says so, and tries again
            else:
                logger.info(f"{stopped.what}: the pending stop was sent on reconnect")

    def stop_all(self, reason: str) -> None:
        """Stop every motion a service started (a halt), each tried on the wire; one
        that failed is tried again on a timer (``retry_pending_stops``)."""
        logger = self.node.get_logger()
        motions = self.node.service_motions
        try:
            self._log_stops(motions.stop_all(), reason, logger)
        finally:
            with self._retry_lock:
                if motions.pending() and self._retry.is_canceled():
                    self._retry.reset()

    @staticmethod
    def _log_stops(results: Iterable[StopResult], reason: str, logger: Any) -> None:
        for stopped in results:
            if stopped.error is None:
                logger.info(f"{stopped.what}: stopped ({reason})")
            elif isinstance(stopped.error, NotConfirmed):
                logger.error(
                    f"{stopped.what}: its stop went out, not confirmed ({reason}): {stopped.error}"
                )
            else:
                logger.error(
                    f"{stopped.what}: its stop failed ({reason}): {stopped.error}; "
                    "tried again until it gets through"
                )

    def retry_pending_stops(self) -> None:
        """A halt's stop that failed (the link was down) is tried again on a timer, also
        while the node is inactive (nobody reactivates it to get the stop out)."""
        motions, logger = self.node.service_motions, self.node.get_logger()
        with self._retry_lock:
            if not motions.pending():
                self._retry.cancel()  # asleep until a halt leaves a stop pending
                return
        for stopped in motions.retry_pending():
            if stopped.error is None:
                logger.info(f"{stopped.what}: the pending stop got through")
            elif isinstance(stopped.error, NotConfirmed):
                logger.error(
                    f"{stopped.what}: its pending stop went out, not confirmed: {stopped.error}"
                )
            else:
                logger.warn(
                    f"{stopped.what}: its stop still fails: {stopped.error}",
                    throttle_duration_sec=self.log_period_s,
                )


__all__ = [
    "PENDING_STOP_RETRY_S",
    "Command",
    "ServiceHost",
    "Started",
    "bound_rows",
    "interface_type",
    "trigger",
]
