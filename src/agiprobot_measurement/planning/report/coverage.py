"""Measured coverage of a plan and the colours of sample points that carry coverage to rviz and bags.

The trajectory_manager node colours the sample points it publishes (``~surface_points``) by predicted
uncertainty, with red for points no viewpoint can measure; ``ros/bag_coverage`` reads the red back as 'not
coverable'. Both use the constants here. After execution, :func:`measured_coverage` compares the points the
scanner measured with the samples. Points are mm.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agiprobot_measurement.sensors.laser_line.simulator import measured_samples

__all__ = [
    "HIGH_UNCERTAINTY_RGB",
    "LOW_UNCERTAINTY_RGB",
    "MEASURED_RGB",
    "MISSED_RGB",
    "NOT_PLANNED_RGB",
    "UNCOVERABLE_RGB",
    "MeasuredCoverage",
    "is_uncoverable_color",
    "measured_colors",
    "measured_coverage",
    "uncertainty_colors",
]

#: a point no viewpoint can measure (RGB in [0, 1])
UNCOVERABLE_RGB = (0.9, 0.1, 0.1)
#: a point some viewpoint could measure but the plan does not
NOT_PLANNED_RGB = (1.0, 0.55, 0.0)
#: the ends of the planned points' scale, lowest and highest predicted uncertainty
LOW_UNCERTAINTY_RGB = (0.0, 0.85, 0.2)
HIGH_UNCERTAINTY_RGB = (0.0, 0.0, 1.0)
#: after execution: measured and missed sample points
MEASURED_RGB = (0.1, 0.85, 0.2)
MISSED_RGB = UNCOVERABLE_RGB


def uncertainty_colors(u: np.ndarray, u_min: float, u_max: float, coverable: np.ndarray | None = None) -> np.ndarray:
    """Colours of sample points, (N, 3) in [0, 1]: green (low) to blue (high predicted uncertainty ``u``, mm)
    for the points the plan measures, red for points no viewpoint can measure, orange for points some
    viewpoint could measure (``coverable``) but the plan does not."""
    colors = np.zeros((len(u), 3))
    finite = np.isfinite(u)
    colors[~finite] = UNCOVERABLE_RGB
    if coverable is not None:
        colors[~finite & coverable] = NOT_PLANNED_RGB
    share = np.clip((u[finite] - u_min) / max(u_max - u_min, 1e-12), 0.0, 1.0)
    low, high = np.asarray(LOW_UNCERTAINTY_RGB), np.asarray(HIGH_UNCERTAINTY_RGB)
    colors[finite] = low + share[:, None] * (high - low)
    return colors


def is_uncoverable_color(rgb_uint8: np.ndarray) -> np.ndarray:
    """Which (N, 3) uint8 colours are :data:`UNCOVERABLE_RGB` (tolerant of the float -> byte rounding)."""
    rgb = np.asarray(rgb_uint8)
    return (rgb[:, 0] > 200) & (rgb[:, 1] < 60)


@dataclass
class MeasuredCoverage:
    """What an execution measured. Coverages are shares of the coverable sample points (0 if none is)."""

    measured: np.ndarray  # (N,) bool: the sample has a measured point within the radius
    predicted_coverage: float
    measured_coverage: float


def measured_coverage(
    samples_mm: np.ndarray,
    measured_points_mm: np.ndarray,
    radius_mm: float,
    coverable: np.ndarray,
    predicted: np.ndarray,
) -> MeasuredCoverage:
    """Measured against predicted coverage: a sample counts as measured when a measured point lies within
    ``radius_mm``; ``coverable`` and ``predicted`` are (N,) masks of the samples."""
    measured = measured_samples(samples_mm, measured_points_mm, radius_mm)
    coverable = np.asarray(coverable, dtype=bool)
    if coverable.any():
        predicted_share = float(np.asarray(predicted)[coverable].mean())
        measured_share = float(measured[coverable].mean())
    else:
        predicted_share = measured_share = 0.0
    return MeasuredCoverage(measured, predicted_share, measured_share)


def measured_colors(measured: np.ndarray) -> np.ndarray:
    """(N, 3) colours of the samples after execution: green measured, red missed."""
    return np.where(np.asarray(measured)[:, None], [MEASURED_RGB], [MISSED_RGB])
