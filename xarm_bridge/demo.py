"""The xArm's entry in ``bridge_demo`` (bridge_core.ros.demo): simulator, node and state line."""

from __future__ import annotations

from typing import Any

from bridge_core.ros.demo import DemoDevice


def format_state(state: Any) -> str:
    """One line of an ``XArmState``."""
    error = f"error {state.error_code} {state.error_text}" if state.error_code else "no error"
    outputs = "".join("1" if b else "0" for b in state.digital_outputs)
    user = "".join("1" if b else "0" for b in state.user_coils)
    return (
        f"state {state.state_name}  mode {state.mode}  {error}  "
        f"tcp speed {state.tcp_speed:.3f} m/s  DO {outputs}  C{state.user_coil_first}+ {user}"
    )


DEMO = DemoDevice(
    name="xArm",
    package="xarm_bridge",
    state_type="msg_defs/msg/XArmState",
    format_state=format_state,
    node_params={"poll_rate_hz": 50.0, "user_coil_count": 8},
    start_services=[
        ("set_digital_output", "msg_defs/srv/SetOutput", {"board": 0, "index": 2, "state": True}),
        ("run_offline_task", "msg_defs/srv/RunOfflineTask", {"projects": [1, 2, 3, 4, 5, 6]}),
    ],
    order=20,
)
