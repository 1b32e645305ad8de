"""Shared plumbing of the Modbus bridges: register maps, codec, read planner, channel and
transport, node base.

Only ``transport``, ``serial_timing`` and ``sim_base`` import pymodbus; only ``node_base`` and
``recorder`` import rclpy.
"""
