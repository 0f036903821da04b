"""``python -m benchmarks.planning``: the pipeline benchmark (``benchmarks.planning.pipeline``)."""

import os
import sys

from benchmarks.planning.pipeline import main

code = main()
sys.stdout.flush()
sys.stderr.flush()
# The OMPL bindings (nanobind) report 'leaked instances' at interpreter shutdown: noise after the table.
os._exit(code)
