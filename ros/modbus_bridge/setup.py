"""colcon (ament_python) build of modbus_bridge; names and versions come from pyproject.toml."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "scripts"))
from ament_index import setup_ament_python

setup_ament_python("modbus_bridge")
