"""What a bridge does, in plain Python: reads, the poller, stream guards and their deadman,
goals, the motion ledger, the device watchdog feeder, checks, the configuration cache,
parameter specs, diagnostics bookkeeping and the ROS-free interface listing. Imports the
wire layer; never rclpy or pymodbus."""
