"""Modbus on the wire: register maps as data, the codec, the read planner, the requests,
the pymodbus transport (TCP, timed RTU), the channel (one device on a link: backoff,
priority lock, counters) and its link state. The only layer that imports pymodbus (with
``sim``); no rclpy."""
