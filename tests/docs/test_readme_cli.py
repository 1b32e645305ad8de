"""The ros2 command lines of docs/ros2-cli.md and docs/actions.md, and the action examples of
every page under docs/, run as typed against the demo; then the demo's
console (every device connected and moving) and its Ctrl-C, so the suite starts the whole
demo once.

There is no ``ros2`` command here (PyPI wheels), so each line is done the way the CLI does
it: its YAML read with ``yaml.safe_load`` (what ``ros2 service call`` / ``topic pub`` use)
and set field by field on the request or message, the call made through rclpy. A key the
interface does not have, or a value of the wrong type, fails (e.g. a field named ``on``:
YAML reads that key as the boolean true).
"""

from __future__ import annotations

import contextlib
import importlib
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import pytest
import yaml  # type: ignore[import-untyped]
from rcl_interfaces.srv import SetParameters
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from std_srvs.srv import Trigger

from stepper_bridge.demo import DEMO as STEPPER_DEMO

from ..support.ros import (
    ROOT,
    WAIT_S,
    Client,
    interrupt,
    ros_client,
    wait_for,
    wait_subscribed,
)

pytestmark = pytest.mark.ros

# Each block of lines: the page, and the heading of the section whose ```bash block it is.
CLI_PAGE = ROOT / "docs" / "ros2-cli.md"
ACTIONS_PAGE = ROOT / "docs" / "actions.md"
SECTION = "## Against the demo"
ACTIONS_SECTION = "## Against the demo"
DEMO_S = 300  # the demo's --duration: far beyond the test, which stops it itself
DEMO_START_S = 180.0  # four simulators and bridges on a loaded machine


# A docs goal's longest run against the demo (the stepper's home at 9600 baud).
ACTION_END_S = 90.0
# A docs action example: its code span (the command with its arguments: a span that only
# names the command is prose), and the mark of one that cannot run against the demo, right
# after it.
DOCS_SEND_GOAL = re.compile(r"`(ros2 action send_goal\s[^`]*)`(\s*\(real device only\b)?")


def doc_commands(page: Path = CLI_PAGE, heading: str = SECTION) -> list[list[str]]:
    """The lines of the bash block of the page's section, split as the shell splits them."""
    text = page.read_text()
    section = text.split(heading, 1)[1].split("\n## ", 1)[0]
    block = section.split("```bash\n", 1)[1].split("```", 1)[0]
    return [shlex.split(line) for line in block.splitlines() if line.strip()]


def interface(type_name: str) -> Any:
    """``pkg/srv/Name``, ``pkg/msg/Name`` or ``pkg/action/Name`` -> the Python class."""
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def filled(instance: Any, text: str) -> Any:
    """``instance`` with the fields of the YAML ``text`` set (the generated setters check
    the types; a key the interface lacks is an error)."""
    fields = yaml.safe_load(text) or {}
    assert isinstance(fields, dict), text
    known = instance.get_fields_and_field_types()
    for key, value in fields.items():
        assert isinstance(key, str) and key in known, f"{key!r} is not a field of {known}"
        setattr(instance, key, value)
    return instance


@dataclass
class DemoRun:
    """The module's demo process and the file its console goes to."""

    process: subprocess.Popen[bytes]
    out: Path
    interrupted: bool = False  # the Ctrl-C test ended it

    def text(self) -> str:
        return self.out.read_text(errors="replace")


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[DemoRun]:
    """The demo, started once for the module: the docs' lines run against it, its console
    is checked, and the module's last test ends it with a Ctrl-C (else it is ended here)."""
    out = tmp_path_factory.mktemp("demo") / "demo.out"
    log = out.open("wb")
    proc = subprocess.Popen(
        [sys.executable, "-m", "bridge_core.ros.demo", "--duration", str(DEMO_S)],
        cwd=ROOT,
        env=dict(os.environ),
        stdout=log,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        # A process group of its own (a failed test kills its children too), in the tests'
        # session: with the kernel's autogroup scheduling a session of its own is a CPU
        # group, and beside two CPU burners the demo's R6 simulator went unanswered past
        # the R6's 0.5 s timeout there (a run_cycle goal ended LINK_LOST); the simulators
        # of the other tests stay in this session for the same reason (SimProcess).
        process_group=0,
    )
    try:
        # The demo's first report comes after its start services (the drives enabled, the
        # R6 started...): the docs' lines are typed at a demo that is up.
        wait_for(
            lambda: b"--- t =" in out.read_bytes() or proc.poll() is not None,
            DEMO_START_S,
            "the demo's first report",
        )
        assert proc.poll() is None, f"the demo ended at start; see {out}"
        yield DemoRun(proc, out)
    finally:
        interrupt(proc, 60)
        with contextlib.suppress(ProcessLookupError):  # the simulators and nodes it left
            os.killpg(proc.pid, signal.SIGKILL)
        log.close()


