"""Offline accuracy evaluation against ground truth (EVALUATION.md); no rclpy."""
