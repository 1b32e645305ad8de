"""The MOTEC drives' entry in ``bridge_demo`` (bridge_core.ros.demo): three drives on one bus."""

from __future__ import annotations

from typing import Any

from bridge_core.ros.demo import DemoDevice

UNITS = (1, 2, 3)


def format_state(state: Any) -> str:
    """One line of a ``MotecState``."""
    fault = f"fault {state.fault_code} {state.fault_text}" if state.fault_code else "no fault"
    return (
        f"{state.control_mode_name} control  {'enabled' if state.enabled else 'disabled'}  "
        f"position {state.position_actual} counts  speed {state.speed_actual_rpm} rpm  {fault}"
    )


DEMO = DemoDevice(
    name="MOTEC",
    package="motec_bridge",
    sim_module="motec_bridge.sim_cli",
    sim_args=["--unit-ids", ",".join(str(u) for u in UNITS)],
    node_params={
        "baudrate": 115200,
        # A simulator in another process on a busy machine may answer late: the drives'
        # 0.1 s default (a real bus at 115200) would take that for a dead drive.
        "timeout_s": 1.0,
        "unit_ids": "[" + ",".join(str(u) for u in UNITS) + "]",
    },
    state_type="msg_defs/msg/MotecState",
    format_state=format_state,
    start_services=[
        (f"motec_{u}/{service}", type_name, fields)
        for u in UNITS
        for service, type_name, fields in (
            ("set_control_mode", "msg_defs/srv/SetControlMode", {"mode": 2}),
            ("enable", "std_srvs/srv/SetBool", {"data": True}),
            (
                "move",
                "msg_defs/srv/PositionMove",
                {"position": 100.0 * u, "relative": True, "max_velocity": 5.0},
            ),
        )
    ],
    serial=True,
    state_nodes=[f"motec_{u}" for u in UNITS],
    order=40,
)
