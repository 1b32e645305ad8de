"""Simulators served at the device end of a socat pty pair, as the tests' fixtures use them."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

from motec_bridge.sim import MotecSimulator
from motec_bridge.sim import make_simulator as make_motec_simulator
from stepper_bridge.sim import StepperSimDevice
from stepper_bridge.sim import make_simulator as make_stepper_simulator

from .serial_pair import served_on_pty


@contextmanager
def stepper_on_pty(baud: int) -> Iterator[tuple[StepperSimDevice, str]]:
    """The stepper simulator (no reply delay); yields it and the bridge's end of the pair."""
    simulator = make_stepper_simulator(reply_delay_s=0.0)
    device = simulator.device
    assert isinstance(device, StepperSimDevice)
    with served_on_pty(simulator, baud) as bridge_end:
        yield device, bridge_end


@contextmanager
def motec_on_pty(units: Sequence[int], baud: int) -> Iterator[tuple[MotecSimulator, str]]:
    """MOTEC drives ``units`` on one simulated bus; yields it and the bridge's end."""
    simulator = make_motec_simulator(list(units))
    with served_on_pty(simulator, baud) as bridge_end:
        yield simulator, bridge_end
