"""ROS-free algorithm code (numpy/OpenCV only): no rclpy, no message types."""
