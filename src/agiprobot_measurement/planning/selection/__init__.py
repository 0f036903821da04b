"""Choosing the views: the set cover's verify-and-resolve loop over a planning run.

Public face: :func:`~.loop.solve_scp`, :class:`~.loop.CoverLoop`.

Modules: ``loop`` (the rounds: solve, settle, verify; the polish over verified views), ``verify`` (a view's
mechanical verification and what it changes in the run), ``revival`` (dominated candidates evaluated again when
their dominator fails), ``open_points`` (views of points no verified view measures, substitutes of a picked view),
``problem`` (the coverage problem from the run's store and views).
"""
