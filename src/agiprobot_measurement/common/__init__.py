"""Shared foundations: geometry, configuration validation, units, atomic files.

Modules: ``cli`` (how a command-line tool ends: exit status and error line), ``config`` (YAML reading and the
number/vector validators every loader uses), ``files`` (atomic writes; the command-line and node file policies),
``geometry`` (poses, rotations, quaternions), ``limits`` (the bounds of every input read, checked before the work
starts, and ``excerpt`` for quoting inputs in messages), ``message_shape`` (ROS-message-shaped snapshots without ROS),
``units`` (length units to metres).
"""
