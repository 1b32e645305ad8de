"""The process of the bridges: the bus owner, and the ``main()`` that spins bridge nodes.

``spin_nodes`` builds a process's nodes (a bus owner first, then its devices), refuses
parameters no node declares, autostarts the managed nodes, spins them on a
MultiThreadedExecutor, and on the way out (Ctrl-C, SIGTERM, a configuration error, an
error nothing handled) stops every motion before the link closes and the context goes.
"""

from __future__ import annotations

import contextlib
import select
import signal
import socket
import sys
import threading
import traceback
from collections.abc import Callable, Sequence
from typing import Any

from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.lifecycle import LifecycleNode
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import try_shutdown

from ..runtime.parameters import DeviceDefaults, bus_specs
from ..runtime.wire_budget import WIRE_FULL, Budget, line_load, line_text
from ..wire.channel import Priority
from ..wire.errors import ConfigurationError
from ..wire.transport import ModbusLink
from .command_line import EXIT_CONFIGURATION_ERROR, command_line_error, init_from_command_line
from .node_base import BridgeNode
from .node_parameters import ParameterNode, link_settings, one_line
from .node_wire import wire_publisher

# The poll threads wait on the line and then need the GIL for a moment; with Python's
# default 5 ms switch interval, each such moment waits out a busy thread's whole slice
# (the executor handling a flood of command messages). bench/stream_flood.py, 1000 msg/s
# on one MOTEC drive: polls of every drive 10.3 -> 6.0-7.2 Hz at 5 ms, 9.4-9.8 Hz at
# 0.5 ms.
GIL_SWITCH_INTERVAL_S = 0.0005
EXIT_FATAL_ERROR = 1  # a bug or an error nothing handled: motion stopped, then exit
LINE_CHECK_PERIOD_S = 1.0  # how often a bus owner looks at its devices' wire budgets
# How long the exit waits, after every node's stops, for the callbacks still running.
CALLBACK_EXIT_WAIT_S = 5.0
EXIT_SIGNALS = (signal.SIGINT, signal.SIGTERM)
WAKEUP_PEEK_BYTES = 64  # more than the bytes that can wait: one per signal, one per wake


class BusNode(ParameterNode):
    """One serial line shared by several devices (any bridges): the bus owner.

    It holds the line's parameters and its one ``ModbusLink``; device nodes get the link
    and their unit id as Python values (``BridgeNode(link=..., unit_id=...)``) and take
    turns on it through its PriorityLock.
    """

    def __init__(
        self,
        node_name: str,
        defaults: DeviceDefaults | Callable[[ParameterNode], DeviceDefaults],
        *,
        unit_id_range: range,
        unit_ids: Callable[[], Sequence[int]] | None = None,
        **node_kwargs: Any,
    ) -> None:
        super().__init__(node_name, **node_kwargs)
        if not isinstance(defaults, DeviceDefaults):
            defaults = defaults(self)  # as BridgeNode's (a modbus_bridge device file)
        # unit_ids: the devices' ids when something else names them (a device file);
        # else the ``unit_ids`` parameter.
        values = self.declare_specs(bus_specs(defaults, unit_ids=unit_ids is None))
        self.autostart = bool(values["autostart"])
        units = [int(u) for u in (values["unit_ids"] if unit_ids is None else unit_ids())]
        if not units or len(set(units)) != len(units):
            raise ConfigurationError(f"unit_ids {units} must be distinct and not empty")
        for unit in units:
            if unit not in unit_id_range:
                raise ConfigurationError(
                    f"unit id {unit} outside {unit_id_range.start}-{unit_id_range.stop - 1}"
                )
        self.unit_ids = units
        self.settings = link_settings(values)
        # ~/wire (record_wire): every unit's frames, once, on the bus owner's topic.
        self.wire = wire_publisher(self, values)
        self.link = ModbusLink(self.settings, wire=self.wire.callback if self.wire else None)
        self.devices: list[BridgeNode[Any]] = []  # the nodes polling this line (watch_line)
        self._judged: int | None = None  # the devices' budget generations last judged

    def watch_line(self, devices: Sequence[BridgeNode[Any]]) -> None:
        """Sum the wire budgets of ``devices`` (they share this line): said once in a WARN
        when together they ask more than it carries, at start and after a rate change;
        each device's diagnostics show the sum."""
        self.devices = list(devices)
        for device in self.devices:
            device.line_load = self.line_load_text
            device.wire = device.wire or self.wire  # the line's counts in its diagnostics
        self.create_timer(LINE_CHECK_PERIOD_S, self._judge_line)

    def _budgets(self) -> list[Budget] | None:
        asked = [d.wire_budget.budget() for d in self.devices if d.active]
        budgets = [b for b in asked if b is not None]
        return budgets if asked and len(budgets) == len(asked) else None

    def line_load_text(self) -> str:
        budgets = self._budgets()
        return "n/a" if budgets is None else f"{line_load(budgets) * 100:.1f}"

    def _judge_line(self) -> None:
        generation = sum(d.wire_budget.generation for d in self.devices)
        budgets = self._budgets()
        if budgets is None or generation == self._judged:
            return
        self._judged = generation
        if line_load(budgets) > WIRE_FULL:
            self.get_logger().warning(line_text(f"line {self.link.describe()}", budgets))

    def close(self) -> None:
        with self.link.lock.hold(Priority.COMMAND):
            self.link.close()
        if self.wire is not None:
            self.wire.close()


