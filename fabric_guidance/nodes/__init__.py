"""One thin rclpy node per module; all decisions live in fabric_guidance.core."""
