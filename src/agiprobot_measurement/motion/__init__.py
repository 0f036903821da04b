"""Robot motion: kinematics, inverse kinematics, Cartesian paths, collision checking, OMPL planning, trajectories.

Modules: ``kinematics`` with ``kinematics_kernels`` (forward kinematics, the true-kinematics correction; compiled FK
of large batches), ``ik`` (inverse kinematics), ``cartesian`` with ``cartesian_kernels`` (straight tip paths; the
compiled branch walk and continuation), ``cartesian_batch`` (many straight tip paths at once), ``collision`` with
``collision_config`` and ``collision_kernels`` (the FCL checker; its allowed-collision matrix and paddings; the broad
phase's geometry, compiled for large batches), ``motion_planning`` (OMPL; timing a planned path),
``point_to_point`` (synchronised joint moves), ``time_parameterization`` (TOPP-RA), ``trajectory`` (joint
trajectories), ``jtc`` (the simulated UR10e's joint trajectory controller), ``ur_modes`` (its robot and
safety modes, the dashboard's commands, the set_mode steps), ``errors`` (the subpackage's input errors).
"""