@pytest.fixture(scope="module")
def demo(demo_run: DemoRun) -> Iterator[Client]:
    with ros_client("readme_cli_client") as client:
        yield client
    assert demo_run.interrupted or demo_run.process.poll() is None, "the demo ended during the test"


def test_every_cli_command_line_works_as_typed(demo: Client) -> None:
    client = demo
    commands = doc_commands()
    assert len(commands) >= 6, commands
    for words in commands:
        assert words[0] == "ros2", words
        what = " ".join(words)
        match words[1:3]:
            case ["service", "call"]:
                name, type_name, text = words[3:6]
                srv = interface(type_name)
                reply = client.call(srv, name, filled(srv.Request(), text), timeout=WAIT_S * 3)
                assert reply.success, f"{what}: {reply.message}"
            case ["topic", "pub"]:
                assert words[3] == "--once", what
                name, type_name, text = words[4:7]
                msg_type = interface(type_name)
                publisher = client.node.create_publisher(msg_type, name, 10)
                wait_subscribed(publisher, timeout=WAIT_S * 3)
                publisher.publish(filled(msg_type(), text))
                client.node.destroy_publisher(publisher)
            case ["topic", "echo"]:
                name, flags = words[-1], words[3:-1]
                assert set(flags) <= {"--once"}, f"{what}: flags {flags} not handled here"

                def topic_type(name: str = name) -> Any:
                    types = dict(client.node.get_topic_names_and_types())
                    return types.get(name, [None])[0]

                type_name = wait_for(topic_type, WAIT_S * 3, f"{name} to appear")

                # As ros2 topic echo does: the QoS its publishers offer (a latched topic's
                # current value at once), known once a publisher is.
                def publishers(name: str = name) -> list[Any]:
                    return list(client.node.get_publishers_info_by_topic(name))

                offered = wait_for(publishers, WAIT_S * 3, f"a publisher of {name}")
                qos = QoSProfile(depth=10)
                if all(
                    p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in offered
                ):
                    qos.durability = DurabilityPolicy.TRANSIENT_LOCAL
                if all(p.qos_profile.reliability == ReliabilityPolicy.RELIABLE for p in offered):
                    qos.reliability = ReliabilityPolicy.RELIABLE
                client.subscribe(interface(type_name), name, qos)
                client.wait_message(name, timeout=WAIT_S * 3)
            case ["topic", "hz"]:
                # A rate needs a stream: ten messages in a row (no wall-clock figure here).
                name = words[3]
                client.subscribe(interface("sensor_msgs/msg/JointState"), name)
                since = time.monotonic()

                def ten(name: str = name, since: float = since) -> bool:
                    return len(client.received(name, since)) >= 10

                wait_for(ten, WAIT_S * 3, f"ten messages on {name}")
            case ["param", "set"]:
                node, parameter, text = words[3:6]
                request = SetParameters.Request()
                value = yaml.safe_load(text)
                request.parameters = [Parameter(parameter, value=value).to_parameter_msg()]
                reply = client.call(SetParameters, f"{node}/set_parameters", request)
                (result,) = reply.results
                assert result.successful, f"{what}: {result.reason}"
            case _:
                raise AssertionError(f"{what}: not a command this test knows")


