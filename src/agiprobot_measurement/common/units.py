"""Length units accepted in files and requests, as scales to metres."""

__all__ = [
    "MM_TO_M",
    "M_TO_MM",
    "UNIT_SCALES_TO_M",
]

UNIT_SCALES_TO_M = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001, "inch": 0.0254, "in": 0.0254, "ft": 0.3048}

M_TO_MM = 1000.0
MM_TO_M = 0.001
