"""ROS-free scene code (numpy only): no rclpy, no message types."""
