"""ROS 2 bridge for the Huacheng R6 robot controller over Modbus TCP (manual: seed 000)."""
