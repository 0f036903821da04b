"""Motion benchmarks. ``python -m benchmarks.motion`` runs the motion core benchmark.

Module index: ``core`` (closed-form and KDL IK, collision checks, RRTConnect, Cartesian lines; the set ``make bench``
runs), ``collision`` (collision checks per second and joint-space planning between random valid states).
"""