def interrupt_on_signals(on_signal: Callable[[], None] | None = None) -> None:
    """SIGINT/SIGTERM raise KeyboardInterrupt in the main thread (``on_signal`` first).

    Used instead of rclpy's handlers (rclpy.init with SignalHandlerOptions.NO), which shut
    the context down at once while the poll and publisher threads still publish; this way
    the nodes stop their motion and threads first and the context goes last.

    Only the first signal interrupts: the exit's stops run in ``finally`` blocks, and a
    second Ctrl-C (people press it twice) raised there would cut them short, before the
    closers started or while they were being joined. Later signals are ignored; SIGKILL
    remains for a process that does not end.

    ``on_signal`` runs in the handler, before anything else of the exit: the nodes learn
    at once that the process is leaving (a link lost from then on is not an error).
    """
    interrupted = threading.Event()

    def interrupt(_signum: int, _frame: Any) -> None:
        if interrupted.is_set():
            return  # already leaving: the stops must not be cut short
        interrupted.set()
        if on_signal is not None:
            on_signal()
        raise KeyboardInterrupt

    signal.signal(signal.SIGINT, interrupt)
    signal.signal(signal.SIGTERM, interrupt)


def _spin_until_interrupted(
    executor: MultiThreadedExecutor, ended: _ThreadEnd | None = None
) -> None:
    """Spin on a thread of its own while the main thread waits for it to end.

    A signal's handler runs in the main thread, between two Python instructions: spinning
    there, it waited in rcl's wait (not interrupted by signals) for the executor's next
    event, up to a timer period later (0.16 s measured idle, longer on a loaded machine),
    and the exit's stops waited with it. The main thread waits instead in
    ``_ThreadEnd.wait``, which a signal ends at once. The spin thread is then woken and
    joined before anything else: shutting the executor down while it is still in rcl's
    wait destroys what the wait holds (the process aborted: "terminate called without an
    active exception"). What ends the spin on its own (an error no callback handled, an
    external shutdown) is raised here as it was.
    """
    stopping = threading.Event()
    failure: list[BaseException] = []
    ended = _ThreadEnd() if ended is None else ended

    def spin() -> None:
        try:
            while not stopping.is_set() and executor.context.ok():
                executor.spin_once()
        except BaseException as err:  # handed to the main thread, which decides
            failure.append(err)
        finally:
            ended.tell()

    spinner = threading.Thread(target=spin, name="executor", daemon=True)
    try:
        with ended:
            spinner.start()
            ended.wait()
    finally:
        stopping.set()
        executor.wake()
        while spinner.is_alive():
            with contextlib.suppress(KeyboardInterrupt):  # a second signal: already leaving
                spinner.join()
    if failure:
        raise failure[0]


