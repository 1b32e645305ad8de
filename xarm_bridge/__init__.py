"""ROS 2 bridge for the UFactory xArm controller's Modbus TCP interface (manual: seed 001)."""
