"""The demo of the README's quick start ends after its ``--duration`` and its monitor leaves
Ctrl-C to Python (its console and its Ctrl-C against the demo tests/docs/test_readme_cli.py
starts); the example YAML configures the node."""

from __future__ import annotations

import math
import subprocess
import sys
import time
from pathlib import Path

import pytest
from sensor_msgs.msg import JointState

from r6_bridge.sim import make_simulator

from ...support.ros import ROOT, node_process, ros_client, unique_namespace

pytestmark = pytest.mark.ros


def test_example_yaml_configures_the_node(tmp_path: Path) -> None:
    simulator = make_simulator()
    port = simulator.start_tcp()
    config = (ROOT / "config" / "r6.yaml").read_text()
    config = config.replace("port: 502", f"port: {port}").replace(
        'joint_prefix: ""', 'joint_prefix: "left_"'
    )
    params = tmp_path / "r6.yaml"
    params.write_text(config)
    try:
        with ros_client() as client:
            ns = unique_namespace("yaml")
            client.subscribe(JointState, f"{ns}/joint_states")
            with node_process(
                "r6_bridge.node", {}, tmp_path, ["--params-file", str(params), "-r", f"__ns:={ns}"]
            ):
                msg = client.wait_message(f"{ns}/joint_states")
                assert msg.name[0] == "left_joint_1"
                assert all(math.isfinite(p) for p in msg.position)
                assert time.time() - msg.header.stamp.sec < 10
    finally:
        simulator.stop()


def test_demo_ends_after_its_duration() -> None:
    """``--duration``: the demo stops itself (exit 0, no traceback, the last line says it
    stopped). Its console while it runs, and its Ctrl-C, are tests/docs/test_readme_cli.py's
    (one demo for both)."""
    result = subprocess.run(
        [sys.executable, "-m", "bridge_core.ros.demo", "--devices", "R6", "--duration", "3"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        stdin=subprocess.DEVNULL,
        process_group=0,  # in the tests' session, as test_readme_cli's demo
    )
    text = result.stdout + result.stderr
    assert result.returncode == 0, text
    assert "[R6] connected  diagnostics OK" in text, text
    assert "Traceback" not in text and "Exception" not in text, text
    assert text.strip().splitlines()[-1] == "bridge_demo: stopped", text


def test_demo_monitor_leaves_ctrl_c_to_python() -> None:
    """rclpy's own SIGINT handler would shut the monitor's context down under a spin (an
    ExternalShutdownException traceback, exit 1, when it runs before Python's); the demo's
    monitor installs none, so Ctrl-C is always the KeyboardInterrupt main() ends on."""
    import signal

    from rclpy.signals import SignalHandlerOptions, get_current_signal_handlers_options

    from bridge_core.ros.demo import Monitor

    monitor = Monitor([])
    try:
        assert get_current_signal_handlers_options() == SignalHandlerOptions.NO
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    finally:
        monitor.close()


def test_a_ctrl_c_ends_the_monitor_between_two_spins() -> None:
    """main()'s SIGINT handler only flags the Ctrl-C; the monitor raises KeyboardInterrupt
    at its next spin, in Python code: never inside an rclpy call, where pybind11 would turn
    it into a RuntimeError traceback."""
    from bridge_core.ros.demo import INTERRUPTED, Monitor

    monitor = Monitor([])
    try:
        monitor.spin_for(0.05)  # not interrupted: spins and returns
        INTERRUPTED.set()
        with pytest.raises(KeyboardInterrupt):  # at once, not after the hour
            monitor.spin_for(3600.0)
    finally:
        INTERRUPTED.clear()
        monitor.close()