class _ThreadEnd:
    """What the main thread waits on: a thread's end, or a signal taken by any thread.

    A signal sent to the process may be taken by any of its threads (on a loaded machine,
    one that runs while the main thread waits for a CPU). Its C handler then runs on that
    thread, and the Python handler only at the main thread's next instruction, which a
    wait in ``Thread.join`` never reaches: a bridge beside two CPU burners ignored a
    SIGINT until the test's SIGTERM 20 s later. The signal wakeup fd is written whichever
    thread takes the signal; the main thread waits on it (and on the thread's word that it
    ended), so the handler runs at once. Off the main thread (no wakeup fd there), only the
    thread's word.
    """

    def __init__(self) -> None:
        self._reader, self._writer = socket.socketpair()
        for end in (self._reader, self._writer):
            end.setblocking(False)
        self._previous: int | None = None
        # Set by the thread as it ends: what the wait looks at (not ``is_alive()``, still
        # true between the thread's word and its end: a wait that looked then slept on).
        self._ended = threading.Event()
        self._signal_seen = False  # the wait took a signal's byte off the wakeup fd

    def __enter__(self) -> _ThreadEnd:
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.set_wakeup_fd(self._writer.fileno(), warn_on_full_buffer=False)
        return self

    def __exit__(self, *_exc: object) -> None:
        if self._previous is not None:
            signal.set_wakeup_fd(self._previous)
        self._reader.close()
        self._writer.close()

    def signalled(self) -> bool:
        """SIGINT or SIGTERM reached the process, whether or not its Python handler ran:
        its byte came on the wakeup fd (the C handler ran, on whichever thread), or the
        kernel holds it for the process, not yet taken by any of its threads. From any
        thread; a poll that finds its link closed asks it (the cell's simulators get the
        same Ctrl-C and may close the link before the bridge's handler runs)."""
        if self._signal_seen:
            return True
        with contextlib.suppress(OSError):  # nothing there, or closed
            if any(self._reader.recv(WAKEUP_PEEK_BYTES, socket.MSG_PEEK)):
                return True
        return _exit_signal_pending()

    def tell(self) -> None:
        """From the thread, as it ends."""
        self._ended.set()
        with contextlib.suppress(OSError):  # full (a wake is pending) or closed (gone)
            self._writer.send(b"\0")

    def wait(self) -> None:
        """Until the thread said it ended or a signal's handler raises (here, at once)."""
        if self._previous is None:
            self._ended.wait()
            return
        while not self._ended.is_set():
            select.select([self._reader], [], [])
            with contextlib.suppress(BlockingIOError):
                # A signal's number, or the thread's word (0).
                if any(self._reader.recv(4096)):
                    self._signal_seen = True


def _exit_signal_pending() -> bool:
    """SIGINT or SIGTERM sent to this process and not yet taken by any of its threads
    (Linux: ``ShdPnd`` in /proc/self/status; ``signal.sigpending`` shows only blocked
    signals). Elsewhere: False."""
    with contextlib.suppress(OSError, ValueError), open("/proc/self/status") as status:
        for line in status:
            if line.startswith("ShdPnd:"):
                mask = int(line.split()[1], 16)
                return any(mask >> (number - 1) & 1 for number in EXIT_SIGNALS)
    return False


def _mark_exiting(nodes: Sequence[Node]) -> None:
    for node in nodes:
        if isinstance(node, BridgeNode):
            node.exiting = True


def _close_all(nodes: Sequence[Node], executor: MultiThreadedExecutor | None = None) -> None:
    """Close every bridge at once (stops first), let the callbacks still running end, then
    the bus owners, then destroy."""
    bridges = [node for node in nodes if isinstance(node, BridgeNode)]
    closers = [threading.Thread(target=node.close) for node in bridges]
    for closer in closers:
        closer.start()
    for closer in closers:
        closer.join()
    if executor is not None:
        _finish_callbacks(executor)
        executor.shutdown()
    for node in nodes:
        if isinstance(node, BusNode):
            node.close()
    for node in nodes:
        node.destroy_node()


def _finish_callbacks(executor: MultiThreadedExecutor) -> None:
    """Wait for the callbacks the executor's thread pool still runs (bounded), drop those
    it has not started, and say what any of them raised, before the nodes are destroyed.

    The spin has ended, but rclpy's ``MultiThreadedExecutor.shutdown`` does not wait for
    its pool (Jazzy's rclpy 7.1: ``Executor.shutdown`` sets ``_is_shutdown`` and then
    skips the wait it guards with it) and never collects what its tasks raised. A timer
    or message callback dispatched just before the exit then ran into ``destroy_node``
    ("cannot use Destroyable because destruction was requested"), and its task, dropped
    uncollected, printed "The following exception was never retrieved" at garbage
    collection: on about half of the cell's Ctrl-C exits (bench/cell_exit.py). The same
    for the executor's own guard condition, woken to end the spin: its callback must run
    before ``executor.shutdown()`` destroys it, so the shutdown comes after. Callbacks
    run after the nodes' ``close`` find them halted (commands refused), and ``close``
    ended every action goal, so the wait is short; a callback still running after
    ``CALLBACK_EXIT_WAIT_S`` is named and left (the process exits regardless).
    """
    pool = getattr(executor, "_executor", None)  # rclpy's ThreadPoolExecutor, not public
    if pool is not None:
        waiter = threading.Thread(
            target=lambda: pool.shutdown(wait=True, cancel_futures=True), daemon=True
        )
        waiter.start()
        waiter.join(CALLBACK_EXIT_WAIT_S)
        if waiter.is_alive():
            print(
                f"a callback still runs {CALLBACK_EXIT_WAIT_S:g} s into the exit; exiting anyway",
                file=sys.stderr,
            )
    tasks = list(getattr(executor, "_futures", []))  # the dispatched callbacks' tasks
    for task in tasks:
        if task.done():
            error = task.exception()  # collected: what nobody collected printed at exit
            if error is not None:
                print(f"a callback failed during the exit: {one_line(error)}", file=sys.stderr)


