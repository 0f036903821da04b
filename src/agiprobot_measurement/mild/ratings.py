"""The exact IK's heuristics: how well a base pose suits a move from the current one, in (0, 1].

Every heuristic rates a total turn of a radians as ``RATING_BASE ** a`` (SIMPLE: the base rotation's change;
ANGLE_APPROXIMATION: onto the straight line and off it again; NAVIGATION_PATH: every heading change along the
planned path, 0 without a path).
"""

from __future__ import annotations

import numpy as np

from agiprobot_measurement.common.geometry import wrap_to_pi

__all__ = [
    "RATING_BASE",
    "path_heading_change",
    "rating_angle_approximation",
    "rating_angle_approximation_offsets",
    "rating_navigation_path",
    "rating_simple",
]

RATING_BASE = 0.6  # every heuristic rates a total turn of a radians as 0.6 ** a, in (0, 1]


def rating_simple(source_rotation_rad, target_rotation_rad):
    """SIMPLE: 0.6 ** |rotation change| (shortest way round, 0 .. pi)."""
    return RATING_BASE ** np.abs(wrap_to_pi(np.asarray(target_rotation_rad) - source_rotation_rad))


def rating_angle_approximation(source_xy_m, target_xy_m, source_rotation_rad, target_rotation_rad):
    """ANGLE_APPROXIMATION: 0.6 ** (turn onto the straight line from source to target + turn from it to the target
    heading); a turn in place (positions closer than 1 um) is rated by the turn itself."""
    delta = np.asarray(target_xy_m, dtype=float) - np.asarray(source_xy_m, dtype=float)
    return rating_angle_approximation_offsets(delta[..., 0], delta[..., 1], source_rotation_rad, target_rotation_rad)


def rating_angle_approximation_offsets(dx_m, dy_m, source_rotation_rad, target_rotation_rad):
    """ANGLE_APPROXIMATION from the offsets (m) of the targets from the source, without building position arrays."""
    line = np.arctan2(dy_m, dx_m)
    via_line = np.abs(wrap_to_pi(source_rotation_rad - line)) + np.abs(wrap_to_pi(target_rotation_rad - line))
    in_place = np.abs(wrap_to_pi(np.asarray(target_rotation_rad) - source_rotation_rad))
    moving = np.hypot(dx_m, dy_m) > 1e-6
    return RATING_BASE ** np.where(moving, via_line, in_place)


def path_heading_change(path_xy_m: np.ndarray, source_rotation_rad: float, target_rotation_rad: float) -> float:
    """Total absolute heading change (rad) driving along a polyline: onto its first segment, at every corner, and
    from its last segment to the target heading."""
    segments = np.diff(np.asarray(path_xy_m, dtype=float).reshape(-1, 2), axis=0)
    segments = segments[np.hypot(segments[:, 0], segments[:, 1]) > 1e-9]
    if len(segments) == 0:
        return float(abs(wrap_to_pi(target_rotation_rad - source_rotation_rad)))
    headings = np.arctan2(segments[:, 1], segments[:, 0])
    return float(
        abs(wrap_to_pi(headings[0] - source_rotation_rad))
        + np.abs(wrap_to_pi(np.diff(headings))).sum()
        + abs(wrap_to_pi(target_rotation_rad - headings[-1]))
    )


def rating_navigation_path(path_xy_m: np.ndarray | None, source_rotation_rad: float, target_rotation_rad: float):
    """NAVIGATION_PATH: 0.6 ** (sum of heading changes along the planned path); 0 when there is no path."""
    if path_xy_m is None:
        return 0.0
    return RATING_BASE ** path_heading_change(path_xy_m, source_rotation_rad, target_rotation_rad)
