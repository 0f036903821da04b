"""Candidate viewpoints and their evaluation.

Public face: :func:`~.generation.generate_samples_and_viewpoints`, :class:`~.viewpoint.ViewPoint`,
:func:`~.viewpoint.generate_viewpoint_poses`, :func:`~.streaming.evaluate_streaming`.

Modules: ``generation`` (samples, candidates, reachability, metrology, the views of a run), ``viewpoint`` (the
viewpoint and the candidate poses), ``streaming`` (chunked metrology, dominance drops, memory projection),
``time_fit`` (the candidates a deadline leaves time for), ``distributed`` (the same on a Dask cluster), ``mechanics`` (anchor reachability, scan lines and their check).
"""
