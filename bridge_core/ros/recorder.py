"""``bridge_record``: record chosen topics to a rosbag2 bag, for machines without ``ros2 bag``.

Subscribes with ``raw=True`` and writes the CDR bytes as received, so nothing is decoded
and re-encoded; each topic's offered QoS (its publishers') goes into the bag's metadata, as
``ros2 bag record`` does, so a replay of a latched topic is latched; the bag (MCAP by
default, rosbag2 version 9) is written with the pure-Python ``rosbags`` library and plays
back with ``ros2 bag play``. Types not in
rosbags' Jazzy typestore (our own ``msg_defs``) are registered from their ``.msg`` files.
The metadata names the ROS distribution recorded with (``ros_distro``), as ``ros2 bag
record`` does, not the writing library (``DistroWriter``).
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import os
import re
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import ok as rclpy_ok
from rclpy.utilities import try_shutdown
from rosbags.interfaces import (
    ConnectionExtRosbag2,
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from .command_line import EXIT_CONFIGURATION_ERROR, init_from_command_line

# What rosbags (0.11) writes as the bag's ``ros_distro``, in metadata.yaml and in the copy of
# the metadata inside the storage file; DistroWriter puts the real distribution there.
ROSBAGS_DISTRO_LINE = re.compile(r"^(\s*ros_distro: )rosbags$", re.MULTILINE)
# The PyPI wheels' meta-package of rclpy names the distribution: ros-jazzy-rclpy.
RCLPY_WHEEL = re.compile(r"ros-([a-z]+)-rclpy")


def ros_distro() -> str:
    """The ROS distribution recorded with, as ``ros2 bag record`` writes it: ``ROS_DISTRO``
    (set by a sourced ROS install), else the distribution of the installed rclpy wheels
    (``ros-jazzy-rclpy``: "jazzy"), else "" (what rosbag2 writes with no ROS_DISTRO)."""
    distro = os.environ.get("ROS_DISTRO", "").strip()
    if distro:
        return distro
    for dist in importlib.metadata.distributions():
        match = RCLPY_WHEEL.fullmatch((dist.metadata["Name"] or "").lower())
        if match:
            return match.group(1)
    return ""


class DistroWriter(Writer):
    """rosbags' ``Writer`` with the bag's ``ros_distro`` the ROS distribution (``ros_distro()``)
    instead of "rosbags": in metadata.yaml and in the copy the storage keeps (an MCAP file's
    ``rosbag2`` metadata record, sqlite3's metadata table), which ``ros2 bag info`` reads
    when given the file alone. rosbags builds that text inside ``close()`` with no hook: the
    storage's ``close`` gets it corrected, and metadata.yaml is corrected after."""

    def __init__(self, *args: Any, distro: str, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.distro = distro

    def _with_distro(self, metadata: str) -> str:
        return ROSBAGS_DISTRO_LINE.sub(lambda m: m.group(1) + (self.distro or "''"), metadata)

    def open(self) -> None:
        super().open()
        storage = self.storage
        assert storage is not None
        close_storage = storage.close

        def close(version: int, metadata: str) -> None:
            close_storage(version, self._with_distro(metadata))

        setattr(storage, "close", close)  # noqa: B010 (an instance's method, on purpose)

    def close(self) -> None:
        super().close()
        text = self.metapath.read_text("utf8")
        tmp = self.metapath.with_suffix(".yaml.tmp")
        tmp.write_text(self._with_distro(text), "utf8")
        tmp.replace(self.metapath)


def message_class(type_name: str) -> Any:
    """``pkg/msg/Type`` -> the generated Python class."""
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def msg_file(type_name: str) -> Path:
    """Find ``share/<pkg>/msg/<Type>.msg`` in the ament prefixes (or the venv's prefix)."""
    package, kind, name = type_name.split("/")
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    prefixes.append(sys.prefix)
    for prefix in prefixes:
        candidate = Path(prefix) / "share" / package / kind / f"{name}.msg"
        if candidate.exists():
            return candidate
    raise FileNotFoundError(f"no .msg definition found for {type_name}")


def typestore_for(type_names: Sequence[str]) -> Typestore:
    """Jazzy's typestore plus any missing types, registered from their .msg text."""
    store = get_typestore(Stores.ROS2_JAZZY)
    missing = [t for t in type_names if t not in store.fielddefs]
    while missing:
        type_name = missing.pop()
        types = get_types_from_msg(msg_file(type_name).read_text(), type_name)
        store.register(types)
    return store


def _qos_time(duration: Any) -> QosTime:
    nanoseconds = int(duration.nanoseconds)
    return QosTime(nanoseconds // 1_000_000_000, nanoseconds % 1_000_000_000)


def offered_qos(profile: QoSProfile) -> Qos:
    """A publisher's QoS as rosbag2 stores it in the bag (``offered_qos_profiles``), so
    that ``ros2 bag play`` offers it again: a latched topic replays latched."""
    return Qos(
        history=QosHistory(int(profile.history)),
        depth=int(profile.depth),
        reliability=QosReliability(int(profile.reliability)),
        durability=QosDurability(int(profile.durability)),
        deadline=_qos_time(profile.deadline),
        lifespan=_qos_time(profile.lifespan),
        liveliness=QosLiveliness(int(profile.liveliness)),
        liveliness_lease_duration=_qos_time(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions),
    )


# How many recent samples of a topic are remembered to write each once: on a topic with
# a volatile and a transient-local subscription, a latched publisher's messages come on both.
RECENT_SAMPLES = 1000


@dataclass
class _Topic:
    """What the recorder holds for one topic it records."""

    type_name: str
    store: Typestore
    connection: Any  # the bag connection new messages go to
    offered: list[Qos]  # its offered QoS, fixed once the connection is written
    publishers_seen: set[bytes]
    subscriptions: dict[bool, Any] = field(default_factory=dict)  # latched? -> subscription
    recent: deque[tuple[int, int, int]] = field(default_factory=deque)
    recent_keys: set[tuple[int, int, int]] = field(default_factory=set)

    def first_time(self, data: bytes, info: dict[str, Any]) -> bool:
        """False for a sample already written (the same source time and bytes came on the
        topic's other subscription, or on the first before the second was made and got it
        again as a latched value). Without a source time: always True."""
        stamp = int(info.get("source_timestamp") or 0)
        if not stamp:
            return True
        key = (stamp, len(data), hash(bytes(data)))
        if key in self.recent_keys:
            return False
        self.recent.append(key)
        self.recent_keys.add(key)
        if len(self.recent) > RECENT_SAMPLES:
            self.recent_keys.discard(self.recent.popleft())
        return True


class Recorder(Node):
    """Subscribes to topics as their publishers appear and writes every message to one bag.

    A topic is taken up once it has a publisher (a subscriber alone, such as a monitor,
    says nothing of the QoS the messages come with), with a subscription each publisher
    can deliver to: volatile for volatile publishers, transient local for latched ones
    (their latched value too); a topic with both kinds gets both subscriptions, and a
    sample that comes on both is written once. The publishers' QoS go into the bag. A
    publisher that appears later is checked on every pass: it gets the subscription its
    durability needs, and a QoS the topic's bag connection does not list yet opens a new
    connection of the topic that lists every one (a connection's QoS is written with it
    in the bag file and cannot change; the first connection's stays what
    ``ros2 bag play`` offers).
    """

    def __init__(
        self, output: Path, topics: Sequence[str], storage: StoragePlugin, **node_kwargs: Any
    ) -> None:
        super().__init__("bridge_recorder", **node_kwargs)
        self.topics = list(topics)
        self.output = output
        self.storage = storage
        self.counts: dict[str, int] = {t: 0 for t in self.topics}
        self._writer: Writer | None = None
        self._recorded: dict[str, _Topic] = {}
        self._lock = threading.Lock()
        self.discover_passes = 0  # graph looks done (tests wait on it)
        self.create_timer(0.1, self._discover)

    def _discover(self) -> None:
        self.discover_passes += 1
        known = dict(self.get_topic_names_and_types())
        for topic in self.topics:
            if topic not in known:
                continue
            publishers = self.get_publishers_info_by_topic(topic)
            if not publishers:
                continue  # only subscribers known yet: their QoS is not the messages'
            if topic not in self._recorded:
                self._take_up(topic, known[topic][0], publishers)
            else:
                self._late_publishers(topic, publishers)

    def _add_connection(
        self, topic: str, type_name: str, store: Typestore, offered: list[Qos]
    ) -> Any:
        with self._lock:
            if self._writer is None:
                self._writer = DistroWriter(
                    self.output, version=9, storage_plugin=self.storage, distro=ros_distro()
                )
                self._writer.open()
            connection = self._writer.add_connection(
                topic, type_name, typestore=store, offered_qos_profiles=list(offered)
            )
        assert isinstance(connection.ext, ConnectionExtRosbag2)
        return connection

    def _take_up(self, topic: str, type_name: str, publishers: list[Any]) -> None:
        store = typestore_for([type_name])
        offered = [offered_qos(info.qos_profile) for info in publishers]
        connection = self._add_connection(topic, type_name, store, offered)
        recorded = _Topic(
            type_name,
            store,
            connection,
            offered,
            {bytes(info.endpoint_gid) for info in publishers},
        )
        with self._lock:
            self._recorded[topic] = recorded
        for latched in _durabilities(publishers):
            self._subscribe(topic, latched)
        self.get_logger().info(f"recording {topic} ({type_name})")

    def _late_publishers(self, topic: str, publishers: list[Any]) -> None:
        recorded = self._recorded[topic]
        new = [
            info for info in publishers if bytes(info.endpoint_gid) not in recorded.publishers_seen
        ]
        if not new:
            return
        recorded.publishers_seen.update(bytes(info.endpoint_gid) for info in new)
        for latched in _durabilities(new) - set(recorded.subscriptions):
            self._subscribe(topic, latched)
            kind = "a latched" if latched else "a volatile"
            self.get_logger().info(f"{topic}: {kind} publisher appeared, subscribed for it too")
        unlisted = []
        for info in new:
            qos = offered_qos(info.qos_profile)
            if qos not in recorded.offered and qos not in unlisted:
                unlisted.append(qos)
        if unlisted:
            offered = recorded.offered + unlisted
            connection = self._add_connection(topic, recorded.type_name, recorded.store, offered)
            with self._lock:
                recorded.connection, recorded.offered = connection, offered
            self.get_logger().info(
                f"{topic}: a publisher with a QoS not yet in the bag appeared: a new connection "
                "of the topic lists it"
            )

    def _subscribe(self, topic: str, latched: bool) -> None:
        recorded = self._recorded[topic]
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        if latched:
            qos.durability = DurabilityPolicy.TRANSIENT_LOCAL  # the latched value too
        # A callback of two arguments gets the message info too (rclpy's stubs know only
        # the one-argument form): its source time tells a sample that came on both.
        subscription = self.create_subscription(
            message_class(recorded.type_name),
            topic,
            self._writer_for(topic),  # type: ignore[arg-type]
            qos,
            raw=True,
        )
        with self._lock:
            recorded.subscriptions[latched] = subscription

    def _writer_for(self, topic: str) -> Callable[[bytes, dict[str, Any]], None]:
        return lambda data, info: self._write(topic, data, info)

    def _write(self, topic: str, data: bytes, info: dict[str, Any]) -> None:
        with self._lock:
            recorded = self._recorded[topic]
            if self._writer is None or not recorded.first_time(data, info):
                return
            self._writer.write(recorded.connection, time.time_ns(), data)
            self.counts[topic] += 1

    def close(self) -> None:
        with self._lock:
            if self._writer is not None:
                self._writer.close()
                self._writer = None


def _durabilities(publishers: Sequence[Any]) -> set[bool]:
    """The subscriptions ``publishers`` need (True: transient local, False: volatile): a
    transient-local subscription gets nothing from a volatile publisher."""
    return {info.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for info in publishers}


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="record ROS 2 topics to a rosbag2 bag (MCAP)")
    parser.add_argument(
        "-o", "--output", type=Path, required=True, help="bag directory (must not exist)"
    )
    parser.add_argument("topics", nargs="+", help="absolute topic names, e.g. /joint_states")
    parser.add_argument("--duration", type=float, default=0.0, help="seconds; 0 = until Ctrl-C")
    parser.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    args, ros_args = parser.parse_known_args(argv)
    if args.output.exists():
        parser.error(f"{args.output} exists; rosbag2 writes a new directory")
    refused = init_from_command_line(ros_args)
    if refused is not None:
        print(f"error: {refused}", file=sys.stderr)
        sys.exit(EXIT_CONFIGURATION_ERROR)
    storage = StoragePlugin.MCAP if args.storage == "mcap" else StoragePlugin.SQLITE3
    recorder = Recorder(args.output, args.topics, storage)
    executor = SingleThreadedExecutor()
    executor.add_node(recorder)
    deadline = time.monotonic() + args.duration if args.duration > 0 else None
    try:
        while rclpy_ok() and (deadline is None or time.monotonic() < deadline):
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        recorder.close()
        counts = ", ".join(f"{t}: {n}" for t, n in recorder.counts.items())
        print(f"bag {args.output}: {counts}", flush=True)
        executor.shutdown()
        recorder.destroy_node()
        try_shutdown()


if __name__ == "__main__":
    main()
