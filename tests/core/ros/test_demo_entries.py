"""bridge_demo's device entries: each bridge declares its own, the runner names none."""

from __future__ import annotations

import importlib
import subprocess
import sys
from pathlib import Path

import pytest

from bridge_core.ros import demo

ROOT = Path(__file__).resolve().parents[3]


def test_every_bridge_demo_module_is_declared() -> None:
    on_disk = sorted(
        f"{p.parent.name}.demo:DEMO"
        for p in ROOT.glob("*/demo.py")
        if (p.parent / "__init__.py").is_file() and p.parent.name != "bridge_core"
    )
    assert on_disk, "no <bridge>/demo.py found"
    assert sorted(demo.entry_specs(ROOT)) == on_disk


def test_entries_load_in_their_order() -> None:
    devices = demo.load_devices(demo.entry_specs(ROOT))
    assert [d.name for d in devices] == ["R6", "xArm", "Stepper", "MOTEC"]
    for device in devices:
        where = "/tmp/x.pty" if device.serial else 1502
        command = device.simulator_command(where)
        assert command[:4] == [
            "-m",
            device.sim_module or f"{device.package}.sim",
            "--pty" if device.serial else "--port",
            str(where),
        ]
        # The module run is a simulator's command line of the package (MOTEC: sim_cli).
        assert command[1].startswith(f"{device.package}.sim")
        assert callable(getattr(importlib.import_module(command[1]), "main", None)), command[1]
        node = device.node_command(where)
        assert node[:2] == ["-m", f"{device.package}.node"]
        assert f"__ns:=/{device.name.lower()}" in node
        # where the device is, as the node's transport parameter; the entry cannot override it
        where_param = f"serial_port:={where}" if device.serial else f"port:={where}"
        assert node.count(where_param) == 1
        assert not {"port", "serial_port"} & device.node_params.keys()


def test_explicit_modules_and_bad_specs() -> None:
    assert [d.name for d in demo.load_devices(["motec_bridge.demo", "r6_bridge.demo:DEMO"])] == [
        "R6",
        "MOTEC",
    ]
    with pytest.raises(TypeError):
        demo.load_devices(["r6_bridge.demo:format_state"])
    with pytest.raises(ValueError):
        demo.load_devices(["r6_bridge.demo", "r6_bridge.demo:DEMO"])


def test_another_projects_pyproject_is_not_read(tmp_path: Path) -> None:
    (tmp_path / "pyproject.toml").write_text(
        '[project]\nname = "other"\n[project.entry-points."modbus_bridges.demo"]\n'
        'x = "x.demo:DEMO"\n'
    )
    assert "x.demo:DEMO" not in demo.entry_specs(tmp_path)


def test_loading_the_entries_imports_no_rclpy() -> None:
    code = (
        "import sys; from bridge_core.ros import demo; demo.load_devices(demo.entry_specs()); "
        "assert 'rclpy' not in sys.modules, sorted(m for m in sys.modules if 'rcl' in m)"
    )
    subprocess.run([sys.executable, "-c", code], cwd=ROOT, check=True, timeout=60)
