"""The stepper controller's entry in ``bridge_demo`` (bridge_core.ros.demo)."""

from __future__ import annotations

from typing import Any

from bridge_core.ros.demo import DemoDevice


def format_state(state: Any) -> str:
    """One line of a ``StepperState``."""
    running = "".join("R" if r else "." for r in state.running)
    outputs = "".join("1" if o else "0" for o in state.outputs)
    coordinates = " ".join(f"{c:8.2f}" for c in state.coordinates)
    return f"running {running}  coordinates {coordinates}  outputs {outputs}"


DEMO = DemoDevice(
    name="Stepper",
    package="stepper_bridge",
    state_type="msg_defs/msg/StepperState",
    format_state=format_state,
    # The manual's line: 9600 baud 8N1, replies after 35 ms (the simulator's default).
    node_params={"baudrate": 9600, "timeout_s": 1.0},
    start_services=[
        ("motor_1/forward", "std_srvs/srv/Trigger", {}),
        ("motor_3/reverse", "std_srvs/srv/Trigger", {}),
        ("set_output", "msg_defs/srv/SetOutput", {"board": 0, "index": 2, "state": True}),
    ],
    serial=True,
    order=30,
)
