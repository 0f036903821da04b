"""Robot motion: kinematics, inverse kinematics, Cartesian paths, collision checking, OMPL planning, trajectories.

Modules: ``kinematics`` (forward kinematics, the true-kinematics correction), ``ik`` (inverse kinematics),
``cartesian`` with ``cartesian_kernels`` (straight tip paths; the compiled branch walk), ``collision`` with
``collision_config`` (the FCL checker; its allowed-collision matrix and paddings), ``motion_planning`` (OMPL),
``point_to_point`` (synchronised joint moves), ``time_parameterization`` (TOPP-RA), ``trajectory`` (joint
trajectories), ``jtc`` (the simulated UR10e's joint trajectory controller), ``ur_modes`` (its robot and
safety modes, the dashboard's commands, the set_mode steps), ``errors`` (the subpackage's input errors).
"""
