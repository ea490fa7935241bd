"""One thin rclpy node per module; all decisions live in fabric_guidance.core. Beside the nodes:
spin (the main loop and safe shutdown), managed (the lifecycle base), parameters, qos,
diagnostics and array_layout (what every node shares)."""
