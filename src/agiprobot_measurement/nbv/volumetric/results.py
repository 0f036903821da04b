"""What a 3D reconstruction reports: one record per view, the result, and the progress of a running loop."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["TERMINATION_REASONS", "Progress", "ReconstructionResult", "ViewRecord"]

TERMINATION_REASONS = (
    "gain_below_threshold",
    "frontier_exhausted",
    "max_views",
    "max_time",
    "max_path",
    "cancelled",
    "nothing_found",
    "error",
    "plan_only",  # execute=False: the result carries the next best view, nothing moved
)


@dataclass
class ViewRecord:
    index: int
    camera_pose: np.ndarray  # world <- sensor at capture
    joints: np.ndarray  # rad
    gain: float = 0.0  # of the chosen view, predicted before moving there (0 for the opening view)
    utility: float = 0.0
    candidates_total: int = 0
    candidates_feasible: int = 0
    rejections: dict = field(default_factory=dict)
    planning_s: float = 0.0  # candidates + gains + motion planning before this view
    motion_s: float = 0.0  # duration of the trajectory that brought the robot here
    joint_path_rad: float = 0.0  # sum |dq| of that trajectory
    observed_area_m2: float = 0.0  # after fusing this view
    coverage: float | None = None  # of the observable ground truth after this view (simulation)
    expected_new_area_m2: float = 0.0
    new_area_m2: float = 0.0  # realised: observed surface (output map) added by this view
    source: str = ""
    points: int = 0
    capture_s: float = 0.0
    integrate_s: float = 0.0

    def as_dict(self) -> dict:
        return {
            "index": int(self.index),
            "source": self.source,
            "camera_pose": np.round(self.camera_pose, 6).tolist(),
            "joints_rad": np.round(self.joints, 6).tolist(),
            "gain": float(self.gain),
            "utility": float(self.utility),
            "expected_new_area_m2": float(self.expected_new_area_m2),
            "new_area_m2": float(self.new_area_m2),
            "candidates_total": int(self.candidates_total),
            "candidates_feasible": int(self.candidates_feasible),
            "rejections": {str(k): int(v) for k, v in self.rejections.items()},
            "planning_s": round(float(self.planning_s), 4),
            "motion_s": round(float(self.motion_s), 4),
            "joint_path_rad": round(float(self.joint_path_rad), 5),
            "observed_area_m2": float(self.observed_area_m2),
            "coverage": None if self.coverage is None else float(self.coverage),
            "points": int(self.points),
            "capture_s": round(float(self.capture_s), 4),
            "integrate_s": round(float(self.integrate_s), 4),
        }


@dataclass
class ReconstructionResult:
    termination_reason: str
    views: list = field(default_factory=list)
    joint_path_rad: float = 0.0
    tcp_path_m: float = 0.0
    planning_time_s: float = 0.0
    execution_time_s: float = 0.0
    observed_surface_area_m2: float = 0.0
    remaining_frontier_area_m2: float = 0.0
    coverage: float | None = None
    cloud_file: str = ""
    mesh_file: str = ""
    map_file: str = ""
    log_file: str = ""
    error: str = ""
    outputs_error: str = ""  # the outputs could not be written (a full disk): the run failed
    motion_failures: int = 0
    wall_time_s: float = 0.0
    next_view_pose: np.ndarray | None = None  # plan-only: the next best view (world <- sensor)
    next_view_joints: np.ndarray | None = None
    next_view_gain: float = 0.0

    def summary(self) -> dict:
        return {
            "termination_reason": self.termination_reason,
            "error": self.error,
            "outputs_error": self.outputs_error,
            "views": len(self.views),
            "joint_path_rad": float(self.joint_path_rad),
            "tcp_path_m": float(self.tcp_path_m),
            "planning_time_s": float(self.planning_time_s),
            "execution_time_s": float(self.execution_time_s),
            "wall_time_s": float(self.wall_time_s),
            "observed_surface_area_m2": float(self.observed_surface_area_m2),
            "remaining_frontier_area_m2": float(self.remaining_frontier_area_m2),
            "coverage": None if self.coverage is None else float(self.coverage),
            "motion_failures": int(self.motion_failures),
            "cloud_file": self.cloud_file,
            "mesh_file": self.mesh_file,
            "map_file": self.map_file,
            "log_file": self.log_file,
        }


@dataclass
class Progress:
    view: int
    phase: str  # search|capture|integrate|candidates|evaluate|plan_motion|move|finish
    best_gain: float = 0.0
    relative_gain: float = 0.0
    candidates_total: int = 0
    candidates_feasible: int = 0
    observed_area_m2: float = 0.0
    coverage: float | None = None
    progress: float = 0.0
    next_view_pose: np.ndarray | None = None
