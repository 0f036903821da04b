"""The 2D method of Fojtík & Pajdla, "Plánování pohybu range-finderu pro rekonstrukci modelu 3D tělesa".

A grid model, a triangulating range finder, growth points and scanning candidates, the circle of visibility, the view
score and the strategies 0/1/2, run by the report's scripts ``circpix``, ``fullpix`` and ``stratpix``. This
subpackage imports nothing of :mod:`agiprobot_measurement.nbv.volumetric` or :mod:`~agiprobot_measurement.nbv.simulation`.

Public face: :func:`.loop.run` with :class:`.run_config.RunConfig`, :class:`.range_finder.RangeFinder2D`,
:func:`.objects.make_object`, :func:`.evaluation.summarize`, :class:`.errors.NbvInputError`.

Modules (imported on demand; this file stays light):

- :mod:`.grid` values, fusion ``sign(M1 + M2)``, measured points and their export;
- :mod:`.traversal` supercover and 8-connected ray traversal (numba);
- :mod:`.range_finder` the sensor (``rangef2d``, ``rangef2d_``, ``bkrangef2d``);
- :mod:`.predicates` growth points, candidates, contour line, predicted point;
- :mod:`.visibility` the circle of visibility;
- :mod:`.scoring` Viditelnost x Kolmost x Pohyb;
- :mod:`.strategies` strategies 0/1/2 as a state machine with the outcome classes;
- :mod:`.reacquisition` views onto the model's frontier next to the known body, once the growth points are exhausted;
- :mod:`.run_config` the parameters of one run;
- :mod:`.loop` initial search, the scripts and their termination;
- :mod:`.objects` the six substitute bodies and bodies from images;
- :mod:`.families` the generated bodies (stars, combs, spirals, polygons, blobs) with a tuning and a held-out half;
- :mod:`.evaluation` the measurable boundary (brute force) and the run metrics;
- :mod:`.painting` the ``paintRF`` picture;
- :mod:`.errors` :class:`~.errors.NbvInputError`, an :class:`~agiprobot_measurement.errors.InputError`.

Coordinates: the model is an array ``M[i, j]`` (``i`` along x, ``j`` along y); cell ``(i, j)`` covers
``[i - 0.5, i + 0.5] x [j - 0.5, j + 0.5]``, 1 cell = 1 mm by default. The report's MATLAB element (1, 1) is our
``M[0, 0]``: the report's coordinates are ours plus one.
"""
