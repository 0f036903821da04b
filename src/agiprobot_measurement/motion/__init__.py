"""Robot motion: kinematics, inverse kinematics, Cartesian paths, collision checking, OMPL planning, trajectories."""
