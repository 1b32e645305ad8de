"""The one list of bridges (``entries.bridge_packages()``): the tests and scripts that go
over every bridge take it from the ``modbus_bridges.interface`` entry points, so it must
name every bridge package of the checkout, and the installed entry points must agree."""

from __future__ import annotations

from pathlib import Path

from bridge_core.runtime import entries

ROOT = Path(__file__).resolve().parents[3]


def test_every_bridge_package_of_the_checkout_is_listed() -> None:
    on_disk = sorted(
        p.parent.name
        for p in ROOT.glob("*/interface.py")
        if (p.parent / "__init__.py").is_file() and p.parent.name != "bridge_core"
    )
    assert on_disk, "no <bridge>/interface.py found"
    assert sorted(entries.bridge_packages(ROOT).values()) == on_disk


def test_an_install_lists_the_same_bridges(tmp_path: Path) -> None:
    """Without a checkout's pyproject.toml (tmp_path has none), the list comes from the
    installed entry points: the install (scripts/setup.sh) declares them all."""
    installed = entries.bridge_packages(tmp_path)
    assert installed == entries.bridge_packages(ROOT)
    assert all(package.endswith("_bridge") for package in installed.values())
