"""The msg_defs interface package: generated Python types, CDR round trip, and a real
publisher -> subscriber exchange of an R6State between two processes."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import threading
from collections.abc import Iterator
from typing import Any

import pytest
import rclpy
import rclpy.executors
from rclpy.context import Context
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message

import msg_defs.action
import msg_defs.srv
from bridge_core.runtime.goals import Outcome
from msg_defs.msg import MotionOutcome, R6State

pytestmark = pytest.mark.ros

TOPIC = "msg_defs_test/r6_state"

# Builds the R6State that both processes agree on; exec'd here and in the child process.
MAKE_STATE_SRC = textwrap.dedent(
    """
    from msg_defs.msg import R6State

    def make_state():
        m = R6State()
        m.header.stamp.sec = 1_700_000_000
        m.header.stamp.nanosec = 123_456_789
        m.header.frame_id = "r6"
        m.mode = R6State.MODE_CONFIGURATION
        m.mode_name = "configuration"
        m.alarm_code = 517
        m.moving = True
        m.homed = True
        m.global_speed_percent = 37.5
        m.current_cycle_time_ms = 2**40 + 12345  # needs all four registers
        m.last_cycle_time_ms = 2**63 + 1
        m.machine_id = 65535
        m.axis_count = 6
        m.io_board_count = 5
        m.io_board_inputs = [0, 1, 0xFFFF_FFFF, 0x8000_0001, 42]
        m.io_board_outputs = [5, 4, 3, 2, 1]
        return m
    """
)


def make_state() -> Any:
    namespace: dict[str, Any] = {}
    exec(MAKE_STATE_SRC, namespace)
    return namespace["make_state"]()


R6STATE_FIELDS = {
    "header": "std_msgs/Header",
    "slow_stamp": "builtin_interfaces/Time",
    "mode": "uint16",
    "mode_name": "string",
    "alarm_code": "uint16",
    "moving": "boolean",
    "homed": "boolean",
    "global_speed_percent": "double",
    "current_cycle_time_ms": "uint64",
    "last_cycle_time_ms": "uint64",
    "machine_id": "uint16",
    "axis_count": "uint16",
    "io_board_count": "uint16",
    "io_board_inputs": "sequence<uint32>",
    "io_board_outputs": "sequence<uint32>",
    "m_board_inputs": "sequence<uint32>",
    "m_board_outputs": "sequence<uint32>",
    "eu_board_inputs": "sequence<uint32>",
    "eu_board_outputs": "sequence<uint32>",
    "world_extra": "sequence<double>",
}

REPLY = {"success": "boolean", "message": "string"}
SERVICES: dict[str, tuple[dict[str, str], dict[str, str]]] = {
    "SetValue": ({"value": "double"}, REPLY),
    "SetOutput": ({"board": "uint16", "index": "uint16", "state": "boolean"}, REPLY),
    "SetCounter": ({"id": "uint32", "value": "uint32"}, REPLY),
    "ListCounters": ({}, {**REPLY, "ids": "sequence<uint32>"}),
    "ReadCounter": ({"id": "uint32"}, {**REPLY, "target": "uint32", "current": "uint32"}),
    "SetOutputBoard": ({"board": "uint16", "bits": "uint32", "mask": "uint32"}, REPLY),
    "ClearAlarmAndNext": ({"skip_failed_step": "boolean"}, REPLY),
    "SetSafetyMode": ({"data": "boolean", "confirm": "string"}, REPLY),
    "ReadDataSource": ({"source_id": "uint16"}, {**REPLY, "points": "uint32"}),
    "ReadParameter": ({"index": "uint32"}, {**REPLY, "value": "int64"}),
    "WriteParameter": ({"index": "uint32", "value": "int64"}, REPLY),
    "UploadPoints": (
        {
            "data_source_id": "uint16",
            "values_per_point": "uint16",
            "axis_mask": "uint16",
            "values": "sequence<int32>",
        },
        {**REPLY, "frames_sent": "uint32"},
    ),
    "SetInteger": ({"value": "int64"}, REPLY),
    "SetChannelValue": ({"channel": "uint16", "value": "double"}, REPLY),
    "RunOfflineTask": ({"projects": "sequence<uint16>"}, REPLY),
    "MoveBy": ({"distance": "double"}, REPLY),
    "ConfigureMotor": (
        {
            "step_angle_deg": "double",
            "microstep": "uint16",
            "start_frequency_hz": "uint16",
            "accel_frequency_hz": "uint16",
            "speed_rpm": "uint16",
            "lead": "double",
        },
        REPLY,
    ),
    "LineMove": (
        {"pair": "uint8", "start": "double[2]", "end": "double[2]", "speed_rpm": "uint16"},
        REPLY,
    ),
    "ArcMove": (
        {
            "pair": "uint8",
            "mode": "uint8",
            "start": "double[2]",
            "end": "double[2]",
            "center": "double[2]",
            "via": "double[2]",
            "counterclockwise": "boolean",
            "speed_rpm": "uint16",
        },
        REPLY,
    ),
    "ConfirmedCommand": ({"confirm": "string"}, REPLY),
    "SetOutputs": ({"indexes": "sequence<uint16>", "states": "sequence<boolean>"}, REPLY),
    "SetJointEnable": ({"joint": "uint8", "enable": "boolean"}, REPLY),
    "SetHomingOrder": ({"motors": "sequence<uint8>"}, REPLY),
    "SetLimitInputs": (
        {"positive_limit": "uint8", "negative_limit": "uint8", "home": "uint8"},
        REPLY,
    ),
    "SetControlMode": ({"mode": "uint8"}, REPLY),
    "PositionMove": (
        {"position": "double", "relative": "boolean", "max_velocity": "double"},
        {**REPLY, "counts": "int32"},
    ),
    "ReadRegisters": (
        {"names": "sequence<string>"},
        {
            **REPLY,
            "names": "sequence<string>",
            "values": "sequence<double>",
            "units": "sequence<string>",
            "texts": "sequence<string>",
        },
    ),
    "WriteRegister": ({"name": "string", "value": "double", "text": "string"}, REPLY),
}


OUTCOME = {"outcome": "msg_defs/MotionOutcome"}
STEPPER_FEEDBACK = {"positions": "sequence<double>", "running": "sequence<boolean>"}
STEPPER_RESULT = {**OUTCOME, "positions": "sequence<double>"}
PAIR_GOAL = {"pair": "uint8", "start": "double[2]", "end": "double[2]"}
# name: (goal, result, feedback) fields
ACTIONS: dict[str, tuple[dict[str, str], dict[str, str], dict[str, str]]] = {
    "MoveTo": (
        {
            "position": "double",
            "relative": "boolean",
            "max_velocity": "double",
            "timeout_s": "double",
        },
        {**OUTCOME, "position": "double", "target_counts": "int32"},
        {"position": "double", "velocity": "double", "distance_to_go": "double"},
    ),
    "StepperMoveBy": (
        {"distance": "double", "timeout_s": "double"},
        STEPPER_RESULT,
        {**STEPPER_FEEDBACK, "distance_to_go": "double"},
    ),
    "StepperRun": ({"timeout_s": "double"}, STEPPER_RESULT, STEPPER_FEEDBACK),
    "LineMotion": (
        {**PAIR_GOAL, "speed_rpm": "uint16", "timeout_s": "double"},
        STEPPER_RESULT,
        STEPPER_FEEDBACK,
    ),
    "ArcMotion": (
        {
            "pair": "uint8",
            "mode": "uint8",
            "start": "double[2]",
            "end": "double[2]",
            "center": "double[2]",
            "via": "double[2]",
            "counterclockwise": "boolean",
            "speed_rpm": "uint16",
            "timeout_s": "double",
        },
        STEPPER_RESULT,
        STEPPER_FEEDBACK,
    ),
    "PointUpload": (
        {
            "data_source_id": "uint16",
            "values_per_point": "uint16",
            "axis_mask": "uint16",
            "values": "sequence<int32>",
            "timeout_s": "double",
        },
        {**OUTCOME, "frames_sent": "uint32", "frames_total": "uint32", "points_held": "uint32"},
        {"frames_sent": "uint32", "frames_total": "uint32"},
    ),
    "RunCycle": (
        {"single_cycle": "boolean", "timeout_s": "double"},
        {**OUTCOME, "last_cycle_time_ms": "uint64"},
        {"moving": "boolean", "current_cycle_time_ms": "uint64", "alarm_code": "uint16"},
    ),
}


def test_every_action_is_defined_with_its_fields() -> None:
    found = {
        name
        for name in dir(msg_defs.action)
        if not name.startswith("_") and hasattr(getattr(msg_defs.action, name), "Goal")
    }
    assert found == set(ACTIONS)
    for name, (goal, result, feedback) in ACTIONS.items():
        action = getattr(msg_defs.action, name)
        assert action.Goal.get_fields_and_field_types() == goal, name
        assert action.Result.get_fields_and_field_types() == result, name
        assert action.Feedback.get_fields_and_field_types() == feedback, name


def test_motion_outcome_codes_are_the_goal_runtimes() -> None:
    """``bridge_core.runtime.goals.Outcome`` (plain Python) and the message agree code by code."""
    constants = {
        name: getattr(MotionOutcome, name)
        for name in dir(MotionOutcome)
        if name.isupper() and not name.startswith("_") and name != "SLOT_TYPES"
    }
    assert constants == {outcome.name: int(outcome) for outcome in Outcome}
    assert MotionOutcome.get_fields_and_field_types() == {
        "code": "uint8",
        "name": "string",
        "message": "string",
        "fault_code": "int64",
        "fault_text": "string",
        "stop_sent": "boolean",
    }


def test_r6state_constants_and_fields() -> None:
    assert R6State.MODE_MANUAL == 1
    assert R6State.MODE_AUTO == 2
    assert R6State.MODE_CONFIGURATION == 3
    assert R6State.get_fields_and_field_types() == R6STATE_FIELDS
    default = R6State()
    assert default.mode == 0
    assert default.mode_name == ""
    assert list(default.io_board_inputs) == []


def test_every_service_is_defined_with_its_fields() -> None:
    found = {
        name
        for name in dir(msg_defs.srv)
        if not name.startswith("_") and hasattr(getattr(msg_defs.srv, name), "Request")
    }
    assert found == set(SERVICES)
    for name, (request_fields, response_fields) in SERVICES.items():
        srv = getattr(msg_defs.srv, name)
        assert srv.Request.get_fields_and_field_types() == request_fields, name
        assert srv.Response.get_fields_and_field_types() == response_fields, name


def test_r6state_cdr_round_trip() -> None:
    sent = make_state()
    data = serialize_message(sent)
    assert isinstance(data, bytes)
    received = deserialize_message(data, R6State)
    assert received == sent
    assert received.current_cycle_time_ms == 2**40 + 12345
    assert received.last_cycle_time_ms == 2**63 + 1
    assert list(received.io_board_inputs) == [0, 1, 0xFFFF_FFFF, 0x8000_0001, 42]
    assert received != R6State()


def test_service_cdr_round_trip() -> None:
    request = msg_defs.srv.UploadPoints.Request(
        data_source_id=3, values_per_point=4, axis_mask=0b1011, values=[-(2**31), 0, 2**31 - 1, 7]
    )
    assert deserialize_message(serialize_message(request), msg_defs.srv.UploadPoints.Request) == (
        request
    )
    response = msg_defs.srv.ReadParameter.Response(success=True, message="ok", value=-(2**63))
    assert (
        deserialize_message(serialize_message(response), msg_defs.srv.ReadParameter.Response)
        == response
    )


CHILD_PUBLISHER = MAKE_STATE_SRC + textwrap.dedent(
    f"""
    import time
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    rclpy.init()
    node = rclpy.create_node("msg_defs_test_publisher")
    pub = node.create_publisher(
        R6State, {TOPIC!r}, QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    )
    msg = make_state()
    deadline = time.monotonic() + 60.0  # bounded even if the test process vanishes
    while time.monotonic() < deadline:
        pub.publish(msg)
        time.sleep(0.05)
    """
)


@pytest.fixture
def ros_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[dict[str, str]]:
    """A domain of its own (1..100) and localhost-only discovery, for both processes."""
    domain = str(os.getpid() % 100 + 1)
    monkeypatch.setenv("ROS_DOMAIN_ID", domain)
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    yield dict(os.environ)


def test_r6state_published_in_another_process_is_received(ros_env: dict[str, str]) -> None:
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD_PUBLISHER],
        env=ros_env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    context = Context()
    rclpy.init(context=context, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    received: list[Any] = []
    got_one = threading.Event()
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    try:
        node = rclpy.create_node("msg_defs_test_subscriber", context=context)

        def on_state(msg: Any) -> None:
            received.append(msg)
            got_one.set()

        node.create_subscription(
            R6State,
            TOPIC,
            on_state,
            QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE),
        )
        executor.add_node(node)
        spinner = threading.Thread(target=executor.spin, daemon=True)
        spinner.start()

        ok = got_one.wait(timeout=30.0)
        if not ok:
            child.kill()
            output, _ = child.communicate(timeout=10)
            pytest.fail(
                f"no R6State from the publisher process within 30 s "
                f"(child exit code {child.returncode}); its output:\n{output}"
            )
        assert received[0] == make_state()
        assert received[0].mode == R6State.MODE_CONFIGURATION
        assert received[0].mode_name == "configuration"
    finally:
        executor.shutdown()
        rclpy.shutdown(context=context)
        if child.poll() is None:
            child.terminate()
            try:
                child.communicate(timeout=10)
            except subprocess.TimeoutExpired:
                child.kill()
                child.communicate()


def test_device_values_fields_and_round_trip() -> None:
    from msg_defs.msg import DeviceValues

    fields = DeviceValues.get_fields_and_field_types()
    assert fields == {
        "header": "std_msgs/Header",
        "slow_stamp": "builtin_interfaces/Time",
        "names": "sequence<string>",
        "values": "sequence<double>",
        "units": "sequence<string>",
        "texts": "sequence<string>",
    }
    message = DeviceValues(names=["a", "b"], values=[1.5, float("inf")], units=["V", ""])
    message.texts = ["", "text"]
    assert deserialize_message(serialize_message(message), DeviceValues) == message
