"""``python -m benchmarks.nbv3d``: the 3D NBV loop benchmark (``benchmarks.nbv3d.loop``)."""

from benchmarks.nbv3d.loop import main

raise SystemExit(main())
