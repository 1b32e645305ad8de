"""``bridge_plot``: a picture of a recorded bag (joint positions, velocities, link state).

Reads a rosbag2 bag (MCAP or sqlite3, e.g. from ``bridge_record``) with ``rosbags`` and
draws, against time from the first message: each joint's position and velocity from every
``sensor_msgs/JointState`` topic (by header stamp, i.e. when the registers were read), and
below them one band per bridge: ``~/connected`` (green up, red down) and the diagnostics
level of its status (green OK, orange WARN, red ERROR, grey STALE). Written with
matplotlib's Agg backend (no display needed). Plain Python, no rclpy.

    bridge_plot BAG -o FILE.png
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rosbags.rosbag2 import Reader

from .recorder import typestore_for

JOINT_STATE = "sensor_msgs/msg/JointState"
BOOL = "std_msgs/msg/Bool"
DIAGNOSTICS = "diagnostic_msgs/msg/DiagnosticArray"
LEVEL_COLOURS = {0: "tab:green", 1: "tab:orange", 2: "tab:red", 3: "tab:grey"}
LINK_COLOURS = {True: "tab:green", False: "tab:red"}


@dataclass
class Recording:
    """What a bag holds that the picture shows; times in seconds since the epoch."""

    positions: dict[str, list[tuple[float, float]]] = field(
        default_factory=lambda: defaultdict(list)
    )
    velocities: dict[str, list[tuple[float, float]]] = field(
        default_factory=lambda: defaultdict(list)
    )
    connected: dict[str, list[tuple[float, bool]]] = field(
        default_factory=lambda: defaultdict(list)
    )
    levels: dict[str, list[tuple[float, int]]] = field(default_factory=lambda: defaultdict(list))

    @property
    def start(self) -> float:
        times = [t for series in self._all() for t, _ in series]
        return min(times) if times else 0.0

    def _all(self) -> list[list[Any]]:
        return [
            *self.positions.values(),
            *self.velocities.values(),
            *self.connected.values(),
            *self.levels.values(),
        ]


def _stamp(header: Any) -> float:
    return float(header.stamp.sec) + float(header.stamp.nanosec) * 1e-9


def read_bag(bag: Path) -> Recording:
    """Joint samples, link state and diagnostics levels of every bridge in ``bag``."""
    recording = Recording()
    with Reader(bag) as reader:
        store = typestore_for(sorted({c.msgtype for c in reader.connections}))
        for connection, timestamp, raw in reader.messages():
            msgtype, received = connection.msgtype, timestamp * 1e-9
            if msgtype not in (JOINT_STATE, BOOL, DIAGNOSTICS):
                continue
            msg: Any = store.deserialize_cdr(raw, msgtype)
            if msgtype == JOINT_STATE:
                when = _stamp(msg.header)
                for index, name in enumerate(msg.name):
                    if index < len(msg.position):
                        recording.positions[name].append((when, float(msg.position[index])))
                    if index < len(msg.velocity):
                        recording.velocities[name].append((when, float(msg.velocity[index])))
            elif msgtype == BOOL and connection.topic.endswith("/connected"):
                node = connection.topic.rsplit("/", 1)[0]
                recording.connected[node].append((received, bool(msg.data)))
            elif msgtype == DIAGNOSTICS:
                for status in msg.status:
                    node = str(status.name).split(": ", 1)[0]
                    recording.levels[node].append((_stamp(msg.header), int(status.level)))
    return recording


def _bands(
    axis: Any,
    rows: list[tuple[str, list[tuple[float, Any]], dict[Any, str]]],
    start: float,
    end: float,
) -> None:
    """One horizontal band per row: each value coloured from its time to the next's."""
    for row, (_label, series, colours) in enumerate(rows):
        ordered = sorted(series)
        for (when, value), (until, _) in zip(ordered, [*ordered[1:], (end, None)], strict=True):
            axis.broken_barh(
                [(when - start, max(until - when, 1e-3))],
                (row - 0.4, 0.8),
                facecolors=colours.get(value, "tab:grey"),
            )
    axis.set_yticks(range(len(rows)), [label for label, _, _ in rows])
    axis.set_ylim(-0.6, len(rows) - 0.4)


def plot(recording: Recording, output: Path, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    start = recording.start
    end = max((t for series in recording._all() for t, _ in series), default=start + 1.0)
    rows: list[tuple[str, list[tuple[float, Any]], dict[Any, str]]] = [
        (f"{node} connected", series, LINK_COLOURS)
        for node, series in sorted(recording.connected.items())
    ]
    rows += [
        (f"{node} diagnostics", series, LEVEL_COLOURS)
        for node, series in sorted(recording.levels.items())
    ]
    figure, (positions, velocities, bands) = plt.subplots(
        3,
        1,
        sharex=True,
        figsize=(11, 8),
        gridspec_kw={"height_ratios": [3, 3, max(1, len(rows))]},
    )
    for axis, data, unit in (
        (positions, recording.positions, "position (rad or m)"),
        (velocities, recording.velocities, "velocity (rad/s or m/s)"),
    ):
        for name, samples in sorted(data.items()):
            ordered = sorted(samples)
            axis.plot([t - start for t, _ in ordered], [v for _, v in ordered], label=name)
        axis.set_ylabel(unit)
        axis.grid(True, alpha=0.3)
        if data:
            axis.legend(loc="upper right", fontsize="small", ncol=4)
    _bands(bands, rows, start, end)
    bands.set_xlabel("time (s)")
    figure.suptitle(title)
    figure.tight_layout()
    figure.savefig(output, dpi=100)
    plt.close(figure)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="plot a bridge bag: joints and link state")
    parser.add_argument("bag", type=Path, help="rosbag2 bag directory")
    parser.add_argument("-o", "--output", type=Path, required=True, help="picture (.png)")
    args = parser.parse_args(argv)
    if not args.bag.is_dir():
        parser.error(f"{args.bag} is not a bag directory")
    recording = read_bag(args.bag)
    plot(recording, args.output, str(args.bag))
    joints = ", ".join(f"{name} ({len(s)})" for name, s in sorted(recording.positions.items()))
    print(
        f"{args.output}: joints {joints or 'none'}; link bands "
        f"{len(recording.connected)}, diagnostics bands {len(recording.levels)}",
        flush=True,
    )


if __name__ == "__main__":
    main()
