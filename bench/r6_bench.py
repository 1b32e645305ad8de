#!/usr/bin/env python3
"""R6 bridge benchmark under its old name: ``bridge_bench.py``, whose default device is r6.

    .venv/bin/python bench/r6_bench.py [--duration 5] [--quick] [--domain-id 101] ...

takes every option of bench/bridge_bench.py and writes bench/results/r6_bench.json.
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from bench.bridge_bench import main  # noqa: E402

if __name__ == "__main__":
    main()
