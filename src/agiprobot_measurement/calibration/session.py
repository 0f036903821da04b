"""One calibration session of the flange method, ROS-free: the state behind ``nodes/calibration``.

Holds the flag points, the samples (flange centre in the robot base frame and in the camera frame, metres), the
acceptance criteria measured on the flag points, the rejected frames with their reasons, and writes the data file
after every change (atomic rewrite, so an interrupted session keeps every sample taken so far).
"""

from __future__ import annotations

import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from agiprobot_measurement.calibration.flange_detection import FlangeDetection, FlangeDetectorConfig
from agiprobot_measurement.calibration.registration import (
    CalibrationData,
    CalibrationError,
    CalibrationResult,
    Sample,
    calibrate_data,
    check_flag_points,
    read_data_file,
    select_consistent_flags,
    write_data_file,
    zigzag_path,
)
from agiprobot_measurement.common.geometry import transform_points
from agiprobot_measurement.common.limits import excerpt

__all__ = [
    "MODES",
    "CalibrationSession",
    "check_zigzag",
    "detector_config",
    "sample_index",
    "zigzag_for",
]

MODES = ("cal_fine", "cal_coarse", "test")


def sample_index() -> str:
    """Timestamp index of the original data file: ``<seconds>_<microseconds>`` (unique within a session)."""
    now = time.time()
    return f"{int(now)}_{int((now % 1) * 1e6):06d}"


@dataclass
class CalibrationSession:
    """Flag points, samples and criteria of one calibration; the data file is rewritten after every change."""

    data_file: Path | None = None
    ransac: dict = field(default_factory=dict)
    plane_fraction: float = 0.75
    circle_fraction: float = 0.5
    flag_tolerance_m: float = 0.005
    data: CalibrationData = field(default_factory=CalibrationData)
    rejections: list[tuple[str, str]] = field(default_factory=list)  # (what, reason)
    _counter: int = 0

    @classmethod
    def from_config(cls, config: dict, data_file: str | Path | None) -> CalibrationSession:
        acc = config.get("acceptance", {}) or {}
        ransac = dict(config.get("ransac", {}) or {})
        return cls(
            data_file=Path(data_file) if data_file else None,
            ransac=ransac,
            plane_fraction=float(acc.get("plane_fraction", 0.75)),
            circle_fraction=float(acc.get("circle_fraction", 0.5)),
            flag_tolerance_m=float(acc.get("flag_tolerance_m", 0.005)),
        )

    # ------------------------------------------------------------------------------------------ samples
    def _index(self) -> str:
        self._counter += 1
        return f"{sample_index()}_{self._counter:04d}"

    def save(self, path: str | Path | None = None) -> Path | None:
        target = Path(path) if path else self.data_file
        if target is None:
            return None
        return write_data_file(target, self.data)

    def load(self, path: str | Path | None = None) -> int:
        """Replace the samples by a data file's; returns their number."""
        source = Path(path) if path else self.data_file
        if source is None:
            raise CalibrationError("no data file given")
        self.data = read_data_file(source)
        return len(self.data.samples)

    def clear(self) -> None:
        self.data = CalibrationData()
        self.rejections = []
        self.save()

    def add_flags(self, p_robot_m: np.ndarray, candidates: list[list[FlangeDetection]]) -> list[Sample]:
        """The flag samples from the detections at every flag point (several candidates each): the combination
        whose distances agree with the robot's (:func:`select_consistent_flags`); sets the criteria."""
        robot = check_flag_points(p_robot_m)
        choice = select_consistent_flags(
            robot, [[d.centre_m for d in found] for found in candidates], self.flag_tolerance_m
        )
        chosen = [candidates[i][k] for i, k in enumerate(choice)]
        self.data.samples = [s for s in self.data.samples if not s.flag]
        added = [Sample(self._index(), robot[i], det.centre_m, True) for i, det in enumerate(chosen)]
        self.data.samples[:0] = added
        self.data.criteria_plane = min(d.plane_points for d in chosen)
        self.data.criteria_line = min(d.circle_inliers for d in chosen)
        self.save()
        return added

    def judge(self, detection: FlangeDetection) -> str:
        """ "" when the detection passes the acceptance criteria, else the reason."""
        if not detection.ok:
            return detection.reason
        if self.data.criteria_plane and detection.plane_points < self.plane_fraction * self.data.criteria_plane:
            return (
                f"{detection.plane_points} points on the flange plane < {self.plane_fraction} x "
                f"{self.data.criteria_plane} (flag points)"
            )
        if self.data.criteria_line and detection.circle_inliers < self.circle_fraction * self.data.criteria_line:
            return (
                f"{detection.circle_inliers} circle inliers < {self.circle_fraction} x {self.data.criteria_line} "
                "(flag points)"
            )
        return ""

    def _save_samples(self, samples: list[Sample]) -> None:
        """Make ``samples`` the session's samples only when the data file took them: when writing fails the
        samples are left as they were and the error is raised (either changed and saved, or neither)."""
        previous = self.data.samples
        self.data.samples = samples
        try:
            self.save()
        except BaseException:
            self.data.samples = previous
            raise

    def add_sample(self, p_robot_m: np.ndarray, detection: FlangeDetection, what: str = "sample") -> tuple[bool, str]:
        """Judge a detection; accepted ones become a sample (data file rewritten; not added when that fails),
        rejected ones are recorded."""
        reason = self.judge(detection)
        if reason:
            self.rejections.append((what, reason))
            return False, reason
        sample = Sample(self._index(), np.asarray(p_robot_m, dtype=float), detection.centre_m)
        self._save_samples([*self.data.samples, sample])
        return True, sample.index

    def remove(self, index: str) -> Sample:
        """Remove a sample by index ("" or "last": the last one). The data file is rewritten first: when that
        fails, the error is raised and the sample stays."""
        if not self.data.samples:
            raise CalibrationError("no samples")
        if index in ("", "last"):
            removed = self.data.samples[-1]
        else:
            matches = [s for s in self.data.samples if s.index == index]
            if not matches:
                raise CalibrationError(f"no sample with index {excerpt(index)}")
            removed = matches[0]
        self._save_samples([s for s in self.data.samples if s is not removed])
        return removed

    def listing(self) -> str:
        lines = [
            f"{s.index} {'flag' if s.flag else 'path'} robot {np.round(s.p_robot_m, 4).tolist()} "
            f"camera {np.round(s.p_camera_m, 4).tolist()}"
            for s in self.data.samples
        ]
        lines += [f"rejected {what}: {reason}" for what, reason in self.rejections]
        return "\n".join(lines) or "no samples"

    # -------------------------------------------------------------------------------------- calibration
    def compute(self, mode: str) -> CalibrationResult:
        options = {k: self.ransac[k] for k in ("threshold_m", "min_threshold_m", "det_threshold", "max_draws")}
        options = {k: v for k, v in options.items() if v is not None}
        result = calibrate_data(self.data, mode, **options)
        if mode == "cal_coarse":
            self.data.h_coarse = result.transform
            self.save()
        return result

    def expected_camera_point(self, p_robot_m: np.ndarray) -> np.ndarray:
        """Where the coarse calibration expects the flange centre in the camera frame (metres)."""
        if self.data.h_coarse is None:
            raise CalibrationError("no coarse calibration yet")
        return transform_points(np.linalg.inv(self.data.h_coarse), np.asarray(p_robot_m, dtype=float)[None])[0]


