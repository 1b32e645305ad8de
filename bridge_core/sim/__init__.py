"""The simulators' base: a strict pymodbus server whose datastore follows a register map.
Imports the wire layer; never rclpy."""
