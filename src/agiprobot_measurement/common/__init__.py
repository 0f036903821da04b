"""Shared foundations: geometry, configuration validation, units, atomic files.

Modules: ``cli`` (how a command-line tool ends: exit status and error line), ``config`` (YAML reading and the
number/vector validators every loader uses), ``files`` (atomic writes; the command-line and node file policies),
``geometry`` (poses, rotations, quaternions), ``message_shape`` (ROS-message-shaped snapshots without ROS),
``units`` (length units to metres).
"""
