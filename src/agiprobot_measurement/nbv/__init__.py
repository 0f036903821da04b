"""Next-best-view reconstruction (ROS-free).

Part 1 is the faithful 2D method of Fojtík & Pajdla, "Plánování pohybu range-finderu pro rekonstrukci modelu 3D
tělesa": a grid model, a triangulating range finder, growth points and scanning candidates, the circle of visibility,
the view score and the strategies 0/1/2, run by the report's scripts ``circpix``, ``fullpix`` and ``stratpix``.

Part 2 is the report's announced generalisation to 3D on the station: the UR10e carries a PhoXi on its flange and
reconstructs an unknown part inside an a-priori bounding box, with a probabilistic voxel map, frontier-driven
candidate views filtered by closed-form IK and FCL, PhoXi-aware volumetric gains and a gain-based stop.

Modules (imported on demand; this file stays light so that ``import agiprobot_measurement.nbv`` costs nothing):

- :mod:`.grid` values, fusion ``sign(M1 + M2)``, measured points and their export;
- :mod:`.traversal` supercover and 8-connected ray traversal (numba);
- :mod:`.range_finder` the sensor (``rangef2d``, ``rangef2d_``, ``bkrangef2d``);
- :mod:`.predicates` growth points, candidates, contour line, predicted point;
- :mod:`.visibility` the circle of visibility;
- :mod:`.scoring` Viditelnost x Kolmost x Pohyb;
- :mod:`.strategies` strategies 0/1/2 as a state machine with the outcome classes;
- :mod:`.loop` initial search, the scripts and their termination;
- :mod:`.objects` the six substitute bodies and bodies from images;
- :mod:`.evaluation` the measurable boundary (brute force) and the run metrics;
- :mod:`.painting` the ``paintRF`` picture.

3D (metres, world frame of the station):

- :mod:`.voxel_map` the log-odds voxel map (OctoMap sensor model), its labels, growth voxels, candidates, occlusion
  plane, predicted surface and exports; :mod:`.raycast3d` its numba kernels;
- :mod:`.gains` the seven volumetric information gains and the report's, PhoXi-aware, and the utilities (their names in
  :mod:`.gain_names`, light to import);
- :mod:`.meshing` projective TSDF and marching cubes;
- :mod:`.interfaces` the robot and camera the loop needs (implemented by :mod:`.station3d` without ROS and by
  ``agiprobot_measurement.ros.nbv_interfaces`` on the station);
- :mod:`.candidates` frontier-driven and view-sphere candidates and their filter chain;
- :mod:`.reconstruction` the request, the loop, the stopping rules and the outputs; :mod:`.baselines` the
  comparison methods; :mod:`.ground_truth` observable surface and the benchmark metrics; :mod:`.objects3d` the
  procedural concave test bodies.

2D coordinates: the model is an array ``M[i, j]`` (``i`` along x, ``j`` along y); cell ``(i, j)`` covers
``[i - 0.5, i + 0.5] x [j - 0.5, j + 0.5]``, 1 cell = 1 mm by default. The report's MATLAB element (1, 1) is our
``M[0, 0]``: the report's coordinates are ours plus one.
"""
