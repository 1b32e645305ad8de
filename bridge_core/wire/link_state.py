"""Whether a device's link is up: one owner (its ``DeviceChannel``), and who is told.

Two levels, kept together under one lock:

- ``connected``: the device's last transaction got an answer. The channel sets it on
  every transaction, whoever sent it (a poll, a command, a stop); commands are refused
  while it is false.
- up, as announced: a whole poll was answered on the current connection (``confirm``).
  The listeners (the poller's console reports, the node's latched ``~/connected``) are
  told once per edge: ``UP`` after the first good poll of a connection, ``LOST`` when a
  link that was up fails (whichever transaction failed), ``UNREACHABLE`` at the first
  failure of a device never up. Nobody else keeps an up/down flag, so a command that
  loses the link needs to tell nobody.

Listeners run under the state lock (on the thread whose transaction changed the state,
maybe under the link lock): the order they see is the order of the edges, and a poll
that ends after a loss cannot announce ``UP`` over it. They must be short and must not
use the link.
"""

from __future__ import annotations

import enum
import logging
import threading
from collections.abc import Callable

_log = logging.getLogger(__name__)


class LinkEvent(enum.Enum):
    UP = "up"  # the first good poll of a connection
    LOST = "lost"  # a link that was up failed
    UNREACHABLE = "unreachable"  # the first failure of a device never up


LinkListener = Callable[[LinkEvent, str], None]  # (edge, the error text of a loss)


class LinkState:
    """A device's link state and its listeners (``DeviceChannel.link_state``)."""

    def __init__(self) -> None:
        self._lock = threading.RLock()
        # Read by anyone, written only by the methods below (under the lock): plain
        # attributes, because the channel reads them on every transaction.
        # ``connected``: the device's last transaction got an answer (data or an exception).
        self.connected = False
        self._ever_connected = False
        # Bumped each time the device answers after being down (a poll's, or a stop's
        # sent while down): the poller's link-up work is due once per generation.
        self._generation = 0
        # Bumped whenever the device is marked down: a session (a command, a poll) that
        # began on an older epoch must not run on, or confirm, a link lost meanwhile.
        self.epoch = 0
        self._announced: bool | None = None  # what the listeners were told (None: nothing)
        self._confirmed = 0  # the generation a good poll confirmed (its link-up work done)
        self._losses = 0
        self._listeners: list[LinkListener] = []

    @property
    def ever_connected(self) -> bool:
        return self._ever_connected

    @property
    def generation(self) -> int:
        return self._generation

    @property
    def losses(self) -> int:
        """Down edges announced so far (``LOST`` and ``UNREACHABLE``): a poll that failed
        without one was a further failed attempt of a device already down."""
        return self._losses

    @property
    def link_up_due(self) -> bool:
        """The poller's link-up work is due before the next poll: the device is down (the
        next poll is a probe), or it came up since the last good poll (a stop sent while
        down reconnected it between two polls)."""
        return not self.connected or self._generation != self._confirmed

    def add_listener(self, listener: LinkListener) -> Callable[[], None]:
        """Tell ``listener`` every edge from now on; returns what unsubscribes it."""
        with self._lock:
            self._listeners.append(listener)

        def remove() -> None:
            with self._lock:
                if listener in self._listeners:
                    self._listeners.remove(listener)

        return remove

    def answered(self) -> None:
        """A transaction got an answer: connected (a new generation if it was down)."""
        with self._lock:
            if not self.connected:
                self._ever_connected = True
                self._generation += 1
                self.connected = True

    def went_down(self, text: str) -> None:
        """A transaction failed on the link: down, a new epoch, and a loss if it was up."""
        with self._lock:
            self.epoch += 1
            self.connected = False
            self._announce_down(text)

    def lose(self, text: str) -> None:
        """A poll failed on the link where the transport saw no fault (a reply too short,
        a frame the device's own check refused): not up until a poll succeeds again;
        the connection itself stays."""
        with self._lock:
            self._announce_down(text)

    def confirm(self, epoch: int) -> bool:
        """A whole poll was answered in a session begun at ``epoch``: up (announced once
        per connection), unless the link was marked down since the session began."""
        with self._lock:
            if not self.connected or epoch != self.epoch:
                return False
            self._confirmed = self._generation
            if self._announced is not True:
                self._announced = True
                self._notify(LinkEvent.UP, "")
            return True

    def _announce_down(self, text: str) -> None:
        was = self._announced
        if was is False:
            return  # down already: told once per loss
        self._announced = False
        self._losses += 1
        self._notify(LinkEvent.LOST if was else LinkEvent.UNREACHABLE, text)

    def _notify(self, event: LinkEvent, text: str) -> None:
        for listener in list(self._listeners):
            try:
                listener(event, text)
            except Exception:  # a listener's bug must not break the transaction
                _log.exception("a link listener failed on %s", event.value)


__all__ = ["LinkEvent", "LinkListener", "LinkState"]
