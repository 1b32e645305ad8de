"""bridge_core/ros/process.py: a command line rcl refuses is one line and exit code 2.

rclpy.init raises before any node exists, so ``spin_node`` runs here in the test's own
process (the exit-2 path of a whole bridge process is tests/test_contract.py's)."""

from __future__ import annotations

from pathlib import Path

import pytest
from rclpy.node import Node

from bridge_core.ros.process import EXIT_CONFIGURATION_ERROR, spin_node


def never_built() -> Node:
    raise AssertionError("a node was built for a command line rcl refused")


@pytest.mark.parametrize(
    ("args", "named"),
    [
        (["--ros-args", "--help"], "'--help'"),
        (["--ros-args", "-p", "host"], "'-p host'"),
        (["--ros-args", "-p", "host:=[1,"], "'-p host:=[1,'"),
        (["--ros-args", "-r", "bad"], "'-r bad'"),
        (["--ros-args", "--params-file", "{missing}"], "missing.yaml"),
        (["--ros-args", "--params-file", "{malformed}"], "malformed.yaml"),
    ],
    ids=["unknown", "parameter", "value", "remap", "missing-file", "malformed-yaml"],
)
def test_a_refused_command_line_is_one_line_and_exit_2(
    args: list[str], named: str, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    malformed = tmp_path / "malformed.yaml"
    malformed.write_text("r6_bridge:\n  ros__parameters: [host: 1\n")
    paths = {"missing": str(tmp_path / "missing.yaml"), "malformed": str(malformed)}
    code = spin_node(never_built, [arg.format(**paths) for arg in args])
    out, err = capfd.readouterr()
    lines = [line for line in (out + err).splitlines() if line.strip()]
    assert code == EXIT_CONFIGURATION_ERROR, lines
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    assert named in lines[0] and "Traceback" not in lines[0], lines
    assert ", at /" not in lines[0], lines  # rcl's source places are dropped
