"""The demo of the README's quick start runs and shows live state (docs/ros2-cli.md, "The
demo"); the example YAML configures the node."""

from __future__ import annotations

import contextlib
import math
import subprocess
import sys
import time
from pathlib import Path

import pytest
from sensor_msgs.msg import JointState

from r6_bridge.sim import make_simulator

from .support.ros import ROOT, node_process, ros_client, unique_namespace

pytestmark = pytest.mark.ros


def test_demo_shows_moving_r6(tmp_path: Path) -> None:
    import os

    env = dict(os.environ)
    result = subprocess.run(
        [sys.executable, "-m", "bridge_core.ros.demo", "--duration", "6"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
        env=env,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    out = result.stdout
    assert "start: done" in out
    blocks = [line for line in out.splitlines() if line.startswith("   joints (deg): joint_1")]
    assert len(blocks) >= 2, out
    first = float(blocks[0].split()[3])
    last = float(blocks[-1].split()[3])
    assert abs(last - first) > 1.0, out  # the axes move after ~start
    assert "[R6] connected  diagnostics OK" in out
    assert "[xArm] connected  diagnostics OK" in out
    assert "run_offline_task [1, 2, 3, 4, 5, 6]: done" in out
    xarm = [line for line in out.splitlines() if line.startswith("   joints (deg): joint1")]
    assert len(xarm) >= 2 and xarm[0] != xarm[-1], out  # the xArm moves too
    assert "[Stepper] connected  diagnostics OK" in out
    stepper = [line for line in out.splitlines() if line.startswith("   joints (deg): motor_1")]
    assert len(stepper) >= 2 and stepper[0] != stepper[-1], out  # motor 1 runs forward
    for unit in (1, 2, 3):
        assert f"[MOTEC motec_{unit}] connected  diagnostics OK" in out
        assert f"/motec/motec_{unit}/move: move by {100.0 * unit} rad: done" in out
    motec = [line for line in out.splitlines() if line.startswith("   joints (deg): drive_1")]
    assert len(motec) >= 2 and motec[0] != motec[-1], out  # the drives move
    assert "bridge_demo: stopped" in out


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


def test_demo_ends_cleanly_on_ctrl_c(tmp_path: Path) -> None:
    """Ctrl-C while the demo runs: exit 0, no traceback, the last line says it stopped."""
    import os
    import signal

    from .support.ros import wait_for

    out_path = tmp_path / "demo.out"
    with out_path.open("wb") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "bridge_core.ros.demo", "--devices", "R6"],
            cwd=ROOT,
            stdout=out,
            stderr=subprocess.STDOUT,
            env=dict(os.environ),
            start_new_session=True,  # its own group: a failed test kills its children too
        )
        try:
            wait_for(lambda: "--- t =" in out_path.read_text(), 120, "the demo's first report")
            proc.send_signal(signal.SIGINT)
            code = proc.wait(60)
        finally:
            with contextlib.suppress(ProcessLookupError):  # the simulators and nodes it left
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(10)
    text = out_path.read_text()
    assert code == 0, text
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
