"""Inspection benchmark: simulated parts with analytic truth (null, dent, hole, warp, scale) scanned and inspected,
seeds x magnitudes, against the targets; and the speed of a 1 M-point inspection against a 100 k-face model."""
