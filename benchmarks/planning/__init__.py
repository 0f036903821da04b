"""Planning benchmarks. ``python -m benchmarks.planning`` runs the pipeline benchmark.

Module index: ``pipeline`` (the whole pipeline on the original's cube, beside the original's numbers), ``parts``
(every real part planned and replayed on the simulated scanner), ``scale`` (door-sized panels, streamed and on local
Dask clusters), ``set_cover`` (the solvers on synthetic cube instances), ``metrology`` (sampling, viewpoints and
metrological evaluation alone).
"""
