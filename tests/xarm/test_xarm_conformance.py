"""Every example frame of the xArm Modbus TCP manual, byte-exact, over a real socket.

Requests are produced by the bridge's device layer (or, for FC 0x17 whose example has no
bridge command of its own, by the link's read_write_registers) through the real pymodbus
client; replies are the manual's and must decode to what it says.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from bridge_core.wire.channel import DeviceChannel
from bridge_core.wire.errors import DeviceException
from bridge_core.wire.transport import ModbusLink, TcpSettings
from xarm_bridge.device import XArmDevice

from ..support.replay import ReplayServer, Step, pdu_of


def run(
    steps: list[tuple[str, str, str]], action: Callable[[XArmDevice, DeviceChannel], Any]
) -> Any:
    server = ReplayServer([Step(pdu_of(req), pdu_of(rep), meaning) for req, rep, meaning in steps])
    link = ModbusLink(TcpSettings("127.0.0.1", server.port, timeout_s=2.0))
    channel = DeviceChannel(link, 1, retries=0)
    try:
        result = action(XArmDevice(channel), channel)
    finally:
        link.close()
        server.close()
    assert server.mismatches == []
    assert len(server.received) == len(steps)
    return result


def test_fc01_read_coils() -> None:
    names = [f"controller_do_{i}" for i in range(16)]
    values = run(
        [("00 01 00 00 00 06 01 01 00 00 00 10", "00 01 00 00 00 05 01 01 02 F7 00", "16 coils")],
        lambda d, _: d.read_named(*names),
    )
    # 0xF7 = 1111 0111: coil 3 off, coils 0-2 and 4-7 on; 0x00: coils 8-15 off.
    assert [values[n] for n in names] == [True] * 3 + [False] + [True] * 4 + [False] * 8


def test_fc05_write_coil() -> None:
    run(
        [("00 01 00 00 00 06 01 05 00 02 FF 00", "00 01 00 00 00 06 01 05 00 02 FF 00", "DO 2 on")],
        lambda d, _: d.set_digital_output(2, True),
    )


def test_fc0f_write_coils() -> None:
    run(
        [
            (
                "00 01 00 00 00 08 01 0F 00 02 00 03 01 07",
                "00 01 00 00 00 06 01 0F 00 02 00 03",
                "DO 2-4 on",
            )
        ],
        lambda d, _: d.write_digital_outputs(2, [True, True, True]),
    )


def test_fc02_read_discrete_inputs() -> None:
    names = [f"controller_di_{i}" for i in range(16)]
    values = run(
        [("00 01 00 00 00 06 01 02 00 00 00 10", "00 01 00 00 00 05 01 02 02 FF 00", "16 inputs")],
        lambda d, _: d.read_named(*names),
    )
    assert [values[n] for n in names] == [True] * 8 + [False] * 8


def test_fc03_read_holding_registers() -> None:
    values = run(
        [
            (
                "00 01 00 00 00 06 01 03 00 03 00 02",
                "00 01 00 00 00 07 01 03 04 00 05 00 06",
                "AO 0-1",
            )
        ],
        lambda d, _: d.read_named("controller_ao_0", "controller_ao_1"),
    )
    assert values == {
        "controller_ao_0": pytest.approx(0.005),
        "controller_ao_1": pytest.approx(0.006),
    }


def test_fc06_write_register() -> None:
    # H32 = 6: the arm mode register (mode 6).
    run(
        [("00 01 00 00 00 06 01 06 00 20 00 06", "00 01 00 00 00 06 01 06 00 20 00 06", "mode 6")],
        lambda d, _: d.set_mode(6),
    )


def test_fc10_write_registers() -> None:
    # 1234 and 3456 at H3-4: controller AO 0-1 = 1.234 V and 3.456 V (x1000).
    run(
        [
            (
                "00 01 00 00 00 0B 01 10 00 03 00 02 04 04 D2 0D 80",
                "00 01 00 00 00 06 01 10 00 03 00 02",
                "AO 0-1",
            )
        ],
        lambda d, _: d.set_analog_outputs([1.234, 3.456]),
    )


def test_fc16_mask_write_register() -> None:
    # and 0x000F, or 0x0F00 on H0: DO 0-3 kept, DO 8-11 on, DO 4-7 and 12-15 off.
    changes = {
        **{i: False for i in range(4, 8)},
        **{i: True for i in range(8, 12)},
        **{i: False for i in range(12, 16)},
    }
    run(
        [
            (
                "00 04 00 00 00 08 01 16 00 00 00 0F 0F 00",
                "00 04 00 00 00 08 01 16 00 00 00 0F 0F 00",
                "mask write H0",
            )
        ],
        lambda d, _: d.change_digital_outputs(changes),
    )


def test_fc17_read_write_registers() -> None:
    values = run(
        [
            (
                "00 01 00 00 00 0F 01 17 00 03 00 02 00 20 00 02 04 00 06 00 04",
                "00 01 00 00 00 07 01 17 04 04 D1 0D 7F",
                "write H32-33, read H3-4",
            )
        ],
        lambda _, channel: channel.read_write_registers(0x03, 2, 0x20, [6, 4]),
    )
    assert values == [0x04D1, 0x0D7F]


def test_fc17_as_set_state_reads_mode_and_state_back() -> None:
    result = run(
        [
            (
                "00 01 00 00 00 0D 01 17 00 20 00 02 00 21 00 01 02 00 03",
                "00 01 00 00 00 07 01 17 04 00 00 00 03",
                "set_state 3 (pause, decision 19): H33 = 3, read H32-33",
            )
        ],
        lambda d, _: d.set_state(3),
    )
    assert result == (0, 3)


def test_stop_writes_c145_and_h33_at_once_and_reads_the_state_back() -> None:  # decision 19
    said = run(
        [
            ("00 01 00 00 00 06 01 05 00 91 FF 00", "00 01 00 00 00 06 01 05 00 91 FF 00", "C145"),
            (
                "00 01 00 00 00 0D 01 17 00 20 00 02 00 21 00 01 02 00 04",
                "00 01 00 00 00 07 01 17 04 00 00 00 04",
                "H33 = 4 at once, H32-33 read",
            ),
            ("00 01 00 00 00 06 01 03 00 20 00 02", "00 01 00 00 00 07 01 03 04 00 00 00 04", "H"),
            ("00 01 00 00 00 06 01 04 00 20 00 01", "00 01 00 00 00 05 01 04 02 00 00", "I32"),
            ("00 01 00 00 00 06 01 01 00 90 00 02", "00 01 00 00 00 04 01 01 01 02", "C144-145"),
        ],
        lambda d, _: d.stop(),
    )
    assert said == (
        "wrote C145 = 1 and H33 = 4; reads mode 0 (position), state 4 (stopped), error 0, "
        "C144 paused 0, C145 stopped 1"
    )


def test_fc04_read_input_registers() -> None:
    values = run(
        [
            (
                "00 01 00 00 00 06 01 04 00 03 00 02",
                "00 01 00 00 00 07 01 04 04 00 0E 00 13",
                "AI 0-1",
            )
        ],
        lambda d, _: d.read_named("controller_ai_0", "controller_ai_1"),
    )
    assert values == {
        "controller_ai_0": pytest.approx(0.014),
        "controller_ai_1": pytest.approx(0.019),
    }


EXCEPTION_CASES = [
    ("00 01 00 00 00 06 01 01 00 00 00 10", 0x01, lambda d, c: d.read_named("controller_do_0")),
    ("00 01 00 00 00 06 01 05 00 02 FF 00", 0x05, lambda d, c: d.set_digital_output(2, True)),
    (
        "00 01 00 00 00 08 01 0F 00 02 00 03 01 07",
        0x0F,
        lambda d, c: d.write_digital_outputs(2, [True] * 3),
    ),
    (
        "00 01 00 00 00 06 01 02 00 00 00 10",
        0x02,
        lambda d, c: d.read_named(*[f"controller_di_{i}" for i in range(16)]),
    ),
    (
        "00 01 00 00 00 06 01 03 00 03 00 02",
        0x03,
        lambda d, c: d.read_named("controller_ao_0", "controller_ao_1"),
    ),
    ("00 01 00 00 00 06 01 06 00 20 00 06", 0x06, lambda d, c: d.set_mode(6)),
    (
        "00 01 00 00 00 0B 01 10 00 03 00 02 04 04 D2 0D 80",
        0x10,
        lambda d, c: d.set_analog_outputs([1.234, 3.456]),
    ),
    (
        "00 04 00 00 00 08 01 16 00 00 00 0F 0F 00",
        0x16,
        lambda d, c: d.change_digital_outputs(
            {**{i: False for i in (4, 5, 6, 7, 12, 13, 14, 15)}, **{i: True for i in range(8, 12)}}
        ),
    ),
    (
        "00 01 00 00 00 0F 01 17 00 03 00 02 00 20 00 02 04 00 06 00 04",
        0x17,
        lambda d, c: c.read_write_registers(0x03, 2, 0x20, [6, 4]),
    ),
    (
        "00 01 00 00 00 06 01 04 00 03 00 02",
        0x04,
        lambda d, c: d.read_named("controller_ai_0", "controller_ai_1"),
    ),
]


@pytest.mark.parametrize("code", [0x01, 0x02, 0x03])
@pytest.mark.parametrize(("request_frame", "function", "action"), EXCEPTION_CASES)
def test_exception_responses(request_frame: str, function: int, action: Any, code: int) -> None:
    # "00 01 00 00 00 03 01 8X XX": the exception reply of every function code.
    reply = f"00 01 00 00 00 03 01 {function | 0x80:02X} {code:02X}"
    names = {1: "ILLEGAL FUNCTION", 2: "ILLEGAL DATA ADDRESS", 3: "ILLEGAL DATA VALUE"}
    with pytest.raises(DeviceException, match=names[code]) as info:
        run([(request_frame, reply, f"exception to {function:#x}")], action)
    assert (info.value.function_code, info.value.exception_code) == (function, code)
