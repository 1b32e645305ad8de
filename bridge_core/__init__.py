"""Shared runtime of the Modbus bridges: each concern two bridges share is solved here once.

Four layers (docs/architecture.md, "The rooms of bridge_core"), each a sub-package:
``wire`` (Modbus on the wire: maps, codec, planner, transport, channel, link state),
``runtime`` (what a bridge does, in plain Python: polling, reads, streams, goals, checks,
parameter specs, the interface listing), ``ros`` (the rclpy side: node base, parameters,
streams, actions, diagnostics, process runner, recorder, plot, demo) and ``sim`` (the
simulators' pymodbus server). A module imports its own layer and the layers below; only
``ros`` imports rclpy, only ``wire`` and ``sim`` import pymodbus (tests/core/test_layers.py).
"""
