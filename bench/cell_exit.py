"""Ctrl-C of the demo cell, as ``launch/cell.launch.py`` runs it: what the processes print.

``ros2 launch`` is not in the PyPI wheels, so this starts the launch file's processes
itself: the four simulators and their bridges with the launch file's arguments and
parameters (config file, then the same ``-p`` values), all in one process group, as
launch's children are. After ``--run-s`` of running it sends SIGINT to the whole group:
what a terminal's Ctrl-C does (launch, interrupted by it, sends no SIGINT of its own, only
SIGTERM to a child still running after its ``sigterm_timeout``, 5 s). It counts, per run,
the ERROR lines and the "never retrieved" lines (an rclpy callback's error nobody
collected) in every process's output, and lists the exit codes that were not 0.

    .venv/bin/python bench/cell_exit.py --runs 3            # ~20 s a run
    .venv/bin/python bench/cell_exit.py --runs 5 --show     # print the offending lines

Ports are free ones (not the launch file's 5020 / 5021), ptys in a temp dir; the ROS
domain is ``--domain-id`` (default 103) with discovery on this machine only.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bridge_core.wire.ports import free_port  # noqa: E402

CONFIG = ROOT / "config"
BIN = Path(sys.executable).parent
EXIT_WAIT_S = 20.0
MOTEC_LIFEGUARD_MS = 6000  # launch/cell.launch.py's


def commands(tmp: Path) -> dict[str, list[str]]:
    """Each process of launch/cell.launch.py: name -> argv."""
    r6_port, xarm_port = free_port(), free_port()
    stepper_pty, motec_pty = str(tmp / "cell_stepper"), str(tmp / "cell_motec")

    def bridge(package: str, namespace: str, config: str, **params: object) -> list[str]:
        argv = [str(BIN / package), "--ros-args"]
        if package != "motec_bridge":  # a LifecycleNode: launch names it
            argv += ["-r", f"__node:={package}"]
        argv += ["-r", f"__ns:={namespace}", "--params-file", str(CONFIG / config)]
        for key, value in params.items():
            argv += ["-p", f"{key}:={value}"]
        return argv

    return {
        "r6_sim": [str(BIN / "r6_sim"), "--port", str(r6_port), "--running"],
        "xarm_sim": [str(BIN / "xarm_sim"), "--port", str(xarm_port)],
        "stepper_sim": [str(BIN / "stepper_sim"), "--pty", stepper_pty],
        "motec_sim": [str(BIN / "motec_sim"), "--pty", motec_pty, "--unit-ids", "1,2,3"],
        "r6_bridge": bridge("r6_bridge", "/r6", "r6.yaml", host="127.0.0.1", port=r6_port),
        "xarm_bridge": bridge(
            "xarm_bridge", "/xarm", "xarm.yaml", host="127.0.0.1", port=xarm_port
        ),
        "stepper_bridge": bridge(
            "stepper_bridge", "/stepper", "stepper.yaml", serial_port=stepper_pty
        ),
        "motec_bridge": bridge(
            "motec_bridge",
            "/motec",
            "motec.yaml",
            serial_port=motec_pty,
            timeout_s=1.0,
            lifeguard_ms=MOTEC_LIFEGUARD_MS,
        ),
    }


def one_run(run_s: float, show: bool, keep: Path | None) -> tuple[int, int, dict[str, int | None]]:
    """Start the cell, Ctrl-C it: (ERROR lines, never-retrieved lines, exit codes)."""
    with tempfile.TemporaryDirectory(prefix="cell_exit_") as name:
        tmp = Path(name)
        procs: dict[str, subprocess.Popen[bytes]] = {}
        logs: dict[str, Path] = {}
        group = 0
        for proc_name, argv in commands(tmp).items():
            logs[proc_name] = tmp / f"{proc_name}.log"
            with logs[proc_name].open("wb") as log:
                proc = subprocess.Popen(
                    argv, cwd=ROOT, stdout=log, stderr=subprocess.STDOUT, process_group=group
                )
            group = group or proc.pid
            procs[proc_name] = proc
        time.sleep(run_s)  # the cell runs: connects, polls (a bench: nothing is judged by it)
        os.killpg(group, signal.SIGINT)  # the terminal's Ctrl-C reaches every child
        codes: dict[str, int | None] = {}
        for proc_name, proc in procs.items():
            try:
                codes[proc_name] = proc.wait(EXIT_WAIT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
                codes[proc_name] = None
        if keep is not None:
            keep.mkdir(parents=True, exist_ok=True)
            for path in logs.values():
                (keep / path.name).write_bytes(path.read_bytes())
        errors = retrieved = 0
        for proc_name, path in logs.items():
            for line in path.read_text(errors="replace").splitlines():
                bad = "ERROR" in line or "never retrieved" in line or "Traceback" in line
                errors += "ERROR" in line
                retrieved += "never retrieved" in line
                if bad and show:
                    print(f"  {proc_name}: {line}")
        return errors, retrieved, codes


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--run-s", type=float, default=12.0, help="running time before Ctrl-C")
    parser.add_argument("--domain-id", type=int, default=103)
    parser.add_argument("--show", action="store_true", help="print the ERROR lines")
    parser.add_argument("--logs", type=Path, help="keep each run's logs in LOGS/run_<n>/")
    args = parser.parse_args()
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.pop("ROS_LOCALHOST_ONLY", None)
    os.environ["ROS_DOMAIN_ID"] = str(args.domain_id)
    total_errors = total_retrieved = 0
    for run in range(1, args.runs + 1):
        keep = args.logs / f"run_{run}" if args.logs else None
        errors, retrieved, codes = one_run(args.run_s, args.show, keep)
        total_errors += errors
        total_retrieved += retrieved
        unclean = {name: code for name, code in codes.items() if code != 0}
        print(
            f"run {run}: ERROR lines {errors}, 'never retrieved' lines {retrieved}, "
            f"non-zero exits {unclean or 'none'}",
            flush=True,
        )
    print(
        f"{args.runs} runs: ERROR lines {total_errors}, 'never retrieved' lines {total_retrieved}"
    )


if __name__ == "__main__":
    main()
