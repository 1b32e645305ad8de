"""Shared plumbing of the Modbus bridges: register maps, codec, read planner, link, node base.

Only ``link`` and ``sim_base`` import pymodbus; only ``node_base`` and ``recorder`` import rclpy.
"""
