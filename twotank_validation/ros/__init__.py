"""ROS 2 adapters (rclpy): nodes, composition, message conversion. The core stays ROS-free."""
