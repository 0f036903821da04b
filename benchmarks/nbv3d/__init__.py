"""3D next-best-view benchmarks. ``python -m benchmarks.nbv3d`` runs the loop benchmark.

Module index: ``loop`` (every method on the simulated station against the observable ground truth: coverage curves,
views, joint path, planning time, Chamfer distance, the gain-quality study, merging result files), ``map`` (speed of
the voxel map, gains and TSDF on simulated PhoXi frames).
"""
