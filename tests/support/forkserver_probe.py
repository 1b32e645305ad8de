"""A program for tests/support_tests/test_forkserver.py: what a forked child sees of itself.

``python -m tests.support.forkserver_probe ACTION [ARG]``: prints its argv, working
directory, ``PROBE`` variable and whether it leads a process group, then ``exit CODE``,
``raise`` (an uncaught error), ``interrupt`` (an uncaught KeyboardInterrupt) or ``wait``
(until a signal ends it; SIGINT raises KeyboardInterrupt as in any Python program).
"""

from __future__ import annotations

import os
import sys
import time


def main() -> None:
    action = sys.argv[1]
    print(f"argv={sys.argv[1:]} cwd={os.getcwd()} PROBE={os.environ.get('PROBE')!r}")
    print(f"group leader={os.getpgid(0) == os.getpid()} main={__name__}")
    print("to stderr", file=sys.stderr)
    sys.stdout.flush()
    if action == "exit":
        sys.exit(int(sys.argv[2]))
    if action == "raise":
        raise RuntimeError("probe error")
    if action == "interrupt":
        raise KeyboardInterrupt
    try:
        while True:
            time.sleep(0.05)
    except KeyboardInterrupt:
        print("interrupted")
        sys.exit(3)


if __name__ == "__main__":
    main()
