"""A real rosbag2 (MCAP) bag recorded from a running R6 bridge reads back right."""

from __future__ import annotations

import contextlib
import math
import os
import sqlite3
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import rclpy
import yaml  # type: ignore[import-untyped]
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import try_shutdown
from rosbags.rosbag2 import Reader, StoragePlugin
from std_msgs.msg import Bool

from bridge_core.ros.recorder import DistroWriter, Recorder, ros_distro, typestore_for
from msg_defs.msg import R6State
from r6_bridge.sim import R6SimDevice, make_simulator

from ...support.ros import ROOT, Bridge, node_process, refused_at_start, ros_client, wait_for

pytestmark = pytest.mark.ros

# The bags' ros_distro: a sourced ROS's ROS_DISTRO, else the rclpy wheels' (Jazzy).
DISTRO = os.environ.get("ROS_DISTRO") or "jazzy"


def test_bag_of_a_running_bridge(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    simulator = make_simulator(axis_count=4)
    port = simulator.start_tcp()
    device = simulator.device
    assert isinstance(device, R6SimDevice)
    monkeypatch.setattr(device, "tick", lambda dt: None)  # hold the values still
    device.set("axis_position_2", 30.0)
    device.set("mode", 1)
    bag = tmp_path / "bag"
    ns = "/rec"
    topics = [
        f"{ns}/joint_states",
        f"{ns}/r6_bridge/state",
        "/diagnostics",
        f"{ns}/r6_bridge/connected",
    ]
    try:
        with node_process(
            "r6_bridge.node", {"port": port, "poll_rate_hz": 20.0}, tmp_path, ["-r", f"__ns:={ns}"]
        ):
            # The bridge publishing before the recorder's 6 s begin (a node that took them
            # to start, beside other busy processes, left an empty bag).
            with ros_client("recorder_probe") as client:
                bridge = Bridge(client, ns, "r6_bridge", R6State)
                client.wait_message(bridge.joint_states, timeout=60)
            result = subprocess.run(
                [
                    sys.executable,
                    "-m",
                    "bridge_core.ros.recorder",
                    "-o",
                    str(bag),
                    *topics,
                    "--duration",
                    "6",
                ],
                cwd=ROOT,
                capture_output=True,
                text=True,
                timeout=60,
            )
    finally:
        simulator.stop()
    assert result.returncode == 0, result.stdout + result.stderr
    assert (bag / "metadata.yaml").exists()
    assert list(bag.glob("*.mcap"))
    # The distribution recorded with, as ros2 bag record writes it, not "rosbags".
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["ros_distro"] == DISTRO, info["ros_distro"]

    store = typestore_for(["msg_defs/msg/R6State"])
    seen: dict[str, list[object]] = {t: [] for t in topics}
    with Reader(bag) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types == {
            f"{ns}/joint_states": "sensor_msgs/msg/JointState",
            f"{ns}/r6_bridge/state": "msg_defs/msg/R6State",
            "/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
            f"{ns}/r6_bridge/connected": "std_msgs/msg/Bool",
        }
        for connection, _, raw in reader.messages():
            seen[connection.topic].append(store.deserialize_cdr(raw, connection.msgtype))
    joint_states = seen[f"{ns}/joint_states"]
    states = seen[f"{ns}/r6_bridge/state"]
    diagnostics = seen["/diagnostics"]
    assert len(joint_states) >= 10 and len(states) >= 10 and diagnostics
    js = joint_states[-1]
    assert list(js.name) == ["joint_1", "joint_2", "joint_3", "joint_4"]  # type: ignore[attr-defined]
    assert js.position[1] == pytest.approx(math.radians(30.0))  # type: ignore[attr-defined]
    assert js.header.stamp.sec > 0  # type: ignore[attr-defined]
    state = states[-1]
    assert (state.mode, state.mode_name, state.axis_count) == (1, "manual", 4)  # type: ignore[attr-defined]
    hardware_ids = {s.hardware_id for d in diagnostics for s in d.status}  # type: ignore[attr-defined]
    assert f"Huacheng R6@tcp://127.0.0.1:{port} unit 1" in hardware_ids

    # An independent reader (mcap + mcap-ros2-support): every message decodes from the
    # schemas in the file, and the latched ~/connected keeps its offered QoS, so that
    # `ros2 bag play` replays it latched.
    (mcap_file,) = bag.glob("*.mcap")
    decoded: dict[str, int] = {}
    qos_of: dict[str, list[dict[str, object]]] = {}
    with mcap_file.open("rb") as stream:
        mcap_reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        # The copy of the metadata in the file (what `ros2 bag info FILE.mcap` reads).
        (embedded,) = [m for m in mcap_reader.iter_metadata() if m.name == "rosbag2"]
        assert yaml.safe_load(embedded.metadata["serialized_metadata"])["ros_distro"] == DISTRO
        for _schema, channel, _message, ros_msg in mcap_reader.iter_decoded_messages():
            decoded[channel.topic] = decoded.get(channel.topic, 0) + 1
            assert ros_msg is not None
            qos_of[channel.topic] = yaml.safe_load(channel.metadata["offered_qos_profiles"])
    assert decoded[f"{ns}/joint_states"] == len(joint_states)
    assert decoded[f"{ns}/r6_bridge/state"] == len(states)
    assert decoded[f"{ns}/r6_bridge/connected"] >= 1  # the latched value, at least
    (connected_qos,) = qos_of[f"{ns}/r6_bridge/connected"]
    assert connected_qos["durability"] in (1, "transient_local"), connected_qos
    assert connected_qos["reliability"] in (1, "reliable"), connected_qos
    (joint_states_qos,) = qos_of[f"{ns}/joint_states"]
    assert joint_states_qos["durability"] in (2, "volatile"), joint_states_qos

    # bridge_plot draws it: a PNG, and the summary counts what the bag holds.
    picture = tmp_path / "bag.png"
    result = subprocess.run(
        [sys.executable, "-m", "bridge_core.ros.plot", str(bag), "-o", str(picture)],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    samples = len(joint_states)
    joints = ", ".join(f"joint_{n} ({samples})" for n in range(1, 5))
    assert f"joints {joints}; link bands 1, diagnostics bands 1" in result.stdout, result.stdout


LATE_PUBLISHER_RUNS = 20
LATCHED = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)


def test_a_latched_topic_whose_subscriber_appears_first(tmp_path: Path) -> None:
    """A monitor subscribes to ``~/connected`` before the bridge publishes it (the demo's
    monitor does): the recorder waits for a publisher, records its QoS (transient local)
    and gets the latched value, every time (20 runs)."""
    context = Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    try:
        for run in range(LATE_PUBLISHER_RUNS):
            _record_a_late_publisher(run, tmp_path / f"bag_{run}", context, executor)
    finally:
        executor.shutdown()
        try_shutdown(context=context)


def _record_a_late_publisher(run: int, bag: Path, context: Context, executor: Any) -> None:
    def spin_until(predicate: Callable[[], bool], what: str) -> None:
        def spun() -> bool:
            executor.spin_once(timeout_sec=0.02)
            return predicate()

        wait_for(spun, 20, f"run {run}: {what}")

    topic = f"/late_{run}/connected"
    monitor = Node(f"monitor_{run}", context=context)
    monitor.create_subscription(Bool, topic, lambda _msg: None, 10)
    recorder = Recorder(bag, [topic], StoragePlugin.MCAP, context=context)
    bridge = Node(f"bridge_{run}", context=context)
    for node in (monitor, recorder, bridge):
        executor.add_node(node)
    try:
        # The recorder sees the topic (the monitor's), then looks at it twice more.
        spin_until(lambda: topic in dict(recorder.get_topic_names_and_types()), "the topic")
        passes = recorder.discover_passes
        spin_until(lambda: recorder.discover_passes >= passes + 2, "two discovery passes")
        bridge.create_publisher(Bool, topic, LATCHED).publish(Bool(data=True))
        spin_until(lambda: recorder.counts[topic] >= 1, "the latched value recorded")
    finally:
        recorder.close()
        for node in (monitor, recorder, bridge):
            executor.remove_node(node)
            node.destroy_node()
    metadata = yaml.safe_load((bag / "metadata.yaml").read_text())
    (entry,) = metadata["rosbag2_bagfile_information"]["topics_with_message_count"]
    offered = entry["topic_metadata"]["offered_qos_profiles"]
    assert "transient_local" in str(offered), f"run {run}: offered QoS {offered!r}"
    assert entry["message_count"] == 1, f"run {run}"


VOLATILE = QoSProfile(
    depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE
)


def test_a_latched_publisher_that_appears_after_a_volatile_one(tmp_path: Path) -> None:
    """A volatile publisher of a topic is discovered first (the recorder takes the topic
    up volatile), a latched one appears later: the recorder subscribes transient local
    too, so the bag holds the latched value (once), what the volatile publisher sends
    afterwards still (a transient-local subscription alone gets nothing from it), and the
    offered QoS of both; the bag reads back with rosbags' reader. Every time (20 runs)."""
    context = Context()
    rclpy.init(context=context)
    executor = SingleThreadedExecutor(context=context)
    try:
        for run in range(LATE_PUBLISHER_RUNS):
            _record_a_late_latched_publisher(run, tmp_path / f"bag_{run}", context, executor)
    finally:
        executor.shutdown()
        try_shutdown(context=context)


def _record_a_late_latched_publisher(run: int, bag: Path, context: Context, executor: Any) -> None:
    def spin_until(predicate: Callable[[], bool], what: str) -> None:
        def spun() -> bool:
            executor.spin_once(timeout_sec=0.02)
            return predicate()

        wait_for(spun, 20, f"run {run}: {what}")

    topic = f"/late_latched_{run}/connected"
    volatile = Node(f"volatile_{run}", context=context)
    live = volatile.create_publisher(Bool, topic, VOLATILE)
    recorder = Recorder(bag, [topic], StoragePlugin.MCAP, context=context)
    latched = Node(f"latched_{run}", context=context)
    nodes = (volatile, recorder, latched)
    for node in nodes:
        executor.add_node(node)

    def recorder_durabilities() -> list[DurabilityPolicy]:
        """The durability of each subscription the recorder has on ``topic`` (the graph)."""
        return sorted(
            info.qos_profile.durability
            for info in volatile.get_subscriptions_info_by_topic(topic)
            if info.node_name == recorder.get_name()
        )

    both = sorted([DurabilityPolicy.VOLATILE, DurabilityPolicy.TRANSIENT_LOCAL])
    try:
        # The recorder takes the topic up from the volatile publisher alone.
        spin_until(lambda: recorder_durabilities() != [], "the recorder subscribed")
        assert recorder_durabilities() == [DurabilityPolicy.VOLATILE], f"run {run}"
        passes = recorder.discover_passes
        spin_until(lambda: recorder.discover_passes >= passes + 2, "two discovery passes")
        latched.create_publisher(Bool, topic, LATCHED).publish(Bool(data=True))
        spin_until(lambda: recorder_durabilities() == both, "a transient-local subscription")
        spin_until(lambda: recorder.counts[topic] >= 1, "the latched value recorded")
        live.publish(Bool(data=False))
        spin_until(lambda: recorder.counts[topic] >= 2, "the volatile publisher's message")
    finally:
        recorder.close()
        for node in nodes:
            executor.remove_node(node)
            node.destroy_node()
    store = typestore_for(["std_msgs/msg/Bool"])
    with Reader(bag) as reader:
        offered = [c.ext.offered_qos_profiles for c in reader.connections]  # type: ignore[union-attr]
        values = [
            store.deserialize_cdr(raw, c.msgtype).data  # type: ignore[attr-defined]
            for c, _, raw in reader.messages()
        ]
    assert values == [True, False], f"run {run}: {values}"
    # The topic's newest connection lists both publishers' QoS (a connection's QoS cannot
    # change once written: the volatile-only one stays first).
    durabilities = sorted(profile.durability.name for profile in offered[-1])
    assert durabilities == ["TRANSIENT_LOCAL", "VOLATILE"], f"run {run}: {offered}"


@pytest.mark.parametrize(
    ("ros_args", "named"),
    [
        (["--ros-args", "--no-such-flag"], "--no-such-flag"),
        (["--ros-args", "-r", "no_separator"], "no_separator"),
    ],
    ids=["unknown-flag", "bad-remap"],
)
def test_a_command_line_rcl_refuses_is_one_line_and_exit_2(
    tmp_path: Path, ros_args: list[str], named: str
) -> None:
    """What rcl cannot parse is said on one line (exit 2), as the bridges say it, and no
    bag is started."""
    bag = tmp_path / "bag"
    line = refused_at_start("bridge_core.ros.recorder", ["-o", str(bag), "/x", *ros_args])
    assert line.startswith("error: ") and named in line, line
    assert not bag.exists()


def test_the_distro_is_rosdistro_else_the_rclpy_wheels(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("ROS_DISTRO", "rolling")
    assert ros_distro() == "rolling"
    monkeypatch.delenv("ROS_DISTRO")
    assert ros_distro() == "jazzy"  # this venv's ros-jazzy-rclpy


def test_a_sqlite3_bag_names_the_distro_in_both_copies(tmp_path: Path) -> None:
    """metadata.yaml and the metadata table of the .db3 (plain Python: no ROS graph)."""
    bag = tmp_path / "bag"
    writer = DistroWriter(bag, version=9, storage_plugin=StoragePlugin.SQLITE3, distro="jazzy")
    writer.open()
    store = typestore_for(["std_msgs/msg/Bool"])
    connection = writer.add_connection("/flag", "std_msgs/msg/Bool", typestore=store)
    writer.write(connection, 1, store.serialize_cdr(Bool(data=True), "std_msgs/msg/Bool"))
    writer.close()
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["ros_distro"] == "jazzy"
    (db3,) = bag.glob("*.db3")
    with contextlib.closing(sqlite3.connect(db3)) as db:
        (text,) = db.execute("SELECT metadata FROM metadata").fetchone()
    assert yaml.safe_load(text)["ros_distro"] == "jazzy"
