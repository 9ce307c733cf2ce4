"""aril_ros: a ROS 2 robustness testbed for imitation-learned policies (ARIL).

The library (this package) never imports rclpy; the ROS 2 side (``nodes/``, installed as
``aril_ros_nodes``) is thin adapters around it and registers itself through entry points
(:mod:`aril_ros.plugins`). docs/architecture.md maps the rooms.
"""
__version__ = "0.1.0"
