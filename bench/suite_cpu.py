"""Where the test suite's CPU goes: every Python process of a run, by kind and by test.

The suite is CPU-bound on a 2-core machine (docs/testing.md, "What is slow and why"): its
wall time follows the CPU its processes take, not the waits. This runs ``scripts/test.sh``
(``LINT=0``; arguments go to pytest) with a ``sitecustomize`` on ``PYTHONPATH`` that makes
every Python process of the run append, at exit, its own CPU time (user + system), its
command line and the test that was running (``PYTEST_CURRENT_TEST``, inherited by the
processes a test starts) to a log; then it prints the wall time, the CPU of the whole run
(``RUSAGE_CHILDREN``), the share of it no Python process accounts for (the colcon build's
compilers, socat, processes killed before their exit hook), and the Python CPU by kind of
process, by test module and by test.

    .venv/bin/python bench/suite_cpu.py                     # the whole suite (~9 min)
    .venv/bin/python bench/suite_cpu.py tests/core/ros/test_contract.py -k r6
    .venv/bin/python bench/suite_cpu.py --log results/cpu.jsonl --top 20

Figures only; nothing is asserted. A process ended by SIGKILL writes no record.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LOG_VARIABLE = "SUITE_CPU_LOG"

# Appended by each Python process of the run at its exit (atexit: a normal exit, an
# exception, SIGINT turned into KeyboardInterrupt; not SIGKILL).
SITECUSTOMIZE = f'''
import atexit, json, os, sys

def _suite_cpu_record():
    times = os.times()
    record = {{
        "pid": os.getpid(),
        "argv": sys.argv[:4],
        "test": os.environ.get("PYTEST_CURRENT_TEST", ""),
        "cpu": times.user + times.system,
    }}
    with open(os.environ["{LOG_VARIABLE}"], "a") as log:
        log.write(json.dumps(record) + "\\n")

if os.environ.get("{LOG_VARIABLE}"):
    atexit.register(_suite_cpu_record)
'''


def kind_of(argv: list[str]) -> str:
    """What a process was, from its ``sys.argv`` (a ``-m`` module's is its file's path)."""
    if argv == ["-c"]:
        return "pytest-xdist worker (the tests themselves, in-process)"  # execnet's bootstrap
    first = Path(argv[0]) if argv else Path("?")
    text = str(first)
    if "pytest" in text:
        return "pytest"
    if "rosidl" in text or "colcon" in text or "ament" in text:
        return "colcon build (Python parts)"
    package = first.parent.name if first.suffix == ".py" else first.name
    if first.name == "demo.py":
        return "demo"
    if first.name == "sim.py" or first.name.endswith("_sim"):
        return f"simulator: {package}"
    if first.name in ("node.py", "bus.py") or first.name.endswith(("_bridge", "_bus")):
        return f"bridge node: {package}"
    return f"other Python: {first.name}"


def table(rows: Iterable[tuple[str, float, int]], total: float, title: str, top: int) -> None:
    print(f"\n{title}")
    print(f"  {'CPU-s':>8} {'share':>6} {'procs':>6}  what")
    for name, cpu, count in list(rows)[:top]:
        print(f"  {cpu:8.1f} {100 * cpu / total:5.1f}% {count:6d}  {name}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--log", type=Path, help="keep the per-process records here (JSON lines)")
    parser.add_argument("--top", type=int, default=15, help="rows per table (default 15)")
    parser.add_argument("--workers", help="TEST_WORKERS for scripts/test.sh (its default if unset)")
    args, pytest_args = parser.parse_known_args()

    with tempfile.TemporaryDirectory(prefix="suite_cpu_") as tmp:
        hook = Path(tmp) / "hook"
        hook.mkdir()
        (hook / "sitecustomize.py").write_text(SITECUSTOMIZE)
        log = args.log or Path(tmp) / "cpu.jsonl"
        log.parent.mkdir(parents=True, exist_ok=True)
        log.write_text("")
        env = {
            **os.environ,
            "LINT": "0",
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST",
            LOG_VARIABLE: str(log.resolve()),
            "PYTHONPATH": os.pathsep.join(
                p for p in (str(hook), os.environ.get("PYTHONPATH", "")) if p
            ),
        }
        if args.workers is not None:
            env["TEST_WORKERS"] = args.workers
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        started = time.monotonic()
        code = subprocess.call(["bash", "scripts/test.sh", "-q", *pytest_args], cwd=ROOT, env=env)
        wall = time.monotonic() - started
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        records = [json.loads(line) for line in log.read_text().splitlines() if line.strip()]

    total = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    python = sum(r["cpu"] for r in records)
    cores = os.cpu_count() or 1
    print(f"\nscripts/test.sh exit code {code}; wall {wall:.1f} s on {cores} cores")
    print(
        f"CPU of the run {total:.1f} CPU-s ({100 * total / (wall * cores):.0f} % of the cores);"
        f" Python processes {python:.1f} CPU-s in {len(records)} processes;"
        f" not accounted for by them {max(0.0, total - python):.1f} CPU-s"
    )

    by_kind: dict[str, list[float]] = collections.defaultdict(list)
    by_module: dict[str, list[float]] = collections.defaultdict(list)
    by_test: dict[str, list[float]] = collections.defaultdict(list)
    for record in records:
        kind = kind_of(record["argv"])
        by_kind[kind].append(record["cpu"])
        if record["test"] and not kind.startswith("pytest"):
            test = record["test"].rsplit(" (", 1)[0].split("@", 1)[0]
            by_module[test.split("::", 1)[0]].append(record["cpu"])
            by_test[test].append(record["cpu"])

    def rows(groups: dict[str, list[float]]) -> list[tuple[str, float, int]]:
        return sorted(
            ((name, sum(cpus), len(cpus)) for name, cpus in groups.items()),
            key=lambda row: -row[1],
        )

    table(rows(by_kind), total, "Python CPU by kind of process", args.top)
    table(rows(by_module), total, "CPU of the processes each test module started", args.top)
    table(rows(by_test), total, "CPU of the processes each test started", args.top)
    node_cpus = sorted(
        cpu for kind, cpus in by_kind.items() if "bridge node" in kind for cpu in cpus
    )
    if node_cpus:
        median = node_cpus[len(node_cpus) // 2]
        print(
            f"\nbridge node processes: {len(node_cpus)}, CPU-s each: least {node_cpus[0]:.2f}"
            f" (a refused start), median {median:.2f}, most {node_cpus[-1]:.2f}"
        )
    sys.exit(code)


if __name__ == "__main__":
    main()
