"""ROS 2 bridge for MOTEC β servo drives on one Modbus RTU bus (manual: seed 003)."""
