"""How the simulators decode requests like the device: function codes it lacks are
ILLEGAL FUNCTION with the code echoed, FC 05 takes only FF00 / 0000.

Why: pymodbus 3.16 answers FC 07, 08, 11 and 2B itself, a TCP server answers a code it
cannot decode with function byte 0x80 (which a client takes for a timeout), and an RTU
server cannot frame a code it does not know (it skips it byte by byte and the next
request is lost with it).
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable
from typing import Any

from pymodbus.constants import ExcCodes
from pymodbus.pdu import ExceptionResponse, ModbusPDU
from pymodbus.pdu.bit_message import WriteSingleCoilRequest
from pymodbus.pdu.decoders import DecodePDU

from .rtu_framing import crc_frame_size

# FC 05's only values (Modbus application protocol §6.5; stepper manual §5(2) "其它所有值
# 均为非法的,并且对线圈不起作用"): anything else is ILLEGAL DATA VALUE and writes nothing.
COIL_ON, COIL_OFF = 0xFF00, 0x0000
# Function codes 1-127 are requests; 128 and up are exception replies.
LAST_FUNCTION_CODE = 0x7F


def _refusing(base: type[ModbusPDU], function_code: int, frame_size: int) -> type[ModbusPDU]:
    """A request class for a function code the device does not have: framed like
    ``base`` (an RTU server needs its frame size), answered ``FC|0x80, 0x01``.

    Without it pymodbus answers 07/08/11/2B itself, and a TCP server answers a code it
    cannot decode with function byte 0x80 (no code), which a client takes for a timeout.
    """

    def decode(self: ModbusPDU, data: bytes) -> None:
        """Not parsed: the request is refused whatever it holds."""

    async def datastore_update(self: ModbusPDU, context: Any, device_id: int) -> ModbusPDU:
        code = await context.refuse(device_id, function_code, ExcCodes.ILLEGAL_FUNCTION)
        return ExceptionResponse(function_code, code)

    return type(
        f"Refused{function_code:02X}",
        (base,),
        {
            "function_code": function_code,
            "rtu_frame_size": frame_size,
            "sub_function_code": -1,  # no sub-function table lookup (FC 08, 2B)
            "decode_sub_function_code": classmethod(lambda cls, data: -1),
            "decode": decode,
            "datastore_update": datastore_update,
        },
    )


class _StrictWriteSingleCoil(WriteSingleCoilRequest):
    """FC 05 with a value other than FF00 / 0000: ILLEGAL DATA VALUE, nothing written
    (pymodbus itself takes any non-zero value for ON)."""

    value = COIL_OFF

    def decode(self, data: bytes) -> None:
        super().decode(data)
        self.value = struct.unpack(">H", data[2:4])[0]

    async def datastore_update(self, context: Any, device_id: int) -> ModbusPDU:
        if self.value not in (COIL_ON, COIL_OFF):
            code = await context.refuse(device_id, self.function_code, ExcCodes.ILLEGAL_VALUE)
            return ExceptionResponse(self.function_code, code)
        return await super().datastore_update(context, device_id)


def strict_decoder(
    decoder: DecodePDU,
    allowed: Iterable[int],
    *,
    tcp: bool,
    units: Callable[[], Iterable[int]] = tuple,
) -> None:
    """Make a pymodbus server's decoder answer like the device: every function code
    outside ``allowed`` is ILLEGAL FUNCTION with the code echoed (TCP: any code 1-127;
    RTU: the codes pymodbus can frame, and, to a unit in ``units()``, any other code
    1-127 framed by its CRC: pymodbus alone skips such a frame byte by byte and the
    next request is lost with it), and FC 05 takes only FF00 / 0000."""
    allowed = set(allowed)
    table = dict(decoder.pdu_table)
    codes = range(1, LAST_FUNCTION_CODE + 1) if tcp else sorted(table)
    for code in codes:
        if code in allowed:
            continue
        request, response = table.get(code, (ModbusPDU, ModbusPDU))
        # FC 2B's size is known only to its sub-function classes (all one size).
        sizes = {sub.rtu_frame_size for sub, _ in decoder.pdu_sub_table.get(code, {}).values()}
        frame_size = request.rtu_frame_size or (sizes.pop() if len(sizes) == 1 else 0)
        table[code] = (_refusing(request, code, frame_size), response)
    if 5 in allowed:
        table[5] = (_StrictWriteSingleCoil, table[5][1])
    decoder.pdu_table = table
    if tcp:
        return
    unframed = {
        code: type(
            f"Unframed{code:02X}",
            (_refusing(ModbusPDU, code, 0),),
            {"calculateRtuFrameSize": classmethod(lambda cls, data: crc_frame_size(data))},
        )
        for code in range(1, LAST_FUNCTION_CODE + 1)
        if code not in table
    }
    known_lookup = decoder.lookupPduClass

    def lookup(data: bytes) -> type[ModbusPDU] | None:
        found = known_lookup(data)
        if found is None and int(data[1]) in unframed and int(data[0]) in set(units()):
            return unframed[int(data[1])]
        return found

    decoder.lookupPduClass = lookup  # type: ignore[method-assign]
    # The request's decode (after framing) looks the code up in the table too.
    decoder.pdu_table = {**table, **{code: (cls, cls) for code, cls in unframed.items()}}
