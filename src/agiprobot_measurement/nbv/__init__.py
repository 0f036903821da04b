"""Next-best-view reconstruction (ROS-free), in three subpackages that never import each other's internals.

- :mod:`.planar` the faithful 2D method of Fojtík & Pajdla, "Plánování pohybu range-finderu pro rekonstrukci modelu
  3D tělesa": a grid model, a triangulating range finder, growth points and scanning candidates, the circle of
  visibility, the view score and the strategies 0/1/2, run by the report's scripts ``circpix``, ``fullpix`` and
  ``stratpix``. Modules: ``grid``, ``traversal``, ``range_finder``, ``predicates``, ``visibility``, ``scoring``,
  ``strategies``, ``run_config``, ``loop``, ``objects``, ``evaluation``, ``painting``, ``errors``.
- :mod:`.volumetric` the report's announced generalisation to 3D on the station: the UR10e carries a PhoXi on its
  flange and reconstructs an unknown part inside an a-priori bounding box, with a probabilistic voxel map,
  frontier-driven candidate views filtered by closed-form IK and FCL, PhoXi-aware volumetric gains and a gain-based
  stop. Modules: ``settings``, ``request``, ``results``, ``reconstruction``, ``stopping``, ``novelty``, ``outputs``,
  ``policies`` (``base``, ``ours``, ``metrics``, ``baselines``, ``registry``), ``voxel_map``, ``map_parts``,
  ``pooling``, ``raycast3d``, ``gains``, ``gain_names``, ``meshing``, ``interfaces``, ``station3d``, ``candidates``,
  ``errors``.
- :mod:`.simulation` the 3D loop's simulated station (the hidden part, the robot, the rendered PhoXi), the observable
  ground truth and its metrics, and the procedural test bodies. Modules: ``station3d``, ``ground_truth``,
  ``objects3d``. It uses the public face of :mod:`.volumetric` only.

Each subpackage's ``__init__`` names its public face and its module index; this file imports nothing, so that
``import agiprobot_measurement.nbv`` costs nothing. ``test/core/nbv/test_nbv_layout.py`` keeps the three apart.
"""
