"""A plan's lifecycle: its file, its execution, the executors and the measurement session.

Public face: :class:`~.plan_io.ExecutionPlan`, :func:`~.plan_io.load_execution_plan`,
:func:`~.execution.load_plan`, :func:`~.execution.adapt_plan_start`, :func:`~.execution.execute_segments`,
:func:`~.executors.register`, :class:`~.session.MeasurementSession`.

Modules: ``plan_io`` (the plan file format, start adaptation), ``execution`` (the executor interface, the segment
loop, the one plan loader and start adaptation), ``executors`` (the registry the layers above register their
station executors in), ``session`` (a station's current plan and everything done with it).
"""
