"""The R6's entry in ``bridge_demo`` (bridge_core.ros.demo): simulator, node and state line."""

from __future__ import annotations

from typing import Any

from bridge_core.ros.demo import DemoDevice


def format_state(state: Any) -> str:
    """One line of an ``R6State``."""
    return (
        f"mode {state.mode_name}  alarm {state.alarm_code}  "
        f"moving {'yes' if state.moving else 'no'}  "
        f"speed {state.global_speed_percent:.1f}%  cycle {state.current_cycle_time_ms} ms"
    )


DEMO = DemoDevice(
    name="R6",
    package="r6_bridge",
    state_type="msg_defs/msg/R6State",
    format_state=format_state,
    node_params={"poll_rate_hz": 50.0},
    start_services=[
        ("set_global_speed", "msg_defs/srv/SetValue", {"value": 80.0}),
        ("start", "std_srvs/srv/Trigger", {}),
    ],
    order=10,
)
