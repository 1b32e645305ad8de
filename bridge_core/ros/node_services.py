"""Services of the bridge nodes: one guarded command per request.

``BridgeNode`` mixes this in; the guard itself (refusals, halts, what a reply says went
out) is ``BridgeNode.run_command``. A service that stops motion runs in the node's stop
group (or a reentrant one for a service that both stops and starts), never behind
another command.
"""

from __future__ import annotations

from collections.abc import Callable, Hashable, Iterable
from typing import TYPE_CHECKING, Any, TypeVar

from rclpy.callback_groups import CallbackGroup, ReentrantCallbackGroup

T = TypeVar("T")


class CommandServices:
    """``command_service`` and ``trigger_service`` of a ``BridgeNode``."""

    if TYPE_CHECKING:  # what the services need of their node (a BridgeNode has them)
        command_group: CallbackGroup
        stop_group: CallbackGroup
        run_command: Callable[..., tuple[bool, str, Any]]
        create_service: Callable[..., Any]

    def command_service(
        self,
        srv_type: Any,
        name: str,
        describe: Callable[[Any], str],
        action: Callable[[Any], T],
        *,
        writes: bool = True,
        stop: bool | Callable[[Any], bool] = False,
        fill: Callable[[Any, T], None] | None = None,
        starts: Callable[[Any], tuple[Hashable, Callable[[], object]] | None] | None = None,
        stops_axes: Callable[[Any], Iterable[Hashable]] | None = None,
    ) -> None:
        """A service that runs one guarded command per request.

        ``starts(request)``: (axis, its stop) when the request sets an axis moving (the
        node's halts stop it), None when it does not; ``stops_axes(request)``: the axes an
        acknowledged request stopped.

        ``describe(request)`` names the command in the reply message, ``action(request)``
        does it through the device layer, ``fill(response, result)`` copies a result into
        the response on success. ``stop`` (or ``stop(request)``, e.g. a disable): the
        command ends motion, so it is tried even while the link is down (``run_command``),
        and the service runs in ``stop_group``, never behind another command.
        """

        def handle(request: Any, response: Any) -> Any:
            ok, message, result = self.run_command(
                describe(request),
                lambda: action(request),
                writes=writes,
                stop=stop(request) if callable(stop) else stop,
                starts=starts(request) if starts is not None else None,
                stops_axes=stops_axes(request) if stops_axes is not None else (),
            )
            response.success, response.message = ok, message
            if ok and fill is not None:
                fill(response, result)
            return response

        group: CallbackGroup = self.command_group
        if callable(stop):
            # Stops and non-stops in one service (enable true / false): reentrant, so a
            # non-stop waiting for its turn holds no group a stop needs.
            group = ReentrantCallbackGroup()
        elif stop:
            group = self.stop_group
        self.create_service(srv_type, name, handle, callback_group=group)

    def trigger_service(
        self,
        name: str,
        what: str,
        action: Callable[[], object],
        *,
        stop: bool = False,
        starts: tuple[Hashable, Callable[[], object]] | None = None,
        stops_axes: Iterable[Hashable] = (),
    ) -> None:
        """A std_srvs/Trigger service that runs one guarded command (``starts`` /
        ``stops_axes`` as in ``command_service``)."""
        from std_srvs.srv import Trigger

        self.command_service(
            Trigger,
            name,
            lambda _request: what,
            lambda _request: action(),
            stop=stop,
            starts=None if starts is None else lambda _request: starts,
            stops_axes=lambda _request: stops_axes,
        )
