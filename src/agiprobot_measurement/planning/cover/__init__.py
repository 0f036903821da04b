"""The set cover solvers of viewpoint selection.

Public face: :func:`~.solve.solve_set_cover`, :data:`~.solve.SOLVER_TYPES`, :class:`~.solve.SetCoverResult`.

Modules: ``solve`` (the entry point and its result), ``columns`` (the column store), ``reduction`` (row and column
reductions), ``greedy`` (the weighted greedy cover), ``ip`` (the integer programme with HiGHS).
"""
