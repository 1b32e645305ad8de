"""``bridge_commission BRIDGE --ros-args --params-file config/<bridge>.yaml -p host:=...``:
a bridge's hardware checks run against a real device, and a report.

The parameters are the bridge's own, parsed as the bridge parses them: rcl reads the
command line and params file, a node of the bridge's name declares the bridge's specs
(``ParameterNode.declare_specs``), and a value no spec takes is refused: a bad value is the
same one ``error:`` line, exit code 2, as the bridge gives. The node only parses (it is
destroyed before the first request); the phases are ``runtime.commission_run``'s. Ctrl-C
and SIGTERM end a running step with its stop, then the report is written (exit 130).
``--write-docs`` / ``--check-docs`` render the decisions pages' hardware checks from the
same data (``runtime.commission_doc``).
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, cast

from rclpy.context import Context
from rclpy.exceptions import ParameterException
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import try_shutdown

from ..runtime import commission_doc, entries
from ..runtime.commission import (
    REPLY_SAMPLES_DEFAULT,
    REPLY_SAMPLES_RANGE,
    Commissioning,
    Described,
    Probe,
    Report,
    commissionings,
)
from ..runtime.commission_run import DEVICE_LOST, Operator, commission, verdict_lines
from ..runtime.interface import NodeInterface, nodes
from ..wire.channel import DeviceChannel
from ..wire.errors import ConfigurationError, LinkError
from ..wire.transport import ModbusLink
from .command_line import EXIT_CONFIGURATION_ERROR, init_from_command_line
from .node_parameters import ParameterNode, link_settings, one_line
from .process import _refuse_unused_parameters

EXIT_NO_DEVICE = 1  # the device never answered (no report), or stopped answering (a report)
EXIT_DOCS_DIFFER = 1  # --check-docs: a page is not what the data renders
EXIT_INTERRUPTED = 130  # Ctrl-C or SIGTERM: the report holds what was found so far
# Where the device is: copied into the recommended params file as given.
LINK_PARAMETERS = ("host", "port", "serial_port", "baudrate", "parity", "stopbits", "unit_id")
RECONNECT_MAX_S = 1.0  # the tool's channel: a lost device is tried again soon
EXIT_SIGNALS = (signal.SIGINT, signal.SIGTERM)
# A bus bridge's commission module (MOTEC: node motec_{unit_id}, link on the bus node) may
# list the node the tool parses as (bus and device parameters together) and the params
# file's node name ("*": every node of the process).
COMMISSION_NODE = "COMMISSION_NODE"
PARAMS_NODE = "PARAMS_NODE"


def parse_parameters(
    node: NodeInterface, ros_args: Sequence[str], described: Described | None = None
) -> dict[str, Any]:
    """The bridge's parameters from its command line, as the bridge takes them; raises
    ``ConfigurationError`` with the bridge's one line. ``described``: the parameters that
    name the bridge's file first, then those of the node the file makes."""
    context = Context()
    refused = init_from_command_line(
        ["bridge_commission", *ros_args],
        context=context,
        signal_handler_options=SignalHandlerOptions.NO,
    )
    if refused is not None:
        raise ConfigurationError(refused)
    parser: ParameterNode | None = None
    try:
        parser = ParameterNode(node.node, context=context)
        if described is None:
            values = parser.declare_specs(node.parameters)
        else:
            values = parser.declare_specs(described.first)
            rest = [s for s in described.node(values).parameters if s.name not in values]
            values.update(parser.declare_specs(rest))
        _refuse_unused_parameters([parser])
        return values
    except ParameterException as err:
        raise ConfigurationError(one_line(err)) from err
    finally:
        if parser is not None:
            parser.destroy_node()
        try_shutdown(context=context)