def run_goal_to_its_end(client: Client, words: list[str]) -> None:
    """One ``ros2 action send_goal [--feedback] <name> <type> <yaml>`` line as typed: the
    goal is accepted, sends feedback and runs to its end, REACHED."""
    what = " ".join(words)
    assert words[:3] == ["ros2", "action", "send_goal"], what
    arguments = [word for word in words[3:] if word != "--feedback"]
    assert len(arguments) == 3, f"{what}: flags not handled here"
    name, type_name, text = arguments
    action = interface(type_name)
    goal = client.send_goal(action, name, filled(action.Goal(), text), timeout=WAIT_S * 3)
    try:
        assert goal.accepted, f"{what}: rejected (see the demo's log)"
        assert goal.fed_before_end(ACTION_END_S), f"{what}: no feedback"
        _status, result = goal.result(timeout=ACTION_END_S)
        assert result.outcome.name == "REACHED", f"{what}: {result.outcome}"
    finally:
        goal.close()


def device_of(words: list[str]) -> str:
    """The demo device a ``ros2 service call`` / ``action send_goal`` line talks to: its
    name's namespace (``/r6/r6_bridge/stop`` -> ``/r6``)."""
    name = next(word for word in words[3:] if word.startswith("/"))
    return "/" + name.split("/")[1]


def per_device(
    lines: list[Any], run: Callable[[Any], None], words: Callable[[Any], list[str]]
) -> None:
    """Each device's lines in their order, the devices side by side: the demo's four
    simulators are independent, so what a user types for one does not wait on another's
    motion (the R6's single cycle and the stepper's home take ~12 s each). Every device's
    failure is reported, the first raised."""
    groups: dict[str, list[Any]] = {}
    for line in lines:
        groups.setdefault(device_of(words(line)), []).append(line)

    def run_group(group: list[Any]) -> None:
        for line in group:
            run(line)

    with ThreadPoolExecutor(max_workers=len(groups) or 1) as pool:
        futures = [pool.submit(run_group, group) for group in groups.values()]
    errors = [err for future in futures if (err := future.exception()) is not None]
    if errors:
        raise errors[0]


def test_every_actions_page_line_works_as_typed(demo: Client) -> None:
    """docs/actions.md's block, as a user types it against the demo: each goal is accepted,
    sends feedback and runs to its end, REACHED; a service call in it (the R6 program
    stopped before a single cycle, R6 decision 23) succeeds. Each device's lines in their
    order, the devices side by side (``per_device``)."""
    commands = doc_commands(ACTIONS_PAGE, ACTIONS_SECTION)
    assert len(commands) >= 3, commands

    def run(words: list[str]) -> None:
        if words[1:3] == ["service", "call"]:
            name, type_name, text = words[3:6]
            srv = interface(type_name)
            reply = demo.call(srv, name, filled(srv.Request(), text), timeout=WAIT_S * 3)
            assert reply.success, f"{' '.join(words)}: {reply.message}"
            return
        assert "--feedback" in words, " ".join(words)
        run_goal_to_its_end(demo, words)

    per_device(commands, run, lambda words: words)


def docs_action_lines() -> list[tuple[str, list[str], bool]]:
    """Every ``ros2 action send_goal`` code span of the pages under docs/ (one wrapped over
    lines is joined, as the shell would take it pasted on one line): (page, words, marked
    "real device only")."""
    found = []
    for path in sorted((ROOT / "docs").rglob("*.md")):
        for match in DOCS_SEND_GOAL.finditer(path.read_text()):
            words = shlex.split(" ".join(match.group(1).split()))
            found.append((str(path.relative_to(ROOT)), words, match.group(2) is not None))
    return found


def test_every_docs_action_line_works_as_typed_or_is_marked(demo: Client) -> None:
    """The docs' send_goal examples against the same demo: each runs to its end, REACHED,
    unless it is marked "(real device only: why)" right after it (a check that needs the
    pendant, the wiring or settings the demo does not start with). A line docs/actions.md's
    block holds too (but for ``--feedback``) ran there already. The devices side by side,
    as in the block's test."""
    lines = docs_action_lines()
    marked = [words for _file, words, real_only in lines if real_only]
    runnable = [(file, words) for file, words, real_only in lines if not real_only]
    assert len(marked) >= 3 and len(runnable) >= 3, lines
    in_block = {_without_feedback(words) for words in doc_commands(ACTIONS_PAGE, ACTIONS_SECTION)}

    def run(line: tuple[str, list[str]]) -> None:
        file, words = line
        try:
            run_goal_to_its_end(demo, words)
        except AssertionError as err:
            raise AssertionError(f"{file}: {err}") from err

    todo = [line for line in runnable if _without_feedback(line[1]) not in in_block]
    stop_the_motors_the_demo_started(demo)
    per_device(todo, run, lambda line: line[1])


