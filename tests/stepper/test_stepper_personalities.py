"""The stepper bridge against a controller that does not obey (issue 39): the simulator's
``--ignore`` personality (stepper_bridge/sim.py ``IGNORABLE``) acknowledges a motion write
as the manual says and changes nothing. A command that starts, stops or changes motion is a
success only when the controller's own state, read back, shows it; otherwise the reply says
what was written and what was read back, and a halt still sends its stop and logs "not
confirmed".

Device rows: the device layer over a real socat pty pair (no ROS), 115200 baud and no reply
delay.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import pytest

from bridge_core.sim.sim_base import Simulator
from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import NotConfirmed
from bridge_core.wire.registers import Table
from bridge_core.wire.transport import ModbusLink, SerialSettings
from stepper_bridge.device import StepperDevice
from stepper_bridge.registers import SYSTEM_COILS, coil, motor_coil
from stepper_bridge.sim import StepperSimDevice, make_simulator

from ..support.ros import wait_for
from ..support.serial_pair import PTY_REPLY_TIMEOUT_S, socat_pair

BAUD = 115200
TRAVEL = 1000.0  # far beyond every motion here: no limit switch ends one
WAIT_S = 20.0
C = Table.COIL


@dataclass
class Rig:
    sim: Simulator
    fake: StepperSimDevice
    device: StepperDevice

    def coils(self, since: int = 0) -> list[tuple[int, bool]]:
        """(coil address, ignored) of every coil written since write ``since``."""
        return [(r.address, r.ignored) for r in self.fake.write_log[since:] if r.table is C]


@pytest.fixture
def rig() -> Iterator[Rig]:
    sim = make_simulator(reply_delay_s=0.0, travel=TRAVEL)
    fake = sim.device
    assert isinstance(fake, StepperSimDevice)
    with socat_pair() as (bridge_end, device_end, _):
        sim.start_serial(device_end, BAUD)
        link = ModbusLink(SerialSettings(bridge_end, BAUD, timeout_s=PTY_REPLY_TIMEOUT_S))
        device = StepperDevice(DeviceChannel(link, 1, retries=0))
        device.read_config()
        try:
            yield Rig(sim, fake, device)
        finally:
            link.close()
            sim.stop()


def system_coil(name: str) -> int:
    return coil(SYSTEM_COILS[name])


def running_line(rig: Rig) -> None:
    """A slow line of pair 1 (motors 1+2) that runs for many seconds."""
    d = rig.device
    d.pair_reading = "type_rows"
    d.line_move(1, (1.0, 1.0), (200.0, 100.0), 60)
    wait_for(
        lambda: rig.fake.interpolation is not None and rig.fake.interpolation.phase == "path",
        WAIT_S,
        "the line on its path",
    )


# ---------------------------------------------------------------- hole 7: interpolation stop


def test_an_interpolation_stop_the_controller_ignores_still_stops_its_motors(rig: Rig) -> None:
    """Issue 39 hole 7: the interpolation stop sent only the arc and line stop coils. A
    controller that does not obey them (here: acknowledges and ignores them) kept the
    pair moving while the bridge said "stopped". The motors' own stop coils follow, and
    their running flags are read back."""
    running_line(rig)
    rig.sim.ignore({"line_stop", "arc_stop"})
    mark = len(rig.fake.write_log)
    said = rig.device.stop_interpolation()
    assert rig.fake.interpolation is None and not any(rig.fake.motion.values())
    assert rig.coils(mark) == [
        (system_coil("arc_stop"), True),
        (system_coil("line_stop"), True),
        (motor_coil(1, "stop"), False),
        (motor_coil(2, "stop"), False),
    ]
    assert "running" in said and "40168" in said, said


def test_an_interpolation_stop_nothing_obeys_is_not_confirmed(rig: Rig) -> None:
    running_line(rig)
    rig.sim.ignore({"line_stop", "arc_stop", "stop"})
    mark = len(rig.fake.write_log)
    with pytest.raises(NotConfirmed) as err:
        rig.device.stop_interpolation()
    text = str(err.value)
    assert "wrote" in text and "00101" in text and "00103" in text and "00005" in text, text
    assert "read" in text and "40168" in text and "\n" not in text, text
    assert rig.fake.interpolation is not None  # still running: the reply says so
    assert all(ignored for _, ignored in rig.coils(mark))
    # The bridge still counts the line as running: a second line is refused meanwhile.
    assert rig.device.interpolation_run is not None
