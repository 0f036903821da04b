"""The project's benchmarks: speed, accuracy and coverage figures of every domain, outside the installed package.

Run from the checkout's root, e.g. ``python -m benchmarks.planning`` (see benchmarks/README.md). Every module shares
:mod:`benchmarks.harness`; the default parameter sets and targets are the YAML files of ``benchmarks/conditions/``.

Module index: ``harness`` (process runner, peak memory, timing, JSON and tables, options, targets, conditions),
``planning`` (pipeline, parts, scale, set_cover, metrology), ``motion`` (core, collision), ``nbv3d`` (loop, map),
``nbv2d``, ``mild``, ``calibration``, ``phoxi``, ``reliability`` (the hostile-input replay of ``make fuzz``).
"""

import sys
from pathlib import Path

#: the checkout's root (package.xml, parts/, src/)
ROOT = Path(__file__).resolve().parents[1]

# The import bootstrap, once for every benchmark: a checkout without the catkin environment finds the package in src/.
try:
    import agiprobot_measurement  # noqa: F401
except ImportError:
    sys.path.insert(0, str(ROOT / "src"))