@contextlib.contextmanager
def interrupted_by_signals() -> Iterator[None]:
    """SIGINT and SIGTERM raise ``KeyboardInterrupt`` in the main thread (a step's stop
    then goes out in its ``finally``); the handlers before are restored after. Only the
    first signal interrupts: the stop must not be cut short by a second Ctrl-C."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    seen: list[int] = []

    def interrupt(number: int, _frame: Any) -> None:
        if seen:
            return
        seen.append(number)
        raise KeyboardInterrupt

    before = {number: signal.signal(number, interrupt) for number in EXIT_SIGNALS}
    try:
        yield
    finally:
        for number, handler in before.items():
            signal.signal(number, handler)


def stdin_line() -> str | None:
    line = sys.stdin.readline()
    return None if line == "" else line.rstrip("\n")


def the_node(commissioning: Commissioning, values: dict[str, Any] | None = None) -> NodeInterface:
    """The bridge's node (a described bridge's: the one its file in ``values`` makes)."""
    if commissioning.described is not None and values is not None:
        return commissioning.described.node(values)
    listed = getattr(bus_module(commissioning), COMMISSION_NODE, None)
    if listed is not None:
        return cast(NodeInterface, listed)  # the bus module's listing (getattr: Any)
    return next(n for n in nodes() if n.node == commissioning.node)


def bus_module(commissioning: Commissioning) -> Any:
    """The bridge's ``<package>.commission`` module (a bus bridge's lists its node)."""
    package = entries.bridge_packages()[commissioning.bridge]
    return sys.modules.get(f"{package}.commission")


def unit_of(values: dict[str, Any], args: argparse.Namespace) -> int:
    """The device's unit: ``unit_id``, or on a bus (``unit_ids``) ``--unit-id`` or the
    first of ``unit_ids``."""
    if "unit_id" in values:
        return int(values["unit_id"])
    return int(args.unit_id if args.unit_id is not None else values["unit_ids"][0])


def run(
    commissioning: Commissioning,
    values: dict[str, Any],
    args: argparse.Namespace,
    read_line: Callable[[], str | None],
    say: Callable[[str], None],
) -> tuple[Report, int]:
    """Open the link from the parameters, run both phases, close it."""
    link = ModbusLink(link_settings(values))
    unit = unit_of(values, args)
    channel = DeviceChannel(link, unit, retries=0, reconnect_max_s=RECONNECT_MAX_S)
    device = f"{link.describe()} unit {unit}"
    params_node = getattr(bus_module(commissioning), PARAMS_NODE, commissioning.node)
    report = Report(commissioning.bridge, params_node, device)
    first = commissioning.described.first if commissioning.described is not None else ()
    linked = (*(spec.name for spec in first), *LINK_PARAMETERS)  # the file, then the link
    report.link = {name: values[name] for name in linked if name in values}
    operator = None if args.read_only else Operator(read_line)
    probe = Probe(channel, values, say=say)
    if operator is not None:
        probe.stop_requested = operator.stop_requested
        probe.wait = operator.wait
    timeout = next(s for s in the_node(commissioning, values).parameters if s.name == "timeout_s")
    if commissioning.described is not None:  # the rows of the file the parameters name
        commissioning = commissioning.described.bind(commissioning, values)
    try:
        with interrupted_by_signals():
            commission(
                commissioning,
                probe,
                report,
                samples=args.samples,
                operator=operator,
                timeout_low_s=float(timeout.low or 0.0),
            )
    finally:
        link.close()
    if report.interrupted.startswith(DEVICE_LOST):
        return report, EXIT_NO_DEVICE
    return report, EXIT_INTERRUPTED if report.interrupted else 0


def write_report(report: Report, args: argparse.Namespace, say: Callable[[str], None]) -> None:
    stem = f"commission-{report.bridge}"
    for path, text in (
        (args.report or Path(f"{stem}.md"), report.markdown()),
        (args.json or Path(f"{stem}.json"), report.json_text()),
        (args.params or Path(f"{stem}.yaml"), report.params_yaml()),
    ):
        path.write_text(text, encoding="utf-8")
        say(f"wrote {path}")


def docs(args: argparse.Namespace, known: dict[str, Commissioning]) -> int:
    chosen = [known[name] for name in args.bridges] or list(known.values())
    if args.check_docs:
        found = [line for c in chosen if (line := commission_doc.differs(c, args.root))]
        for line in found:
            print(line)
        return EXIT_DOCS_DIFFER if found else 0
    for c in chosen:
        (args.root / commission_doc.page_name(c)).write_text(
            commission_doc.written(c, args.root), encoding="utf-8"
        )
    return 0


def samples_count(text: str) -> int:
    value = int(text)
    low, high = REPLY_SAMPLES_RANGE
    if not low <= value <= high:
        raise argparse.ArgumentTypeError(f"{value} outside {low}..{high}")
    return value


def parser_of(known: dict[str, Commissioning]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bridge_commission",
        description="a bridge's hardware checks against a real device, and a report; "
        "the bridge's parameters follow --ros-args",
    )
    parser.add_argument("bridges", nargs="*", metavar="BRIDGE", help=", ".join(known))
    parser.add_argument(
        "--samples",
        type=samples_count,
        default=REPLY_SAMPLES_DEFAULT,
        help=f"requests timed for the reply times (default {REPLY_SAMPLES_DEFAULT})",
    )
    parser.add_argument("--read-only", action="store_true", help="skip the guided phase")
    parser.add_argument(
        "--unit-id",
        type=int,
        metavar="N",
        help="a bus bridge (MOTEC): the device checked (default: the first of unit_ids)",
    )
    parser.add_argument("--report", type=Path, help="Markdown report (commission-BRIDGE.md)")
    parser.add_argument("--json", type=Path, help="JSON report (commission-BRIDGE.json)")
    parser.add_argument("--params", type=Path, help="params file (commission-BRIDGE.yaml)")
    docs_mode = parser.add_mutually_exclusive_group()
    docs_mode.add_argument(
        "--write-docs", action="store_true", help="rewrite docs/decisions/BRIDGE.md's checks"
    )
    docs_mode.add_argument(
        "--check-docs", action="store_true", help="exit 1 if a page's checks differ"
    )
    parser.add_argument("--root", type=Path, default=entries.ROOT, help="repository root")
    return parser


def main(
    argv: Sequence[str] | None = None,
    *,
    read_line: Callable[[], str | None] = stdin_line,
    say: Callable[[str], None] = print,
) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    known = commissionings()
    parser = parser_of(known)
    split = argv.index("--ros-args") if "--ros-args" in argv else len(argv)
    ours, ros_args = argv[:split], argv[split:]  # the tool's options, then the bridge's
    args = parser.parse_args(ours)
    unknown = [name for name in args.bridges if name not in known]
    if unknown:
        parser.error(f"no hardware checks for {unknown[0]!r} (bridges: {', '.join(known)})")
    if args.write_docs or args.check_docs:
        return docs(args, known)
    if len(args.bridges) != 1:
        parser.error("name one bridge")
    commissioning = known[args.bridges[0]]
    try:
        values = parse_parameters(the_node(commissioning), ros_args, commissioning.described)
    except ConfigurationError as err:
        print(f"error: {one_line(err)}", file=sys.stderr)
        return EXIT_CONFIGURATION_ERROR
    try:
        report, code = run(commissioning, values, args, read_line, say)
    except LinkError as err:
        print(f"error: no reply from the device: {one_line(err)}", file=sys.stderr)
        return EXIT_NO_DEVICE
    for line in verdict_lines(report):
        say(line)
    write_report(report, args, say)
    return code


if __name__ == "__main__":
    sys.exit(main())
