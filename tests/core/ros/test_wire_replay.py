"""A recording of the wire replays into the same ``joint_states`` (docs/tools.md,
"Recording the wire"), end to end with real processes and a real bag:

the R6 bridge with ``record_wire`` on polls its simulator (the axes moving) while
``bridge_record`` records its ``~/wire`` and ``joint_states``; then ``bridge_replay``
serves that bag over TCP and a second bridge (``record_wire`` off) polls the replay:
it publishes the recorded positions in the recorded order. On the way: the parameter
is read-only (a set is refused), ``~/wire`` outlives a lifecycle cleanup, the recording
node's diagnostics count its frames, and with the parameter off there is no ``~/wire``.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
from rcl_interfaces.srv import SetParameters
from rosbags.rosbag2 import Reader
from sensor_msgs.msg import JointState

from bridge_core.ros.recorder import typestore_for
from msg_defs.msg import ModbusFrame
from r6_bridge.sim import R6SimDevice, make_simulator

from ...support.ros import ROOT, Client, node_process, ros_client, values_of, wait_for

pytestmark = pytest.mark.ros

NODE = "r6_bridge"
POLL_RATE_HZ = 20.0
# The slow group read once at start, in both runs: a replay that reads it at another
# moment than the recording did would take its reply from there and skip ahead.
SLOW_PERIOD_S = 3600.0
RECORDED_POLLS = 40  # two seconds of them
START_S = 60.0
DIAGNOSTICS_KEY = "wire frames published / dropped"
SNAPSHOTS_DROPPED_KEY = "snapshots dropped (publisher behind)"  # node_diagnostics


def change(client: Client, node: str, transition: int) -> None:
    request = ChangeState.Request()
    request.transition.id = transition
    assert client.call(ChangeState, f"{node}/change_state", request).success


def activate(client: Client, node: str) -> None:
    change(client, node, Transition.TRANSITION_CONFIGURE)
    change(client, node, Transition.TRANSITION_ACTIVATE)


def bridge_params(port: int, record: bool) -> dict[str, Any]:
    return {
        "port": port,
        "poll_rate_hz": POLL_RATE_HZ,
        "slow_poll_period_s": SLOW_PERIOD_S,
        "autostart": False,
        "record_wire": record,
    }


def nanoseconds(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def positions(messages: list[Any]) -> list[tuple[float, ...]]:
    return [tuple(round(p, 9) for p in m.position) for m in messages]


def snapshots_dropped(client: Client, node: str, after: float) -> int:
    """The node's count of snapshots dropped, from a status published after ``after``."""
    name = f"{node}: "

    def counted() -> tuple[int] | None:  # a tuple: a count of 0 is an answer
        for array in client.received("/diagnostics", after):
            for status in array.status:
                value = values_of(status).get(SNAPSHOTS_DROPPED_KEY)
                if status.name.startswith(name) and value is not None:
                    return (int(value),)
        return None

    (count,) = wait_for(counted, START_S, f"{node}'s '{SNAPSHOTS_DROPPED_KEY}'")
    assert isinstance(count, int)
    return count


def refused_set(client: Client, node: str) -> str:
    request = SetParameters.Request()
    request.parameters = [
        Parameter(
            name="record_wire",
            value=ParameterValue(type=ParameterType.PARAMETER_BOOL, bool_value=False),
        )
    ]
    (result,) = client.call(SetParameters, f"{node}/set_parameters", request).results
    assert not result.successful
    return str(result.reason)


