#!/usr/bin/env python3
"""Actions: how soon a cancel puts the stop on the wire, and how soon feedback starts.

What "cancelling it stops it" (docs/actions.md) costs. Setup: ``motec_bridge`` in a process
of its own (one drive, 115200 baud, 20 Hz polls, ``timeout_s`` 1.0) against the MOTEC
simulator in this process on a socat pty pair; an ``rclpy.action.ActionClient`` here. Per
repetition: a long ``~/move_to`` goal; once its feedback shows the drive turning, cancel it.
Measured with wall-clock stamps of this host (the simulator's write log uses
``time.time()``):

- ``accept``: goal sent -> goal response (accepted);
- ``first feedback``: goal response -> first feedback message;
- ``cancel -> stop``: cancel request sent -> the stop write (0x29 = 0) in the write log;
- ``cancel -> result``: cancel request sent -> result received.

Prints a table (median, p90, max); asserts nothing. Only loopback and ptys; discovery on
localhost.

    .venv/bin/python bench/action_cancel.py [--repeat 20] [--poll-rate-hz 20]
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
os.environ.setdefault("ROS_DOMAIN_ID", "106")

BAUD = 115200
WAIT_S = 30.0  # generous bound on every wait for the bridge (a loaded machine)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=20, help="goals to send and cancel")
    parser.add_argument("--poll-rate-hz", type=float, default=20.0)
    args = parser.parse_args()

    from std_srvs.srv import SetBool

    from motec_bridge.registers import MOTEC_MAP, STOP_MOVE
    from motec_bridge.sim import make_simulator
    from msg_defs.action import MoveTo
    from msg_defs.msg import MotecState
    from msg_defs.srv import SetControlMode
    from tests.support.ros import node_process, ros_client, wait_for
    from tests.support.serial_pair import served_on_pty

    start_register = MOTEC_MAP["start"].address
    simulator = make_simulator([1])
    drive = simulator.drive(1)
    figures: dict[str, list[float]] = {
        "accept": [],
        "first feedback": [],
        "cancel -> stop": [],
        "cancel -> result": [],
    }
    namespace = "/bench_action"
    state = f"{namespace}/motec_1/state"
    with (
        tempfile.TemporaryDirectory() as log_dir,
        served_on_pty(simulator, BAUD) as port,
        ros_client("bench_action_client") as client,
    ):
        client.subscribe(MotecState, state)
        params = {
            "serial_port": port,
            "baudrate": BAUD,
            "unit_ids": [1],
            "poll_rate_hz": args.poll_rate_hz,
            "timeout_s": 1.0,
        }
        with node_process("motec_bridge.node", params, Path(log_dir), ["-r", f"__ns:={namespace}"]):
            client.wait_message(state, timeout=WAIT_S)  # connected and polling
            for name, srv, field, value in (
                ("set_control_mode", SetControlMode, "mode", SetControlMode.Request.POSITION),
                ("enable", SetBool, "data", True),
            ):
                request = srv.Request()
                setattr(request, field, value)
                reply = client.call(srv, f"{namespace}/motec_1/{name}", request, timeout=WAIT_S)
                assert reply.success, reply.message
            for _ in range(args.repeat):
                goal = MoveTo.Goal()
                goal.position = 200 * math.pi  # 100 turns: never reached here
                goal.relative = True
                goal.max_velocity = 2 * math.pi
                sent_at = time.time()
                sent = client.send_goal(MoveTo, f"{namespace}/motec_1/move_to", goal, WAIT_S)
                accepted_at = time.time()
                assert sent.accepted, "goal rejected (see the bridge's log)"
                sent.wait_feedback(timeout=WAIT_S)
                fed_at = time.time()
                sent.wait_feedback(lambda f: abs(f.velocity) > 0.1, timeout=WAIT_S)
                mark = len(drive.write_log)
                cancel_at = time.time()
                with client.between_spins():  # rclpy's race: tests/support/ros.py
                    future = sent.handle.cancel_goal_async()
                _status, result = sent.result(WAIT_S)
                result_at = time.time()
                wait_for(future.done, WAIT_S, "the cancel response")
                stops = [
                    r.time
                    for r in drive.write_log[mark:]
                    if r.address == start_register and r.values == (STOP_MOVE,)
                ]
                assert stops and result.outcome.name == "CANCELLED", result.outcome.message
                figures["accept"].append(accepted_at - sent_at)
                figures["first feedback"].append(fed_at - accepted_at)
                figures["cancel -> stop"].append(stops[0] - cancel_at)
                figures["cancel -> result"].append(result_at - cancel_at)
                sent.close()
    print(f"MOTEC ~/move_to, {args.repeat} goals, {BAUD} baud pty, polls {args.poll_rate_hz:g} Hz")
    print(f"{'figure':<18} {'median ms':>10} {'p90 ms':>8} {'max ms':>8}")
    for name, values in figures.items():
        ordered = sorted(values)
        p90 = ordered[min(len(ordered) - 1, int(0.9 * len(ordered)))]
        print(
            f"{name:<18} {statistics.median(values) * 1e3:>10.1f} {p90 * 1e3:>8.1f} "
            f"{max(values) * 1e3:>8.1f}"
        )


if __name__ == "__main__":
    main()
