"""ROS 2 bridge for the 5-axis stepper motion controller over Modbus RTU (manual: seed 002)."""