def record(tmp_path: Path, bag: Path) -> list[tuple[float, ...]]:
    """Run the recording bridge under bridge_record; the positions it published."""
    simulator = make_simulator(axis_count=4)
    device = simulator.device
    assert isinstance(device, R6SimDevice)
    device.running = True  # the axes move: every poll reads other positions
    port = simulator.start_tcp()
    ns = "/rec"
    topics = [f"{ns}/joint_states", f"{ns}/{NODE}/wire"]
    try:
        with (
            node_process(
                "r6_bridge.node", bridge_params(port, True), tmp_path, ["-r", f"__ns:={ns}"]
            ),
            ros_client("wire_record_probe") as client,
        ):
            client.subscribe(DiagnosticArray, "/diagnostics")
            client.subscribe(JointState, topics[0], 100)
            wait_for(
                lambda: client.node.count_publishers(topics[1]) > 0, START_S, "~/wire advertised"
            )
            assert "read-only" in refused_set(client, f"{ns}/{NODE}")
            recorder = subprocess.Popen(
                [sys.executable, "-m", "bridge_core.ros.recorder", "-o", str(bag), *topics],
                cwd=ROOT,
                stdout=subprocess.PIPE,
                stderr=subprocess.STDOUT,
                text=True,
            )
            try:
                # Every frame from the first: the recorder has taken up both topics
                # before the bridge is activated (its link opens with the first poll).
                assert recorder.stdout is not None
                taken = 0
                deadline = time.monotonic() + START_S
                while taken < len(topics) and time.monotonic() < deadline:
                    taken += "recording /rec/" in recorder.stdout.readline()
                assert taken == len(topics), "the recorder did not take up the topics"
                # Configured, cleaned up, then configured again: ~/wire outlives a cleanup.
                change(client, f"{ns}/{NODE}", Transition.TRANSITION_CONFIGURE)
                change(client, f"{ns}/{NODE}", Transition.TRANSITION_CLEANUP)
                activate(client, f"{ns}/{NODE}")
                wait_for(
                    lambda: len(client.received(topics[0])) >= RECORDED_POLLS,
                    START_S,
                    f"{RECORDED_POLLS} polls",
                )
                status = client.wait_message(
                    "/diagnostics",
                    lambda m: any(DIAGNOSTICS_KEY in values_of(s) for s in m.status),
                    timeout=START_S,
                )
                (counted,) = [
                    values_of(s)[DIAGNOSTICS_KEY]
                    for s in status.status
                    if DIAGNOSTICS_KEY in values_of(s)
                ]
                assert counted.split(" / ")[1] == "0", counted  # nothing dropped
            finally:
                recorder.send_signal(signal.SIGINT)
                output, _ = recorder.communicate(timeout=30)
            assert recorder.returncode == 0, output
    finally:
        simulator.stop()
    store = typestore_for(["sensor_msgs/msg/JointState"])
    with Reader(bag) as reader:
        recorded: list[Any] = [
            store.deserialize_cdr(raw, c.msgtype)
            for c, _, raw in reader.messages()
            if c.topic == topics[0]
        ]
        frames = sum(c.msgcount for c in reader.connections if c.topic == topics[1])
    assert frames > len(recorded) > 10
    # An independent reader (mcap + mcap-ros2-support) decodes the frames from the schema
    # bridge_record wrote: the bag stays readable by other tools (ros2 bag reads the same).
    (mcap_file,) = bag.glob("*.mcap")
    with mcap_file.open("rb") as stream:
        mcap = make_reader(stream, decoder_factories=[DecoderFactory()])
        decoded = [m for _s, c, _m, m in mcap.iter_decoded_messages() if c.topic == topics[1]]
    assert len(decoded) == frames
    assert all(m.outcome == ModbusFrame.OK and len(m.reply) > 7 for m in decoded)
    # The recorder is stopped while the bridge polls, and the bridge publishes a poll's
    # frames from a thread of their own: the bag can hold a poll's joint_states but not
    # yet the frame its positions came from (a fresh-clone CI run saw the replay never
    # reach the bag's last positions). A joint_states is stamped when the reply holding
    # its positions arrived, and frames are published in order: with a frame sent after
    # that stamp in the bag, its positions' frame is there too. Only those are compared.
    last_sent = max(nanoseconds(m.sent) for m in decoded)
    complete = [m for m in recorded if nanoseconds(m.header.stamp) < last_sent]
    assert len(complete) > len(recorded) // 2, (len(recorded), len(complete))
    return positions(complete)


def test_a_recording_replays_into_the_same_joint_states(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    recorded = record(tmp_path, bag)
    assert len(set(recorded)) > 10, "the axes did not move"

    port_file = tmp_path / "replay.port"
    writes = tmp_path / "writes.jsonl"
    replay = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "bridge_core.sim.replay",
            str(bag),
            "--port",
            "0",
            "--port-file",
            str(port_file),
            "--write-log",
            str(writes),
        ],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    ns = "/replayed"
    failure = ""
    try:
        assert replay.stdout is not None
        banner = replay.stdout.readline()
        assert "TCP frames of unit(s) 1" in banner and "listening on 127.0.0.1:" in banner, banner
        port = int(port_file.read_text())
        with (
            node_process(
                "r6_bridge.node", bridge_params(port, False), tmp_path, ["-r", f"__ns:={ns}"]
            ),
            ros_client("wire_replay_probe") as client,
        ):
            client.subscribe(JointState, f"{ns}/joint_states", 100)
            client.subscribe(DiagnosticArray, "/diagnostics")
            wait_for(
                lambda: client.node.count_publishers(f"{ns}/joint_states") > 0,
                START_S,
                "the bridge on the replay",
            )
            wait_for(
                lambda: (
                    client.node.count_subscribers(f"{ns}/joint_states") > 0
                    and f"{ns}/{NODE}/change_state"
                    in dict(client.node.get_service_names_and_types())
                ),
                START_S,
                "its lifecycle services",
            )
            # Off: no ~/wire on the graph.
            assert f"{ns}/{NODE}/wire" not in dict(client.node.get_topic_names_and_types())
            activate(client, f"{ns}/{NODE}")
            last = recorded[-1]
            try:
                wait_for(
                    lambda: last in positions(client.received(f"{ns}/joint_states")),
                    START_S,
                    "the recording's last positions",
                )
            except AssertionError as err:
                seen = positions(client.received(f"{ns}/joint_states"))
                failure = (
                    f"{err}: replayed {len(seen)} (last 3: {seen[-3:]}), recorded "
                    f"{len(recorded)} (last 3: {recorded[-3:]})"
                )
                raise
            replayed = positions(client.received(f"{ns}/joint_states"))
            dropped = snapshots_dropped(client, f"{ns}/{NODE}", time.monotonic())
    finally:
        replay.send_signal(signal.SIGINT)
        _, errors = replay.communicate(timeout=10)
        if failure:  # what the replay said goes with the failure
            raise AssertionError(f"{failure}; bridge_replay said: {errors[-2000:]}") from None
    replayed = replayed[: replayed.index(last) + 1]
    assert replayed[0] == recorded[0]
    # The same positions in the same order. Only a snapshot the replaying node itself
    # dropped (its publisher behind, possible on a loaded machine) may be missing, and its
    # diagnostics count each one; with none counted the two lists are equal.
    if dropped == 0:
        assert replayed == recorded
    found = iter(recorded)
    assert all(any(p == r for r in found) for p in replayed), (replayed, recorded)
    assert len(replayed) >= len(recorded) - dropped, (len(replayed), len(recorded), dropped)
    assert "not recorded" not in errors, errors
    assert writes.read_text() == ""  # the R6 bridge polls: it wrote nothing
