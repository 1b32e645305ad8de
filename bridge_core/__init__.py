"""Shared runtime of the Modbus bridges: each concern two bridges share is solved here once.

ROS-free: ``registers`` (maps as data), ``codec``, ``planner``, ``requests``,
``transport`` (the pymodbus pipe), ``serial_timing`` (RTU timing) and ``serial_port``,
``channel`` (one device on a link: backoff, priority lock, counters), ``poller`` (pacing,
re-plan, stamped snapshots), ``stream_guard`` (jog / velocity deadman), ``checks``,
``parameters`` (specs), ``config_cache``, ``diagnostics``, ``sim_base``. ROS: ``node_base``
(BridgeNode) with ``node_parameters``, ``node_streams``, ``node_actions`` /
``action_results``, ``node_diagnostics``, ``process`` (BusNode, spin_nodes); ``recorder``,
``demo``.

Only ``transport``, ``serial_timing`` and ``sim_base`` import pymodbus; only the node modules
above, ``recorder`` and ``demo`` import rclpy.
"""
