"""Run logs: the columnar format and ROS 2 bags."""