def _watch_lines(nodes: Sequence[Node]) -> None:
    """Each bus owner judges the wire budgets of the bridges on its line."""
    bridges = [node for node in nodes if isinstance(node, BridgeNode)]
    for bus in nodes:
        if isinstance(bus, BusNode):
            bus.watch_line([b for b in bridges if b.link is bus.link])


def _refuse_unused_parameters(nodes: Sequence[Node]) -> None:
    """A ``-p`` or params-file value that no node of the process declares is a typo or a
    parameter of another node (``unit_id`` on the MOTEC bus, whose drives are
    ``unit_ids``): refused, since it would be silently ignored. A params file's ``/**``
    block reaches every node, so a value counts as used when any node declares it."""
    given: dict[str, Any] = {}
    for node in nodes:
        for name, parameter in getattr(node, "_parameter_overrides", {}).items():
            given.setdefault(name, parameter.value)
    unused = [name for name in given if not any(node.has_parameter(name) for node in nodes)]
    if unused:
        listed = ", ".join(f"{name}:={given[name]!r}" for name in sorted(unused))
        names = ", ".join(node.get_name() for node in nodes)
        raise ConfigurationError(
            f"parameter {listed} is not one of this process's ({names}); check its name"
        )


def spin_nodes(
    build: Callable[[list[Node]], None],
    args: Sequence[str] | None = None,
    *,
    threads: Callable[[int], int] = lambda nodes: max(4, min(32, 2 + 4 * nodes)),
) -> int:
    """rclpy demo-style main for one process of bridge nodes; returns the exit code.

    ``build`` appends the nodes it creates to the list it is given (so a node that fails
    half-way still has the earlier ones closed). A configuration error (bad parameter
    type or range) is one line on stderr and exit code 2, never a traceback.
    """
    refused = init_from_command_line(args, signal_handler_options=SignalHandlerOptions.NO)
    if refused is not None:
        print(f"error: {refused}", file=sys.stderr)
        return EXIT_CONFIGURATION_ERROR
    nodes: list[Node] = []
    interrupt_on_signals(lambda: _mark_exiting(nodes))
    sys.setswitchinterval(GIL_SWITCH_INTERVAL_S)
    executor: MultiThreadedExecutor | None = None
    code = 0
    try:
        build(nodes)
        _refuse_unused_parameters(nodes)
        _watch_lines(nodes)
        for node in nodes:  # the bus owner first, then its devices
            if isinstance(node, LifecycleNode) and getattr(node, "autostart", False):
                node.trigger_configure()
                node.trigger_activate()
        # A running action goal holds an executor thread until it ends.
        goal_threads = sum(node.actions.threads for node in nodes if isinstance(node, BridgeNode))
        executor = MultiThreadedExecutor(num_threads=threads(len(nodes)) + goal_threads)
        ended = _ThreadEnd()
        for node in nodes:
            executor.add_node(node)
            if isinstance(node, BridgeNode):
                node.exit_signalled = ended.signalled
        _spin_until_interrupted(executor, ended)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except (ConfigurationError, ParameterException) as err:
        print(f"error: {one_line(err)}", file=sys.stderr)
        code = EXIT_CONFIGURATION_ERROR
    except Exception as err:
        # An error no callback handled (a bug): every motion is stopped below before the
        # process ends, and the traceback is kept, since it is what a bug report needs.
        traceback.print_exc()
        print(
            f"fatal error: {one_line(err)}; stopping every motion, then exiting",
            file=sys.stderr,
        )
        code = EXIT_FATAL_ERROR
    finally:
        _mark_exiting(nodes)
        _close_all(nodes, executor)
        try_shutdown()
    return code


def spin_node(make_node: Callable[[], Node], args: Sequence[str] | None = None) -> int:
    """``spin_nodes`` for a process of one node."""
    return spin_nodes(lambda nodes: nodes.append(make_node()), args)


__all__ = [
    "EXIT_CONFIGURATION_ERROR",
    "EXIT_FATAL_ERROR",
    "GIL_SWITCH_INTERVAL_S",
    "BusNode",
    "command_line_error",
    "init_from_command_line",
    "interrupt_on_signals",
    "spin_node",
    "spin_nodes",
]
