"""The 3D loop's simulated station and ground truth (no ROS, no hardware).

It uses the public face of :mod:`agiprobot_measurement.nbv.volumetric` (the station, the interfaces, the request,
the reconstructor, the candidate generator and the gains) and nothing of :mod:`agiprobot_measurement.nbv.planar`.

Public face: :class:`.station3d.SimulatedNBVStation`, :class:`.station3d.SimulatedRobot`,
:class:`.station3d.SimulatedPhoXiCamera`, :func:`.station3d.load_part_mesh`, :class:`.ground_truth.GroundTruth`,
:func:`.ground_truth.simulate`, :func:`.ground_truth.auc`, :func:`.ground_truth.views_to`.

Modules (imported on demand):

- :mod:`.station3d` the station with the hidden part, the robot that executes trajectories and checks them against
  the true scene, and the camera that renders PhoXi frames;
- :mod:`.ground_truth` the observable surface, the coverage and Chamfer metrics and :func:`~.ground_truth.simulate`,
  one reconstruction with its summary;
- :mod:`.objects3d` the procedural concave test bodies;
- :mod:`.families3d` the generated parts (five families, 40 parts) with a tuning and a held-out half.
"""