#: most fractions per flag point pair of the zig-zag path, most jitter (metres)
MAX_ZIGZAG_FRACTIONS = 100
MAX_ZIGZAG_JITTER_M = 1.0
_ZIGZAG_KEYS = ("fractions", "jitter_m", "seed")


def _finite(value, where: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise CalibrationError(f"{where} must be a finite number, got {excerpt(value)}")
    return float(value)


def check_zigzag(zigzag, where: str = "zigzag") -> dict:
    """The zig-zag settings (``fractions``, ``jitter_m``, ``seed``; missing ones take their defaults) checked, so
    that a bad value is refused before the robot moves: a :class:`CalibrationError` naming the key otherwise.
    ``fractions``: 1 to 100 numbers in [0, 1]; ``jitter_m``: 0 to 1 m; ``seed``: a non-negative integer or null."""
    if zigzag is None:
        zigzag = {}
    if not isinstance(zigzag, Mapping):
        raise CalibrationError(f"{where} must be a mapping of {', '.join(_ZIGZAG_KEYS)}, got {excerpt(zigzag)}")
    unknown = [str(k) for k in zigzag if k not in _ZIGZAG_KEYS]
    if unknown:
        raise CalibrationError(f"{where}: unknown key {excerpt(unknown[0])}; the keys are {', '.join(_ZIGZAG_KEYS)}")
    fractions = zigzag.get("fractions", (0.25, 0.5, 0.75))
    if isinstance(fractions, str | bytes) or not isinstance(fractions, list | tuple):
        raise CalibrationError(f"{where}.fractions must be a list of numbers in [0, 1], got {excerpt(fractions)}")
    if not 1 <= len(fractions) <= MAX_ZIGZAG_FRACTIONS:
        raise CalibrationError(f"{where}.fractions needs 1 to {MAX_ZIGZAG_FRACTIONS} values, got {len(fractions)}")
    checked = tuple(_finite(f, f"{where}.fractions[{k}]") for k, f in enumerate(fractions))
    for k, f in enumerate(checked):
        if not 0.0 <= f <= 1.0:
            raise CalibrationError(f"{where}.fractions[{k}] must be in [0, 1] (of a flag point pair), got {f}")
    jitter_m = _finite(zigzag.get("jitter_m", 0.03), f"{where}.jitter_m")
    if not 0.0 <= jitter_m <= MAX_ZIGZAG_JITTER_M:
        raise CalibrationError(f"{where}.jitter_m must be in [0, {MAX_ZIGZAG_JITTER_M}] m, got {jitter_m}")
    seed = zigzag.get("seed", 0)
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
        raise CalibrationError(f"{where}.seed must be a non-negative integer or null, got {excerpt(seed)}")
    return {"fractions": checked, "jitter_m": jitter_m, "seed": seed}


def zigzag_for(flag_points_m: np.ndarray, config: dict) -> np.ndarray:
    """The zig-zag path of ``config['zigzag']`` (checked by :func:`check_zigzag`) between the flag points."""
    zz = check_zigzag(config.get("zigzag"))
    return zigzag_path(flag_points_m, seed=zz["seed"], jitter_m=zz["jitter_m"], fractions=zz["fractions"])


def detector_config(config: dict) -> FlangeDetectorConfig:
    flange = config.get("flange", {}) or {}
    detector = FlangeDetectorConfig()
    for key in ("radius_m", "crop_radius_m", "circle_band_m", "max_offset_m", "max_candidates"):
        if key in flange:
            setattr(detector, key, type(getattr(detector, key))(flange[key]))
    return detector
