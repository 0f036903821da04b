"""The lab: benchmarks of the package's methods, outside the installed product."""
