"""``motec_sim``'s command line: the simulated bus (motec_bridge/sim.py) served on a pty or
a serial port, with the personalities of docs/tools.md ("Device personalities") and those
``bridge_commission motec`` settles (the other reading of MOTEC decisions 2, 3, 7, 9, 13,
17, 21). The console script ``motec_sim`` and ``python -m motec_bridge.sim_cli`` run ``main``
(sim.py holds the bus it serves and does not import this module).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

from bridge_core.sim.command_line import add_serial_arguments, serve_serial_until_signalled
from bridge_core.sim.personality import add_delay_argument, add_ignore_argument

from .registers import DEFAULT_BAUDRATE, UNIT_IDS
from .sim import (
    DEFAULT_ACCEL_RPM_S,
    DEFAULT_COUNTS_PER_REV,
    DEFAULT_MOVE_SPEED_RPM,
    LIFEGUARD_FAULT_CODE,
    MotecSimDrive,
    make_simulator,
)


def _unit_list(text: str) -> list[int]:
    try:
        ids = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a comma-separated id list") from None
    if not ids or any(u not in UNIT_IDS for u in ids) or len(set(ids)) != len(ids):
        raise argparse.ArgumentTypeError(f"unit ids {text!r}: distinct ids in 1-31")
    return ids


def _fault(text: str) -> tuple[int, int]:
    unit, _, code = text.partition(":")
    try:
        return int(unit), int(code, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--fault {text!r}: UNIT:CODE, e.g. 2:0x31") from None


def _add_commissioning_arguments(parser: argparse.ArgumentParser) -> None:
    """The other readings ``bridge_commission motec`` settles (docs/tools.md)."""
    parser.add_argument(
        "--word-order",
        choices=("high", "low"),
        default="high",
        help="32-bit values in reads: high word first (decision 2) or low",
    )
    parser.add_argument(
        "--refuse-unnamed",
        action="store_true",
        help="unnamed parameters answer 0x02 (decision 3's other reading)",
    )
    parser.add_argument(
        "--answer-past-table",
        action="store_true",
        help="addresses past Pr.276 read 0 instead of 0x02 (decision 13's other reading)",
    )
    parser.add_argument(
        "--lifeguard-fault-code",
        type=lambda text: int(text, 0),
        default=LIFEGUARD_FAULT_CODE,
        help="0xC8-0xC9 after a lifeguard trip (default 0x10000: 0xC8 = 1, decision 7; "
        "1 puts the flag in 0xC9)",
    )
    parser.add_argument(
        "--lifeguard-keeps-watching",
        action="store_true",
        help="once armed, the lifeguard watches until a restart (decision 9's other reading)",
    )
    parser.add_argument(
        "--ignore-new-target",
        action="store_true",
        help="0x29 = 1 while a move runs changes nothing (decision 21's other reading)",
    )
    parser.add_argument(
        "--rest-dither-counts",
        type=int,
        default=0,
        help="at rest, enabled: 0xAC this many counts off, alternately (decision 17)",
    )
    parser.add_argument(
        "--lifeguard-ms",
        type=int,
        default=0,
        help="power up armed: 0x112 = this, 0x114 = 9999, as saved to flash (0: off)",
    )


def _play(drive: MotecSimDrive, args: argparse.Namespace) -> None:
    drive.low_word_first = args.word_order == "low"
    drive.unnamed_refused = args.refuse_unnamed
    drive.answer_past_table = args.answer_past_table
    drive.lifeguard_fault_code = args.lifeguard_fault_code
    drive.lifeguard_keeps_watching = args.lifeguard_keeps_watching
    drive.rest_dither_counts = args.rest_dither_counts
    drive.ignores_new_target = args.ignore_new_target
    if args.lifeguard_ms:
        drive.power_up_armed(args.lifeguard_ms)


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="MOTEC β servo drives on one Modbus RTU bus")
    add_serial_arguments(parser, DEFAULT_BAUDRATE, "/tmp/motec")
    parser.add_argument(
        "--unit-ids", type=_unit_list, default=[1], help="drives on the bus, e.g. 1,2,3"
    )
    add_delay_argument(
        parser, 0.0, "delay before every reply, after the request's last byte (manual: none)"
    )
    add_ignore_argument(parser, MotecSimDrive.IGNORABLE)
    parser.add_argument("--counts-per-rev", type=int, default=DEFAULT_COUNTS_PER_REV)
    parser.add_argument("--accel-rpm-s", type=float, default=DEFAULT_ACCEL_RPM_S)
    parser.add_argument(
        "--move-speed-rpm",
        type=float,
        default=DEFAULT_MOVE_SPEED_RPM,
        help="speed limit 0xAE at power-up (a move runs at |0xAE|)",
    )
    parser.add_argument(
        "--fault", type=_fault, action="append", default=[], help="latch a fault: UNIT:CODE"
    )
    _add_commissioning_arguments(parser)
    args = parser.parse_args(argv)
    if args.counts_per_rev <= 0 or args.accel_rpm_s <= 0 or args.move_speed_rpm <= 0:
        parser.error("--counts-per-rev, --accel-rpm-s and --move-speed-rpm must be > 0")
    sim = make_simulator(
        args.unit_ids,
        reply_delay_s=args.reply_delay_ms.low_s,
        counts_per_rev=args.counts_per_rev,
        accel_rpm_s=args.accel_rpm_s,
        move_speed_rpm=args.move_speed_rpm,
    )
    for drive in sim.drives.values():
        _play(drive, args)
    for unit, code in args.fault:
        if unit not in sim.drives:
            parser.error(f"--fault: no drive {unit} on the bus")
        sim.drive(unit).inject_fault(code)
    ids = ",".join(str(u) for u in args.unit_ids)
    serve_serial_until_signalled(
        sim,
        args,
        lambda where: (
            f"motec_sim listening on {where} (units {ids}, {args.baudrate} "
            f"baud, reply delay {args.reply_delay_ms.text})"
        ),
    )


if __name__ == "__main__":
    main()
