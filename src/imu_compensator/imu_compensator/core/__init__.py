"""ROS-free algorithm code (numpy/scipy/OpenCV only): no rclpy, no message types."""
