"""agiprobot_measurement: robotic 3D measurement on ROS 1 (ROS-free core; nodes live in ``nodes/``)."""

__version__ = "0.1.0"
