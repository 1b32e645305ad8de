"""Shared runtime of the Modbus bridges: each concern two bridges share is solved here once.

ROS-free: ``registers`` (maps as data), ``codec``, ``planner``, ``requests``,
``transport`` (the pymodbus pipe), ``channel`` (one device on a link: backoff, priority
lock, counters), ``poller`` (pacing, re-plan, stamped snapshots), ``stream_guard`` (jog /
velocity deadman), ``checks``, ``parameters`` (specs), ``config_cache``, ``diagnostics``,
``sim_base``. ROS: ``node_base`` (BridgeNode, BusNode, spin_nodes), ``recorder``, ``demo``.

Only ``transport``, ``serial_timing`` and ``sim_base`` import pymodbus; only ``node_base``,
``recorder`` and ``demo`` import rclpy.
"""