def stop_the_motors_the_demo_started(demo: Client) -> None:
    """The docs' checks begin with the motors at rest, as on a commissioning bench; the
    demo's start services leave stepper motors running (``motor_<n>/forward``,
    ``/reverse``), and docs/ros2-cli.md's block stops them only when its test runs first
    against the same demo. So each gets its ``motor_<n>/stop`` here, whatever ran before."""
    for service, _type, _fields in STEPPER_DEMO.start_services:
        motor, _, verb = service.rpartition("/")
        if verb in ("forward", "reverse"):
            name = STEPPER_DEMO.service(f"{motor}/stop")
            reply = demo.call(Trigger, name, Trigger.Request(), timeout=WAIT_S * 3)
            assert reply.success, f"{name}: {reply.message}"


def _without_feedback(words: list[str]) -> tuple[str, ...]:
    return tuple(word for word in words if word != "--feedback")


def test_a_yaml_key_named_on_is_not_a_field_name() -> None:
    """Why SetOutput's field is ``state``: the CLI's YAML turns ``on`` into True."""
    from msg_defs.srv import SetOutput

    with pytest.raises(AssertionError, match="True"):
        filled(SetOutput.Request(), "{board: 0, index: 3, on: true}")
    assert filled(SetOutput.Request(), "{board: 0, index: 3, state: true}").state is True


def test_demo_shows_moving_r6(demo_run: DemoRun) -> None:
    """The demo's console (docs/ros2-cli.md, "The demo"): every device connected with OK
    diagnostics, its start services done, and each device's joints moving from one report
    to the next."""

    def reports(prefix: str) -> list[str]:
        return [line for line in demo_run.text().splitlines() if line.startswith(prefix)]

    prefixes = {
        "R6": "   joints (deg): joint_1",
        "xArm": "   joints (deg): joint1",
        "stepper": "   joints (deg): motor_1",
        "MOTEC": "   joints (deg): drive_1",
    }

    def moved(prefix: str) -> bool:
        return len(set(reports(prefix))) >= 2

    for device, prefix in prefixes.items():
        wait_for(partial(moved, prefix), WAIT_S * 3, f"two different {device} reports")
    out = demo_run.text()
    assert "start: done" in out
    # The R6 moved more than a degree from its first report: at some report, not at the
    # last (the docs' lines stop its program and run one cycle back to 0 before this test).
    joint_1 = [float(block.split()[3]) for block in reports(prefixes["R6"])]
    assert max(abs(value - joint_1[0]) for value in joint_1) > 1.0, out
    assert "[R6] connected  diagnostics OK" in out
    assert "[xArm] connected  diagnostics OK" in out
    assert "run_offline_task [1, 2, 3, 4, 5, 6]: done" in out
    assert "[Stepper] connected  diagnostics OK" in out
    for unit in (1, 2, 3):
        assert f"[MOTEC motec_{unit}] connected  diagnostics OK" in out
        assert f"/motec/motec_{unit}/move: move by {100.0 * unit} rad: done" in out


def test_demo_ends_cleanly_on_ctrl_c(demo_run: DemoRun) -> None:
    """Ctrl-C while the demo runs (this module's last test): exit 0, no traceback, the last
    line says it stopped."""
    assert demo_run.process.poll() is None, "the demo ended during the test"
    demo_run.interrupted = True
    demo_run.process.send_signal(signal.SIGINT)
    code = demo_run.process.wait(60)
    text = demo_run.text()
    assert code == 0, text
    assert "Traceback" not in text and "Exception" not in text, text
    assert text.strip().splitlines()[-1] == "bridge_demo: stopped", text
