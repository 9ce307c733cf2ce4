"""aril_ros: a ROS 2 robustness testbed for imitation-learned policies (ARIL).

The library (this package) never imports rclpy; the ROS 2 nodes in ``nodes/`` are thin adapters.
"""
__version__ = "0.1.0"
