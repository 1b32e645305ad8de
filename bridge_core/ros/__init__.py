"""The rclpy side: the node base and its rooms (parameters, streams, actions, diagnostics),
the process runner, and the recorder, plot and demo tools. The only layer that imports
rclpy."""
