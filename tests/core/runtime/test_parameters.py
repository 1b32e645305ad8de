"""Parameter specs: types, coercion of integers for doubles, ranges, choices."""

from __future__ import annotations

import pytest

from bridge_core.runtime.parameters import ParameterSpec, padded


def test_integer_for_a_double_is_taken_as_that_double() -> None:
    spec = ParameterSpec("poll_rate_hz", 20.0, "polls per second", 0.1, 1000.0, live=True)
    assert spec.kind is float
    coerced = spec.coerce(20)
    assert coerced == 20.0 and isinstance(coerced, float)
    assert spec.coerce(True) is True  # a bool is no number; ROS refuses its type
    assert ParameterSpec("ratios", [1.0], "x").coerce([1, 2]) == [1.0, 2.0]


def test_validate_range_choices_and_positive_items() -> None:
    rate = ParameterSpec("poll_rate_hz", 20.0, "polls", 0.1, 1000.0)
    assert rate.validate(5.0) is None
    assert rate.validate(0.0) == "poll_rate_hz 0.0 outside 0.1..1000"
    assert rate.validate(float("nan")) is not None
    parity = ParameterSpec("parity", "N", "parity", choices=("N", "E", "O"))
    assert parity.validate("e") is None
    assert parity.validate("X") == "parity 'X' is not one of N, E, O"
    ratios = ParameterSpec("gear_ratios", [1.0], "per axis", item_positive=True)
    assert ratios.validate([1.0, 2.5]) is None
    assert ratios.validate([1.0, 0.0]) is not None
    assert ratios.validate([float("inf")]) is not None


def test_bad_specs_are_refused_when_written() -> None:
    with pytest.raises(ValueError, match="both ends"):
        ParameterSpec("x", 1.0, "x", low=0.0)
    with pytest.raises(ValueError, match="outside"):
        ParameterSpec("x", 5.0, "x", 0.0, 1.0)  # a default outside its own range


def test_padded() -> None:
    assert padded([2, 3], 4, 1.0) == [2.0, 3.0, 1.0, 1.0]
    assert padded([1.0] * 9, 2, 1.0) == [1.0, 1.0]


def test_the_stepper_refuses_a_reply_timeout_its_replies_cannot_meet() -> None:
    """§3: replies come no sooner than 35 ms, the largest (103 bytes) takes 107 ms more at
    9600 baud and twice that at 4800: the floor scales with the baud rate."""
    from bridge_core.runtime.parameters import transport_specs
    from bridge_core.wire.errors import ConfigurationError
    from bridge_core.wire.transport import SerialSettings, TcpSettings
    from stepper_bridge.interface import STEPPER_DEFAULTS
    from stepper_bridge.node import check_reply_timeout
    from stepper_bridge.registers import reply_timeout_floor_s

    floors = {
        baud: reply_timeout_floor_s(SerialSettings("/dev/null", baud))
        for baud in (4800, 9600, 19200, 38400)
    }
    assert floors == pytest.approx({4800: 0.26, 9600: 0.15, 19200: 0.10, 38400: 0.07})
    assert reply_timeout_floor_s(SerialSettings("/dev/null", 9600, "E")) == pytest.approx(0.16)
    check_reply_timeout(SerialSettings("/dev/null", 9600, timeout_s=0.15))
    check_reply_timeout(SerialSettings("/dev/null", 38400, timeout_s=0.07))
    check_reply_timeout(TcpSettings("localhost", 502, 0.01))  # not a serial line
    for baud, floor in ((4800, "0.26"), (9600, "0.15")):
        with pytest.raises(ConfigurationError) as refused:
            check_reply_timeout(SerialSettings("/dev/null", baud, timeout_s=0.14))
        line = str(refused.value)
        assert f"below {floor} s" in line and f"at {baud} baud" in line and "\n" not in line
        assert "no sooner than 35 ms" in line
    specs = {spec.name: spec for spec in transport_specs(STEPPER_DEFAULTS)}
    assert specs["timeout_s"].validate(0.03) is not None  # below 35 ms at any baud rate
    assert specs["frame_gap_s"].validate(0.035) is None
    assert specs["frame_gap_s"].default == 0.0
