"""Measurement planning: from a part file to an ordered, connected, executable scan plan of a laser line scanner.

Public face: :class:`~.trajectory_manager.TrajectoryManager` (the documented facade), :class:`~.request.PlanRequest`,
:class:`~.plan.session.MeasurementSession`, :class:`~.plan.plan_io.ExecutionPlan`, :func:`~.part_loading.load_part`.

Modules:

- ``trajectory_manager``: the facade; every method reads or writes a :class:`~.run.PlanningRun` and calls a stage.
- ``run``: the run's state (``PlanningRun``, ``Reserve``) and the tools its stages use (``PlanningTools``).
- ``request``: a planning request's defaults and validation, the work budget.
- ``part_loading``: reading, checking, placing and sampling the part.
- ``pipeline``: the whole pipeline on a loaded part, and tilt auto.
- ``connection``: ``ConnectionPlanner``, collision-free connection moves over the motion layer.
- ``ordering``: move times, view order, unwrapping, connecting the chosen views.
- ``recovery``: when a move fails: the other scan direction, retract-and-approach, dropping a view and covering its
  points again.
- ``errors``: the planning errors.
- ``candidates/``: candidate generation (samples, viewpoints, reachability, streamed and distributed metrology,
  scan-line mechanics).
- ``selection/``: the set cover's verify-and-resolve loop (round, verify, settle), revival of dominated
  candidates, the open points' and substitute views, the coverage problem.
- ``cover/``: the set cover solvers (greedy, reductions, integer programme).
- ``plan/``: plan files, execution, the executor registry, the measurement session.
- ``report/``: coverage report, measured coverage, the coverage figure, progress stages.
"""
