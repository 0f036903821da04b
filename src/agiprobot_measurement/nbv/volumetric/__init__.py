"""The 3D next-best-view loop on the station: the UR10e carries a PhoXi on its flange and reconstructs an unknown
part inside an a-priori bounding box, with a probabilistic voxel map, frontier-driven candidate views filtered by
closed-form IK and FCL, PhoXi-aware volumetric gains and a gain-based stop. Metres, world frame of the station.

This subpackage imports nothing of :mod:`agiprobot_measurement.nbv.planar` or
:mod:`agiprobot_measurement.nbv.simulation`.

Public face: :class:`.reconstruction.Reconstructor`, :class:`.request.ReconstructionRequest` and
:data:`.request.METHODS`, :class:`.results.ReconstructionResult` / :class:`.results.ViewRecord` /
:class:`.results.Progress`, :class:`.settings.NBVSettings`, :class:`.station3d.NBVStation` and
:func:`.station3d.load_nbv_config`, the protocols of :mod:`.interfaces`, :func:`.policies.registry.make_policy`.

Modules (imported on demand; this file stays light):

- :mod:`.settings` config/nbv.yaml read once into typed, validated settings;
- :mod:`.request` the request of one reconstruction; :mod:`.results` its view records, result and progress;
- :mod:`.reconstruction` the loop and its collaborators' assembly; :mod:`.stopping` the gain-based stopping rule;
  :mod:`.novelty` the surface a frame added; :mod:`.outputs` the files of a run;
- :mod:`.policies` the view-selection policies over a narrow context, chosen by name; :mod:`.tour` the tour
  planner's pieces (partial set cover, open tour over views x IK branches, the sticky plan);
- :mod:`.voxel_map` the log-odds voxel map (OctoMap sensor model), its labels, growth voxels, candidates, occlusion
  plane, predicted surface and exports, with :mod:`.map_parts` (raw points, static surface samples),
  :mod:`.pooling` (coarse copies) and :mod:`.raycast3d` (its numba kernels);
- :mod:`.gains` the seven volumetric information gains and the report's, PhoXi-aware, and the utilities (their names
  in :mod:`.gain_names`, light to import); :mod:`.sampling` the seen surface sampled too sparsely and the fused
  points' open borders (ours' ``undersampled_surface`` term);
- :mod:`.meshing` projective TSDF and marching cubes;
- :mod:`.interfaces` the robot and camera the loop needs (implemented by the simulation and by
  ``agiprobot_measurement.ros.nbv_interfaces`` on the station);
- :mod:`.station3d` what the loop may know of the station (no part) and ``config/nbv.yaml``;
- :mod:`.candidates` frontier-driven and view-sphere candidates and their filter chain;
- :mod:`.errors` the map's write error.

Motion between views is routed by :class:`agiprobot_measurement.motion.routing.Router`.
"""
