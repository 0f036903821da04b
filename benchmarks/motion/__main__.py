"""``python -m benchmarks.motion``: the motion core benchmark (``benchmarks.motion.core``)."""

from benchmarks.motion.core import main

raise SystemExit(main())
