"""Kinematic model of the MILD mobile robot (asr_robot_model_services' algorithms), ROS-free.

The MILD: a planar base (x, y in metres, rotation in radians about the map's z) carrying a pan-tilt unit (PTU: pan
about a vertical axis, tilt about a horizontal axis, positive tilt raises the view) with a stereo camera pair. A
robot state is (pan, tilt, rotation, x, y) in that order (RobotStateMessage's field order); a camera pose is the pose
of the camera mount frame in the map frame, the camera looking along its +x axis. The view centre of a camera pose is
``position + view * (ncp + fcp) / 2``.

What is here (the reference's section asr_robot_model_services, see ../shared/reference/interfaces.md):

- forward kinematics: :meth:`MildRobotModel.frame_poses`, :meth:`MildRobotModel.camera_poses` (vectorised);
- inverse kinematics with base movement, exact geometric (``robotModelId: 1``, :meth:`MildRobotModel.exact_ik_batch`):
  closed-form tilt from the tilt axis' constant height and the camera offset so that the camera faces the requested
  view centre from the viewing distance with the least angle deviation (the view azimuth is matched exactly; the
  elevation is whatever the heights force), then the pan sampled over its limits, refined by halving the window
  around the best sample until the ratings change by less than ``inverseKinematicIterationAccuracy``, each sample
  rated by a heuristic on the base pose it implies (SIMPLE, ANGLE_APPROXIMATION, NAVIGATION_PATH; 0 where the map
  does not allow the base); no solution when the view centre is too far above or below the camera's reach;
- approximated inverse kinematics (``robotModelId: 2``, :meth:`MildRobotModel.approximated_ik`): the original's linear
  programme splitting the remaining azimuth turn between pan and base rotation at least weighted cost
  (:func:`solve_turn_lp`: GLPK through swiglpk as the original, HiGHS, or its closed form); tilt = elevation of the
  view axis, base (x, y) = the requested camera position;
- PTU-only pose correction (:meth:`MildRobotModel.camera_pose_correction`): closed-form pan and tilt that aim the
  camera's view axis through the requested view centre without moving the base, clamped to the limits;
- movement costs with the omega weights and sigma; GetDistance and IsPositionAllowed on an
  :class:`~agiprobot_measurement.mild.occupancy_map.OccupancyMap`.

Deliberate differences from the original, each because the original's behaviour was a defect: CalculateCameraPose
is implemented (it returned zeros); the approximated IK clamps the tilt to its limits and splits the turn from the
clamped current pan (so pan + rotation always equals the requested azimuth); ANGLE_APPROXIMATION rates a turn in
place (same position) as the turn itself instead of against a heading of 0; pan samples include the window's ends
and the refinement also continues while the window's samples still differ by more than the accuracy (the original
stopped when two samples straddling the optimum rated alike).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from agiprobot_measurement.common.config import vector
from agiprobot_measurement.common.geometry import wrap_to_pi
from agiprobot_measurement.mild.occupancy_map import OccupancyMap, polyline_length
from agiprobot_measurement.station import CONFIG_DIR, ConfigError, read_yaml

__all__ = [
    "FRAME_KEYS",
    "LP_SOLVERS",
    "RATING_BASE",
    "RATING_NAMES",
    "TWO_PI",
    "FrameNames",
    "IKBatch",
    "IKSolution",
    "MildKinematics",
    "MildRobotModel",
    "MovementCosts",
    "PoseCorrection",
    "RobotModelSettings",
    "RobotState",
    "angle_between",
    "check_pose",
    "load_frame_names",
    "load_kinematics",
    "load_map",
    "load_settings",
    "path_heading_change",
    "rating_angle_approximation",
    "rating_navigation_path",
    "rating_simple",
    "settings_from_mapping",
    "solve_turn_lp",
    "turn_split_closed_form",
    "view_directions",
    "wrap_to_2pi",
]

TWO_PI = 2.0 * math.pi
RATING_BASE = 0.6  # every heuristic rates a total turn of a radians as 0.6 ** a, in (0, 1]
RATING_NAMES = ("SIMPLE", "ANGLE_APPROXIMATION", "NAVIGATION_PATH")
LP_SOLVERS = ("glpk", "highs", "closed_form")
EXACT_IK, APPROXIMATED_IK = 1, 2


# --------------------------------------------------------------------------------------------------- angles


def wrap_to_2pi(angle_rad):
    """Angles mapped to [0, 2 pi) (the original's convention for the base rotation)."""
    return np.asarray(angle_rad) % TWO_PI


def view_directions(q_xyzw: np.ndarray) -> np.ndarray:
    """The +x axes (..., 3) of orientations (..., 4): where a camera with that orientation looks."""
    x, y, z, w = np.moveaxis(np.asarray(q_xyzw, dtype=float), -1, 0)
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y + w * z), 2 * (x * z - w * y)], -1)


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles (rad) between unit vectors (..., 3); atan2 keeps them accurate near 0 where arccos is not."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def check_pose(position, orientation_xyzw, what: str = "pose") -> tuple[np.ndarray, np.ndarray]:
    """A finite position and a normalised quaternion, or ValueError saying what is wrong."""
    p = np.asarray(position, dtype=float).reshape(-1)
    q = np.asarray(orientation_xyzw, dtype=float).reshape(-1)
    if p.shape != (3,) or q.shape != (4,):
        raise ValueError(f"{what}: expected a position (x, y, z) and a quaternion (x, y, z, w)")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{what}: position {p.tolist()} is not finite")
    if not np.all(np.isfinite(q)):
        raise ValueError(f"{what}: orientation {q.tolist()} is not finite")
    norm = float(np.linalg.norm(q))
    if norm < 1e-9:
        raise ValueError(
            f"{what}: orientation {q.tolist()} is a zero quaternion; expected a unit quaternion (x, y, z, w)"
        )
    return p, q / norm


# --------------------------------------------------------------------------------------------------- robot state
@dataclass(frozen=True)
class RobotState:
    """A MILD configuration: pan and tilt of the PTU (rad), base rotation (rad) and base position x, y (m, map)."""

    pan: float = 0.0
    tilt: float = 0.0
    rotation: float = 0.0
    x: float = 0.0
    y: float = 0.0

    def as_array(self) -> np.ndarray:
        return np.array([self.pan, self.tilt, self.rotation, self.x, self.y])

    @classmethod
    def from_array(cls, values) -> RobotState:
        v = np.asarray(values, dtype=float).reshape(5)
        return cls(*(float(a) for a in v))

    def checked(self, what: str = "robot state") -> RobotState:
        for name in ("pan", "tilt", "rotation", "x", "y"):
            if not math.isfinite(getattr(self, name)):
                raise ValueError(f"{what}: {name} = {getattr(self, name)} is not finite")
        return self


# --------------------------------------------------------------------------------------------------- configuration
FRAME_KEYS = (
    "map_frame",
    "base_frame",
    "ptu_base_frame",
    "ptu_pan_frame",
    "ptu_pan_frame_rotated",
    "ptu_tilt_frame",
    "ptu_tilt_frame_rotated",
    "camera_mount_frame",
    "camera_left_frame",
    "camera_right_frame",
)


@dataclass(frozen=True)
class FrameNames:
    """The chain's tf frame names, keyed by the original's parameter names (robot_model_frames.yaml)."""

    map_frame: str = "map"
    base_frame: str = "base_link"
    ptu_base_frame: str = "ptu_base_link"
    ptu_pan_frame: str = "ptu_pan_link"
    ptu_pan_frame_rotated: str = "ptu_pan_link_rotated"
    ptu_tilt_frame: str = "ptu_tilt_link"
    ptu_tilt_frame_rotated: str = "ptu_tilted_link"
    camera_mount_frame: str = "ptu_mount_link"
    camera_left_frame: str = "camera_left_frame"
    camera_right_frame: str = "camera_right_frame"

    @classmethod
    def from_mapping(cls, mapping: object, where: str) -> FrameNames:
        if not isinstance(mapping, dict):
            raise ConfigError(f"{where}: expected a mapping of frame names")
        values = {}
        for key in FRAME_KEYS:
            if key not in mapping:
                raise ConfigError(f"{where}: missing key '{key}'")
            name = mapping[key]
            if not isinstance(name, str) or not name.strip("/"):
                raise ConfigError(f"{where}: '{key}' must be a frame name, got {name!r}")
            values[key] = name.strip("/")  # tf2 frame ids carry no leading slash (the original's had one)
        if len(set(values.values())) != len(values):
            raise ConfigError(f"{where}: frame names must be distinct")
        return cls(**values)


def load_frame_names(path: str | Path | None = None) -> FrameNames:
    path = Path(path) if path else CONFIG_DIR / "mild_robot_model_frames.yaml"
    return FrameNames.from_mapping(read_yaml(path), str(path))


@dataclass(frozen=True)
class MildKinematics:
    """The MILD's fixed offsets (m) between the frames of its chain; see config/mild_kinematics.yaml."""

    base_to_ptu_base_m: np.ndarray
    ptu_base_to_pan_m: np.ndarray
    pan_to_tilt_m: np.ndarray
    tilt_to_mount_m: np.ndarray
    camera_baseline_m: float
    pan_joint: str = "ptu_pan_joint"
    tilt_joint: str = "ptu_tilt_joint"
    frames: FrameNames = field(default_factory=FrameNames)
    # speed limits: pan and tilt (rad/s), base rotation (rad/s) and base translation (m/s)
    max_velocity: tuple[float, float, float, float] = (1.0, 1.0, 0.8, 0.5)

    @property
    def base_to_pan_m(self) -> np.ndarray:
        return self.base_to_ptu_base_m + self.ptu_base_to_pan_m

    @property
    def tilt_axis_height_m(self) -> float:
        """Height of the tilt axis above the floor: constant, whatever the base pose and pan (the IK relies on it)."""
        return float(self.base_to_pan_m[2] + self.pan_to_tilt_m[2])


def load_kinematics(path: str | Path | None = None, frames: FrameNames | str | Path | None = None) -> MildKinematics:
    path = Path(path) if path else CONFIG_DIR / "mild_kinematics.yaml"
    where = str(path)
    data = read_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping")

    def vec(key: str) -> np.ndarray:
        if key not in data:
            raise ConfigError(f"{where}: missing key '{key}'")
        return vector(data[key], 3, f"{where}: {key}")

    if "camera_baseline_m" not in data:
        raise ConfigError(f"{where}: missing key 'camera_baseline_m'")
    try:
        baseline = float(data["camera_baseline_m"])
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: camera_baseline_m must be a number") from exc
    if not (math.isfinite(baseline) and baseline >= 0):
        raise ConfigError(f"{where}: camera_baseline_m must be a non-negative number, got {baseline}")
    joints = data.get("joint_names", {}) or {}
    if not isinstance(joints, dict):
        raise ConfigError(f"{where}: joint_names must be a mapping with 'pan' and 'tilt'")
    if not isinstance(frames, FrameNames):
        frames = load_frame_names(frames)
    speeds = data.get("max_velocity", {}) or {}
    if not isinstance(speeds, dict):
        raise ConfigError(f"{where}: max_velocity must be a mapping")
    max_velocity = tuple(
        _number(speeds, key, f"{where}: max_velocity", default=default, strictly_positive=True)
        for key, default in (
            ("pan_rad_s", 1.0),
            ("tilt_rad_s", 1.0),
            ("base_angular_rad_s", 0.8),
            ("base_linear_m_s", 0.5),
        )
    )
    return MildKinematics(
        base_to_ptu_base_m=vec("base_to_ptu_base_xyz_m"),
        ptu_base_to_pan_m=vec("ptu_base_to_pan_xyz_m"),
        pan_to_tilt_m=vec("pan_to_tilt_xyz_m"),
        tilt_to_mount_m=vec("tilt_to_camera_mount_xyz_m"),
        camera_baseline_m=baseline,
        pan_joint=str(joints.get("pan", "ptu_pan_joint")),
        tilt_joint=str(joints.get("tilt", "ptu_tilt_joint")),
        frames=frames,
        max_velocity=max_velocity,
    )


@dataclass(frozen=True)
class RobotModelSettings:
    """asr_robot_model_services' parameters, converted to SI units (radians, metres); names as in the YAML files."""

    robot_model_id: int
    pan_limits_rad: tuple[float, float]
    tilt_limits_rad: tuple[float, float]
    sigma_m: float
    col_thresh: float
    omega_pan: float
    omega_tilt: float
    omega_rot: float
    omega_base: float
    tolerance_m: float
    use_global_planner: bool
    ncp_m: float
    fcp_m: float
    visualize_ik: bool
    ik_angle_rating: str
    pan_sampling_steps: int
    ik_iteration_accuracy: float
    pan_sampling_max_iterations: int = 6
    lp_solver: str = "glpk"
    fovx_rad: float = math.radians(30.0)
    fovy_rad: float = math.radians(20.0)
    inscribed_radius_m: float = 0.30
    inflation_radius_m: float = 0.60
    cost_scaling_per_m: float = 5.0
    ik_visualization_topic: str = "/asr_robot_model_services/IK_Visualization"
    warnings: tuple[str, ...] = ()

    @property
    def view_distance_m(self) -> float:
        """Distance from the camera to the view centre: the middle of the clipping planes."""
        return 0.5 * (self.ncp_m + self.fcp_m)

    def with_changes(self, **changes) -> RobotModelSettings:
        from dataclasses import replace

        return replace(self, **changes)


_REQUIRED = object()


def _number(mapping: dict, key: str, where: str, default=_REQUIRED, minimum=None, strictly_positive=False) -> float:
    if key not in mapping:
        if default is _REQUIRED:
            raise ConfigError(f"{where}: missing key '{key}'")
        return default
    value = mapping[key]
    if isinstance(value, bool):
        raise ConfigError(f"{where}: '{key}' must be a number, got {value!r}")
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: '{key}' must be a number, got {value!r}") from exc
    if not math.isfinite(number):
        raise ConfigError(f"{where}: '{key}' must be finite, got {value!r}")
    if strictly_positive and number <= 0:
        raise ConfigError(f"{where}: '{key}' must be positive, got {value!r}")
    if minimum is not None and number < minimum:
        raise ConfigError(f"{where}: '{key}' must be >= {minimum}, got {value!r}")
    return number


def _flag(mapping: dict, key: str, where: str, default=_REQUIRED) -> bool:
    if key not in mapping:
        if default is _REQUIRED:
            raise ConfigError(f"{where}: missing key '{key}'")
        return default
    value = mapping[key]
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.lower() in ("true", "false"):
        return value.lower() == "true"
    raise ConfigError(f"{where}: '{key}' must be true or false, got {value!r}")


def settings_from_mapping(mapping: object, where: str) -> RobotModelSettings:
    """Check and convert the parameters (a YAML file's or the node's private rosparams); errors name ``where``."""
    if not isinstance(mapping, dict):
        raise ConfigError(f"{where}: expected a mapping of parameters")
    warnings: list[str] = []
    model_id = mapping.get("robotModelId", _REQUIRED)
    if model_id is _REQUIRED:
        raise ConfigError(f"{where}: missing key 'robotModelId'")
    if isinstance(model_id, bool) or model_id not in (EXACT_IK, APPROXIMATED_IK):
        raise ConfigError(
            f"{where}: robotModelId {model_id!r} is not a valid robot model id "
            f"(1 = MILDRobotModelWithExactIK, 2 = MILDRobotModelWithApproximatedIK)"
        )
    limits = {key: _number(mapping, key, where) for key in ("panMin", "panMax", "tiltMin", "tiltMax")}
    for low, high in (("panMin", "panMax"), ("tiltMin", "tiltMax")):
        if limits[low] >= limits[high]:
            raise ConfigError(f"{where}: need {low} < {high} (degrees), got {limits[low]} and {limits[high]}")
    if limits["tiltMin"] <= -90 or limits["tiltMax"] >= 90:
        raise ConfigError(f"{where}: tilt limits must lie within (-90, 90) degrees")
    ncp = _number(mapping, "ncp", where, strictly_positive=True)
    fcp = _number(mapping, "fcp", where, strictly_positive=True)
    if ncp >= fcp:
        raise ConfigError(f"{where}: need ncp < fcp (metres), got {ncp} and {fcp}")
    rating = mapping.get("IKAngleRating", _REQUIRED)
    if rating is _REQUIRED:
        raise ConfigError(f"{where}: missing key 'IKAngleRating'")
    if rating not in RATING_NAMES:
        warnings.append(
            f"'{rating}' is not a valid IK rating algorithm (IKAngleRating: one of {', '.join(RATING_NAMES)}); "
            "using SIMPLE instead"
        )
        rating = "SIMPLE"
    steps = _number(mapping, "panAngleSamplingStepsPerIteration", where, minimum=2)
    iterations = _number(mapping, "panAngleSamplingMaxIterations", where, default=6, minimum=1)
    if steps != int(steps) or iterations != int(iterations):
        raise ConfigError(f"{where}: panAngleSamplingStepsPerIteration and panAngleSamplingMaxIterations are integers")
    solver = str(mapping.get("lpSolver", "glpk"))
    if solver not in LP_SOLVERS:
        raise ConfigError(f"{where}: lpSolver must be one of {', '.join(LP_SOLVERS)}, got {solver!r}")
    fovx = _number(mapping, "fovx_deg", where, default=30.0, strictly_positive=True)
    fovy = _number(mapping, "fovy_deg", where, default=20.0, strictly_positive=True)
    if fovx >= 180 or fovy >= 180:
        raise ConfigError(f"{where}: fovx_deg and fovy_deg must be below 180")
    col_thresh = _number(mapping, "colThresh", where, minimum=0)
    if col_thresh > 100:
        raise ConfigError(f"{where}: colThresh is an occupancy value in [0, 100], got {col_thresh}")
    inscribed = _number(mapping, "inscribedRadius_m", where, default=0.30, minimum=0)
    inflation = _number(mapping, "inflationRadius_m", where, default=0.60, minimum=0)
    if inscribed > inflation:
        raise ConfigError(f"{where}: need inscribedRadius_m <= inflationRadius_m, got {inscribed} and {inflation}")
    return RobotModelSettings(
        robot_model_id=int(model_id),
        pan_limits_rad=(math.radians(limits["panMin"]), math.radians(limits["panMax"])),
        tilt_limits_rad=(math.radians(limits["tiltMin"]), math.radians(limits["tiltMax"])),
        sigma_m=_number(mapping, "mSigma", where, strictly_positive=True),
        col_thresh=col_thresh,
        omega_pan=_number(mapping, "mOmegaPan", where, minimum=0),
        omega_tilt=_number(mapping, "mOmegaTilt", where, minimum=0),
        omega_rot=_number(mapping, "mOmegaRot", where, minimum=0),
        omega_base=_number(mapping, "mOmegaBase", where, minimum=0),
        tolerance_m=_number(mapping, "tolerance", where, minimum=0),
        use_global_planner=_flag(mapping, "useGlobalPlanner", where),
        ncp_m=ncp,
        fcp_m=fcp,
        visualize_ik=_flag(mapping, "visualizeIK", where),
        ik_angle_rating=str(rating),
        pan_sampling_steps=int(steps),
        ik_iteration_accuracy=_number(mapping, "inverseKinematicIterationAccuracy", where, strictly_positive=True),
        pan_sampling_max_iterations=int(iterations),
        lp_solver=solver,
        fovx_rad=math.radians(fovx),
        fovy_rad=math.radians(fovy),
        inscribed_radius_m=inscribed,
        inflation_radius_m=inflation,
        cost_scaling_per_m=_number(mapping, "costScalingFactor_per_m", where, default=5.0, minimum=0),
        ik_visualization_topic=str(mapping.get("IKVisualization", "/asr_robot_model_services/IK_Visualization")),
        warnings=tuple(warnings),
    )


def load_settings(path: str | Path | None = None) -> RobotModelSettings:
    """Settings file (default: config/mild_robot_model_services_real.yaml)."""
    path = Path(path) if path else CONFIG_DIR / "mild_robot_model_services_real.yaml"
    return settings_from_mapping(read_yaml(path), str(path))


def load_map(path: str | Path | None, settings: RobotModelSettings) -> OccupancyMap:
    """A map_server map inflated with the settings' radii (default: config/maps/mild_lab.yaml)."""
    path = Path(path) if path else CONFIG_DIR / "maps" / "mild_lab.yaml"
    return OccupancyMap.load(
        path, settings.inscribed_radius_m, settings.inflation_radius_m, settings.cost_scaling_per_m
    )


# --------------------------------------------------------------------------------------------------- linear programme
def turn_split_closed_form(alpha_rad, pan_up_rad, pan_down_rad, omega_pan: float, omega_rot: float):
    """Optimum of the approximated IK's LP, vectorised: (pan change, rotation change) in rad.

    The LP has one equality row (pan change + rotation change = alpha) and box bounds, so its optimum fills the
    cheaper variable first: the pan up to its limit when omega_pan <= omega_rot, else all of the turn by rotation
    (|alpha| <= pi fits the rotation's bound of pi).
    """
    alpha = np.asarray(alpha_rad, dtype=float)
    if omega_pan <= omega_rot:
        pan = np.clip(alpha, -np.asarray(pan_down_rad, dtype=float), np.asarray(pan_up_rad, dtype=float))
    else:
        pan = np.zeros_like(alpha)
    return pan, alpha - pan


def _solve_turn_lp_glpk(alpha: float, pan_up: float, pan_down: float, omega_pan: float, omega_rot: float):
    import swiglpk as glp

    lp = glp.glp_create_prob()
    try:
        glp.glp_set_obj_dir(lp, glp.GLP_MIN)
        glp.glp_add_cols(lp, 4)
        # x_pan+, x_pan-, x_rot+, x_rot-: all >= 0, pan bounded by the limits, rotation by pi each way
        for column, (upper, weight) in enumerate(
            ((pan_up, omega_pan), (pan_down, omega_pan), (math.pi, omega_rot), (math.pi, omega_rot)), start=1
        ):
            glp.glp_set_col_bnds(lp, column, glp.GLP_DB if upper > 0.0 else glp.GLP_FX, 0.0, max(upper, 0.0))
            glp.glp_set_obj_coef(lp, column, weight)
        glp.glp_add_rows(lp, 1)
        glp.glp_set_row_bnds(lp, 1, glp.GLP_FX, alpha, alpha)
        index, value = glp.intArray(5), glp.doubleArray(5)
        for column, coefficient in enumerate((1.0, -1.0, 1.0, -1.0), start=1):
            index[column], value[column] = column, coefficient
        glp.glp_set_mat_row(lp, 1, 4, index, value)
        parameters = glp.glp_smcp()
        glp.glp_init_smcp(parameters)
        parameters.msg_lev = glp.GLP_MSG_OFF
        glp.glp_simplex(lp, parameters)
        if glp.glp_get_status(lp) != glp.GLP_OPT:
            raise RuntimeError(f"GLPK found no optimal solution (status {glp.glp_get_status(lp)})")
        x = [glp.glp_get_col_prim(lp, column) for column in range(1, 5)]
    finally:
        glp.glp_delete_prob(lp)
    return x[0] - x[1], x[2] - x[3]


def _solve_turn_lp_highs(alpha: float, pan_up: float, pan_down: float, omega_pan: float, omega_rot: float):
    import highspy

    h = highspy.Highs()
    h.setOptionValue("output_flag", False)
    inf = highspy.kHighsInf
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = 4, 1
    lp.col_cost_ = np.array([omega_pan, omega_pan, omega_rot, omega_rot])
    lp.col_lower_ = np.zeros(4)
    lp.col_upper_ = np.array([max(pan_up, 0.0), max(pan_down, 0.0), math.pi, math.pi])
    lp.row_lower_ = np.array([alpha])
    lp.row_upper_ = np.array([alpha])
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_ = np.array([0, 1, 2, 3, 4])
    lp.a_matrix_.index_ = np.array([0, 0, 0, 0])
    lp.a_matrix_.value_ = np.array([1.0, -1.0, 1.0, -1.0])
    del inf
    h.passModel(lp)
    h.run()
    if h.getModelStatus() != highspy.HighsModelStatus.kOptimal:
        raise RuntimeError(f"HiGHS found no optimal solution ({h.modelStatusToString(h.getModelStatus())})")
    x = list(h.getSolution().col_value)
    return x[0] - x[1], x[2] - x[3]


def solve_turn_lp(
    alpha_rad: float, pan_up_rad: float, pan_down_rad: float, omega_pan: float, omega_rot: float, solver: str = "glpk"
) -> tuple[float, float]:
    """The approximated IK's linear programme (the original's, solved by GLPK there).

    minimise   omega_pan (x_pan+ + x_pan-) + omega_rot (x_rot+ + x_rot-)
    subject to x_pan+ - x_pan- + x_rot+ - x_rot- = alpha        (the azimuth still to turn, rad, in [-pi, pi])
               0 <= x_pan+ <= pan_up, 0 <= x_pan- <= pan_down   (room to the pan limits, rad)
               0 <= x_rot+, x_rot- <= pi

    Returns (pan change, rotation change) in rad.
    """
    args = (float(alpha_rad), float(pan_up_rad), float(pan_down_rad), float(omega_pan), float(omega_rot))
    if solver == "glpk":
        return _solve_turn_lp_glpk(*args)
    if solver == "highs":
        return _solve_turn_lp_highs(*args)
    if solver == "closed_form":
        pan, rot = turn_split_closed_form(*args)
        return float(pan), float(rot)
    raise ValueError(f"unknown LP solver '{solver}' (one of {', '.join(LP_SOLVERS)})")


# --------------------------------------------------------------------------------------------------- heuristics
def rating_simple(source_rotation_rad, target_rotation_rad):
    """SIMPLE: 0.6 ** |rotation change| (shortest way round, 0 .. pi)."""
    return RATING_BASE ** np.abs(wrap_to_pi(np.asarray(target_rotation_rad) - source_rotation_rad))


def rating_angle_approximation(source_xy_m, target_xy_m, source_rotation_rad, target_rotation_rad):
    """ANGLE_APPROXIMATION: 0.6 ** (turn onto the straight line from source to target + turn from it to the target
    heading); a turn in place (positions closer than 1 um) is rated by the turn itself."""
    delta = np.asarray(target_xy_m, dtype=float) - np.asarray(source_xy_m, dtype=float)
    return _angle_approximation(delta[..., 0], delta[..., 1], source_rotation_rad, target_rotation_rad)


def _angle_approximation(dx, dy, source_rotation_rad, target_rotation_rad):
    line = np.arctan2(dy, dx)
    via_line = np.abs(wrap_to_pi(source_rotation_rad - line)) + np.abs(wrap_to_pi(target_rotation_rad - line))
    in_place = np.abs(wrap_to_pi(np.asarray(target_rotation_rad) - source_rotation_rad))
    moving = np.hypot(dx, dy) > 1e-6
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


# --------------------------------------------------------------------------------------------------- results
@dataclass(frozen=True)
class IKSolution:
    """Result of an inverse kinematics request. ``state`` is None when there is no solution (``reason`` says why)."""

    state: RobotState | None
    reason: str
    requested_view_centre_m: np.ndarray
    achieved_view_centre_m: np.ndarray | None = None
    camera_pose: np.ndarray | None = None  # 4x4 of the solution's camera mount frame in the map frame
    angle_deviation_rad: float = math.nan  # between the requested and the achieved view axis
    tilt_clamped: bool = False
    base_position_allowed: bool | None = None  # None without a map
    samples: np.ndarray | None = None  # (k, 5) pan, x, y, rotation, rating of every pan sample (visualisation)

    @property
    def ok(self) -> bool:
        return self.state is not None


@dataclass(frozen=True)
class IKBatch:
    """Vectorised IK results: states (n, 5) as (pan, tilt, rotation, x, y), NaN rows where there is no solution."""

    states: np.ndarray
    ok: np.ndarray
    angle_deviation_rad: np.ndarray
    tilt_clamped: np.ndarray
    view_centres_m: np.ndarray  # requested
    achieved_view_centres_m: np.ndarray


@dataclass(frozen=True)
class PoseCorrection:
    """PTU angles (rad) aiming the camera at a view centre without moving the base."""

    pan: float
    tilt: float
    pan_clamped: bool
    tilt_clamped: bool
    view_centre_m: np.ndarray
    reason: str = ""


@dataclass(frozen=True)
class MovementCosts:
    """Movement costs in [0, 1], 1 = no movement (the original's convention), and their omega-weighted mean."""

    base_translation: float
    pan: float
    tilt: float
    rotation: float
    weighted: float


# --------------------------------------------------------------------------------------------------- the model
_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # x right, y down, z along the view


class MildRobotModel:
    """The MILD's kinematics with the settings of asr_robot_model_services and, optionally, a map."""

    def __init__(
        self,
        kinematics: MildKinematics | None = None,
        settings: RobotModelSettings | None = None,
        occupancy_map: OccupancyMap | None = None,
    ):
        self.kinematics = kinematics or load_kinematics()
        self.settings = settings or load_settings()
        self.map = occupancy_map
        k = self.kinematics
        self._bp = k.base_to_pan_m
        self._t = k.pan_to_tilt_m
        self._m = k.tilt_to_mount_m
        self._h = k.tilt_axis_height_m

    @classmethod
    def load(
        cls,
        settings: str | Path | RobotModelSettings | None = None,
        kinematics: str | Path | None = None,
        frames: str | Path | None = None,
        map_file: str | Path | bool | None = None,
    ) -> MildRobotModel:
        """From files (package defaults when None); ``map_file=False`` for a model without a map."""
        if not isinstance(settings, RobotModelSettings):
            settings = load_settings(settings)
        kin = load_kinematics(kinematics, frames)
        occupancy = None if map_file is False else load_map(map_file, settings)
        return cls(kin, settings, occupancy)

    # ----------------------------------------------------------------------------------------- forward kinematics
    @property
    def pan_limits(self) -> tuple[float, float]:
        return self.settings.pan_limits_rad

    @property
    def tilt_limits(self) -> tuple[float, float]:
        return self.settings.tilt_limits_rad

    def frame_poses(self, state: RobotState) -> dict[str, np.ndarray]:
        """4x4 pose in the map frame of every frame of the chain, keyed by tf frame name."""
        k, f = self.kinematics, self.kinematics.frames

        def translation(v):
            m = np.eye(4)
            m[:3, 3] = v
            return m

        def rot_z(a):
            m = np.eye(4)
            m[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
            return m

        def tilt_rotation(a):  # about -y: positive tilt raises the +x axis
            m = np.eye(4)
            m[0, 0], m[0, 2], m[2, 0], m[2, 2] = math.cos(a), -math.sin(a), math.sin(a), math.cos(a)
            return m

        poses = {f.map_frame: np.eye(4)}
        base = translation([state.x, state.y, 0.0]) @ rot_z(state.rotation)
        poses[f.base_frame] = base
        poses[f.ptu_base_frame] = base @ translation(k.base_to_ptu_base_m)
        poses[f.ptu_pan_frame] = poses[f.ptu_base_frame] @ translation(k.ptu_base_to_pan_m)
        poses[f.ptu_pan_frame_rotated] = poses[f.ptu_pan_frame] @ rot_z(state.pan)
        poses[f.ptu_tilt_frame] = poses[f.ptu_pan_frame_rotated] @ translation(k.pan_to_tilt_m)
        poses[f.ptu_tilt_frame_rotated] = poses[f.ptu_tilt_frame] @ tilt_rotation(state.tilt)
        mount = poses[f.ptu_tilt_frame_rotated] @ translation(k.tilt_to_mount_m)
        poses[f.camera_mount_frame] = mount
        optical = np.eye(4)
        optical[:3, :3] = _OPTICAL
        half = 0.5 * k.camera_baseline_m
        poses[f.camera_left_frame] = mount @ translation([0.0, half, 0.0]) @ optical
        poses[f.camera_right_frame] = mount @ translation([0.0, -half, 0.0]) @ optical
        return poses

    def camera_poses(self, states: np.ndarray) -> np.ndarray:
        """Camera mount poses (n, 4, 4) in the map frame of states (n, 5), vectorised."""
        s = np.atleast_2d(np.asarray(states, dtype=float))
        pan, tilt, rotation, x, y = s.T
        heading = rotation + pan
        cr, sr, ch, sh, ct, st = (np.cos(rotation), np.sin(rotation), np.cos(heading), np.sin(heading),
                                  np.cos(tilt), np.sin(tilt))  # fmt: skip
        bp, t, m = self._bp, self._t, self._m
        forward = t[0] + m[0] * ct - m[2] * st  # in the pan-rotated frame
        lateral = t[1] + m[1]
        out = np.zeros((len(s), 4, 4))
        out[:, 0, 3] = x + bp[0] * cr - bp[1] * sr + forward * ch - lateral * sh
        out[:, 1, 3] = y + bp[0] * sr + bp[1] * cr + forward * sh + lateral * ch
        out[:, 2, 3] = self._h + m[0] * st + m[2] * ct
        out[:, :3, 0] = np.stack([ct * ch, ct * sh, st], -1)
        out[:, :3, 1] = np.stack([-sh, ch, np.zeros_like(sh)], -1)
        out[:, :3, 2] = np.stack([-st * ch, -st * sh, ct], -1)
        out[:, 3, 3] = 1.0
        return out

    def camera_pose(self, state: RobotState) -> np.ndarray:
        """Camera mount pose (4x4, map frame) of a robot state: what CalculateCameraPose returns."""
        return self.camera_poses(state.as_array()[None])[0]

    def view_centre(self, camera_pose: np.ndarray) -> np.ndarray:
        return camera_pose[:3, 3] + self.settings.view_distance_m * camera_pose[:3, 0]

    def view_centre_height_range_m(self) -> tuple[float, float]:
        """Heights of view centres the camera can face from the viewing distance at all (before tilt limits)."""
        d = self.settings.view_distance_m
        reach = math.hypot(self._m[0] + d, self._m[2])
        return self._h - reach, self._h + reach

    # ----------------------------------------------------------------------------------------- ratings
    def rate_base_poses(self, source: RobotState, xy_m: np.ndarray, rotations_rad: np.ndarray) -> np.ndarray:
        """Heuristic rating (``IKAngleRating``) of candidate base poses (..., 2) / (...) reached from ``source``;
        0 where the map does not allow the base position (when the model has a map)."""
        xy = np.asarray(xy_m, dtype=float)
        return self._rate(source, xy[..., 0], xy[..., 1], np.asarray(rotations_rad, dtype=float))

    def _rate(self, source: RobotState, x: np.ndarray, y: np.ndarray, rotations: np.ndarray) -> np.ndarray:
        name = self.settings.ik_angle_rating
        if name == "NAVIGATION_PATH" and self.map is not None:
            ratings = self._rate_navigation_path(source, np.stack([x, y], -1), rotations)
        elif name in ("ANGLE_APPROXIMATION", "NAVIGATION_PATH"):  # NAVIGATION_PATH without a map: straight line
            ratings = _angle_approximation(x - source.x, y - source.y, source.rotation, rotations)
        else:
            ratings = rating_simple(source.rotation, rotations)
        if self.map is not None:
            ratings = np.where(self.map.is_allowed_xy(x, y, self.settings.col_thresh), ratings, 0.0)
        return ratings

    def _rate_navigation_path(self, source: RobotState, xy: np.ndarray, rotations: np.ndarray) -> np.ndarray:
        planner = self.map.planner(self.settings.col_thresh)
        start = np.array([source.x, source.y])
        if planner.snap(start, self.settings.tolerance_m) is None:
            # the robot stands where the planner cannot start: rate the straight line instead of everything 0
            return rating_angle_approximation(start, xy, source.rotation, rotations)
        flat_xy, flat_rot = xy.reshape(-1, 2), rotations.reshape(-1)
        paths = planner.plan_many(start, flat_xy, self.settings.tolerance_m)
        ratings = np.array(
            [rating_navigation_path(p, source.rotation, r) for p, r in zip(paths, flat_rot, strict=True)]
        )
        return ratings.reshape(rotations.shape)

    # ----------------------------------------------------------------------------------------- exact IK
    def _exact_geometry(self, positions: np.ndarray, views: np.ndarray):
        """Tilt, camera heading and the pan-rotated frame's position for every request (vectorised)."""
        d = self.settings.view_distance_m
        tmin, tmax = self.tilt_limits
        m = self._m
        centres = positions + d * views
        heading = np.arctan2(views[:, 1], views[:, 0])
        # The camera at distance d looking at the centre puts the centre at height
        # h + (m_x + d) sin(tilt) + m_z cos(tilt) = h + reach sin(tilt + beta): one tilt for every pan and base pose.
        lever = m[0] + d
        reach = math.hypot(lever, m[2])
        beta = math.atan2(m[2], lever)
        sine = (centres[:, 2] - self._h) / reach
        reachable = np.abs(sine) <= 1.0
        tilt = np.arcsin(np.clip(sine, -1.0, 1.0)) - beta
        tilt_c = np.clip(tilt, tmin, tmax)
        clamped = np.abs(tilt_c - tilt) > 1e-12
        # clamped: face the point above/below the requested centre instead, at the same distance
        achieved = centres.copy()
        achieved[:, 2] = self._h + lever * np.sin(tilt_c) + m[2] * np.cos(tilt_c)
        ct, st, ch, sh = np.cos(tilt_c), np.sin(tilt_c), np.cos(heading), np.sin(heading)
        view = np.stack([ct * ch, ct * sh, st], -1)
        camera = achieved - d * view
        forward = m[0] * ct - m[2] * st
        tilt_axis_xy = camera[:, :2] - np.stack([forward * ch - m[1] * sh, forward * sh + m[1] * ch], -1)
        t = self._t
        pan_xy = tilt_axis_xy - np.stack([t[0] * ch - t[1] * sh, t[0] * sh + t[1] * ch], -1)
        return heading, tilt_c, pan_xy, reachable, clamped, centres, achieved, view

    def _base_poses(self, heading: np.ndarray, pan_xy: np.ndarray, pans: np.ndarray):
        """Base positions x, y (n, k) and rotations (n, k) putting the pan axis at ``pan_xy`` (n, 2) for pans (n, k)."""
        rotation = heading[:, None] - pans
        c, s = np.cos(rotation), np.sin(rotation)
        bx = pan_xy[:, 0, None] - (self._bp[0] * c - self._bp[1] * s)
        by = pan_xy[:, 1, None] - (self._bp[0] * s + self._bp[1] * c)
        return bx, by, rotation

    def _sample_pan(self, source: RobotState, heading, pan_xy, record: bool = False):
        """The original's pan sampling: ``panAngleSamplingStepsPerIteration`` samples spread evenly across a window
        that starts as the whole pan range and then halves around the best sample so far (kept inside the limits).

        Refinement stops after ``panAngleSamplingMaxIterations`` or once the best rating improved by at most
        ``inverseKinematicIterationAccuracy`` and the window's samples rate within that accuracy of each other. (The
        original stopped on the improvement alone, which ends too early when two samples straddle the optimum.)
        """
        lo, hi = self.pan_limits
        n = len(heading)
        offsets = np.linspace(-0.5, 0.5, self.settings.pan_sampling_steps)
        accuracy = self.settings.ik_iteration_accuracy
        centre = np.full(n, 0.5 * (lo + hi))
        width = np.full(n, hi - lo)
        best_pan = centre.copy()
        best_rating = np.full(n, -1.0)
        active = np.ones(n, dtype=bool)
        rows = np.arange(n)
        trace = []
        for _ in range(self.settings.pan_sampling_max_iterations):
            centre = np.clip(centre, lo + 0.5 * width, hi - 0.5 * width)
            pans = centre[:, None] + width[:, None] * offsets
            bx, by, rotation = self._base_poses(heading, pan_xy, pans)
            ratings = self._rate(source, bx, by, rotation)
            if record:
                trace.append(np.stack([pans, bx, by, rotation, ratings], -1))
            best = np.argmax(ratings, axis=1)
            rating = ratings[rows, best]
            improved = active & (rating > best_rating)
            gain = np.where(improved, rating - np.maximum(best_rating, 0.0), 0.0)
            best_pan = np.where(improved, pans[rows, best], best_pan)
            best_rating = np.where(improved, rating, best_rating)
            centre = np.where(active, best_pan, centre)
            width = np.where(active, 0.5 * width, width)
            spread = ratings.max(axis=1) - ratings.min(axis=1)
            active &= (gain > accuracy) | (spread > accuracy)
            if not active.any():
                break
        samples = np.concatenate([t.reshape(n, -1, 5) for t in trace], axis=1) if record else None
        return best_pan, best_rating, samples

    def exact_ik_batch(self, source: RobotState, positions: np.ndarray, orientations: np.ndarray) -> IKBatch:
        """Exact geometric IK with base movement for many requested camera poses (positions (n, 3) in m,
        orientations (n, 4) as unit quaternions x, y, z, w) from one source state."""
        return self._exact(source, positions, orientations)[0]

    def _exact(self, source: RobotState, positions, orientations, record: bool = False):
        positions = np.atleast_2d(np.asarray(positions, dtype=float))
        views = view_directions(np.atleast_2d(np.asarray(orientations, dtype=float)))
        views /= np.linalg.norm(views, axis=1, keepdims=True)
        heading, tilt, pan_xy, reachable, clamped, centres, achieved, view = self._exact_geometry(positions, views)
        n = len(positions)
        states = np.full((n, 5), np.nan)
        samples = None
        if reachable.any():
            idx = np.flatnonzero(reachable)
            pan, _, samples = self._sample_pan(source, heading[idx], pan_xy[idx], record)
            bx, by, rotation = self._base_poses(heading[idx], pan_xy[idx], pan[:, None])
            states[idx] = np.stack([pan, tilt[idx], wrap_to_2pi(rotation[:, 0]), bx[:, 0], by[:, 0]], -1)
        deviation = np.where(reachable, angle_between(view, views), np.nan)
        batch = IKBatch(
            states, reachable, deviation, clamped & reachable, centres, np.where(reachable[:, None], achieved, np.nan)
        )
        return batch, samples

    # ----------------------------------------------------------------------------------------- approximated IK
    def approximated_ik_batch(self, source: RobotState, positions, orientations) -> IKBatch:
        """Approximated IK (the LP in its closed form, vectorised) for many requested camera poses."""
        positions = np.atleast_2d(np.asarray(positions, dtype=float))
        views = view_directions(np.atleast_2d(np.asarray(orientations, dtype=float)))
        views /= np.linalg.norm(views, axis=1, keepdims=True)
        alpha, up, down, current_pan, elevation = self._approximated_setup(source, views)
        s = self.settings
        pan_change, rot_change = turn_split_closed_form(alpha, up, down, s.omega_pan, s.omega_rot)
        return self._approximated_result(source, positions, views, current_pan + pan_change, rot_change, elevation)

    def _approximated_setup(self, source: RobotState, views: np.ndarray):
        lo, hi = self.pan_limits
        azimuth = wrap_to_2pi(np.arctan2(views[:, 1], views[:, 0]))
        elevation = np.arcsin(np.clip(views[:, 2], -1.0, 1.0))
        current_pan = min(max(source.pan, lo), hi)  # a pan outside the limits counts as at the limit
        alpha = wrap_to_pi(azimuth - current_pan - source.rotation)
        return (
            alpha,
            np.full_like(alpha, hi - current_pan),
            np.full_like(alpha, current_pan - lo),
            current_pan,
            elevation,
        )

    def _approximated_result(self, source, positions, views, pan, rot_change, elevation) -> IKBatch:
        tmin, tmax = self.tilt_limits
        tilt = np.clip(elevation, tmin, tmax)
        lo, hi = self.pan_limits
        pan = np.clip(pan, lo, hi)
        rotation = wrap_to_2pi(source.rotation + rot_change)
        states = np.stack([pan, tilt, rotation, positions[:, 0], positions[:, 1]], -1)
        poses = self.camera_poses(states)
        achieved_view = poses[:, :3, 0]
        deviation = angle_between(achieved_view, views)
        d = self.settings.view_distance_m
        n = len(states)
        return IKBatch(
            states,
            np.ones(n, dtype=bool),
            deviation,
            np.abs(tilt - elevation) > 1e-12,
            positions + d * views,
            poses[:, :3, 3] + d * achieved_view,
        )

    def approximated_ik(self, source: RobotState, position, orientation_xyzw) -> IKSolution:
        """Approximated IK for one pose, the LP solved by ``lpSolver`` (GLPK by default, as the original)."""
        source = source.checked("sourceRobotState")
        p, q = check_pose(position, orientation_xyzw, "requested camera pose")
        views = view_directions(q[None])
        alpha, up, down, current_pan, elevation = self._approximated_setup(source, views)
        s = self.settings
        pan_change, rot_change = solve_turn_lp(alpha[0], up[0], down[0], s.omega_pan, s.omega_rot, s.lp_solver)
        batch = self._approximated_result(
            source, p[None], views, np.array([current_pan + pan_change]), np.array([rot_change]), elevation
        )
        return self._solution(batch, 0, None)

    # ----------------------------------------------------------------------------------------- IK entry point
    def calculate_robot_state(
        self, source: RobotState, position, orientation_xyzw, record_samples: bool = False
    ) -> IKSolution:
        """Inverse kinematics with base movement by ``robotModelId`` (1 exact, 2 approximated).

        ``position`` (m, map) and ``orientation_xyzw`` are the requested camera pose, the camera looking along +x.
        Raises ValueError for a non-finite state or pose or a zero quaternion.
        """
        if self.settings.robot_model_id == APPROXIMATED_IK:
            return self.approximated_ik(source, position, orientation_xyzw)
        source = source.checked("sourceRobotState")
        p, q = check_pose(position, orientation_xyzw, "requested camera pose")
        batch, samples = self._exact(source, p[None], q[None], record_samples)
        return self._solution(batch, 0, None if samples is None else samples[0] if len(samples) else None)

    def _solution(self, batch: IKBatch, i: int, samples) -> IKSolution:
        centre = batch.view_centres_m[i]
        if not batch.ok[i]:
            low, high = self.view_centre_height_range_m()
            where = "above" if centre[2] > high else "below"
            return IKSolution(
                None,
                f"no solution: the view centre ({centre[0]:.3f}, {centre[1]:.3f}, {centre[2]:.3f}) m is too far "
                f"{where} the robot; the camera faces view centres at {low:.3f} .. {high:.3f} m height from "
                f"{self.settings.view_distance_m:.3f} m",
                centre,
            )
        state = RobotState.from_array(batch.states[i])
        pose = self.camera_pose(state)
        achieved = self.view_centre(pose)
        reason = ""
        if batch.tilt_clamped[i]:
            lo, hi = np.degrees(self.tilt_limits)
            reason = (
                f"tilt clamped to [{lo:.1f}, {hi:.1f}] deg: the view centre is approximated "
                f"{np.linalg.norm(achieved - centre):.3f} m away"
            )
        allowed = None
        if self.map is not None:
            allowed = bool(self.map.is_allowed(np.array([state.x, state.y]), self.settings.col_thresh))
            if not allowed:
                reason = (reason + "; " if reason else "") + "the base position is not allowed on the map"
        return IKSolution(
            state,
            reason,
            centre,
            achieved,
            pose,
            float(batch.angle_deviation_rad[i]),
            bool(batch.tilt_clamped[i]),
            allowed,
            samples,
        )

    # ----------------------------------------------------------------------------------------- PTU pose correction
    def camera_pose_correction(self, state: RobotState, position, orientation_xyzw) -> PoseCorrection:
        """Pan and tilt (rad) that make the camera's view axis pass through the requested view centre without moving
        the base (the distance to it is whatever results), clamped to the PTU limits."""
        state = state.checked("sourceRobotState")
        p, q = check_pose(position, orientation_xyzw, "requested camera pose")
        centre = p + self.settings.view_distance_m * view_directions(q)
        c, s = math.cos(state.rotation), math.sin(state.rotation)
        bp, t, m = self._bp, self._t, self._m
        pan_axis = np.array([state.x + bp[0] * c - bp[1] * s, state.y + bp[0] * s + bp[1] * c])
        w = centre[:2] - pan_axis
        a = math.hypot(w[0], w[1])
        bearing = math.atan2(w[1], w[0])
        lateral = t[1] + m[1]  # the view axis runs in the vertical plane this far left of the pan axis
        notes = []
        if a > abs(lateral) + 1e-9:
            offset = math.asin(lateral / a)
            heading = bearing - offset
            ahead = a * math.cos(offset)
        else:
            heading, ahead = bearing, a
            notes.append("the view centre lies on the pan axis: pan kept on its bearing")
        forward, up = ahead - t[0], centre[2] - self._h
        radius = math.hypot(forward, up)
        elevation = math.atan2(up, forward)
        tilt = elevation - math.asin(m[2] / radius) if radius > abs(m[2]) else elevation
        pan, pan_clamped = self._pan_within_limits(heading - state.rotation, state.pan)
        tmin, tmax = self.tilt_limits
        tilt_c = min(max(tilt, tmin), tmax)
        tilt_clamped = tilt_c != tilt
        if pan_clamped:
            notes.append(f"pan {math.degrees(wrap_to_pi(heading - state.rotation)):.1f} deg clamped to the limits")
        if tilt_clamped:
            notes.append(f"tilt {math.degrees(tilt):.1f} deg clamped to the limits")
        return PoseCorrection(pan, tilt_c, pan_clamped, tilt_clamped, centre, "; ".join(notes))

    def _pan_within_limits(self, pan_rad: float, current_pan_rad: float) -> tuple[float, bool]:
        """The representation pan + 2 pi k within the limits closest to the current pan, else the nearest limit."""
        lo, hi = self.pan_limits
        candidates = float(wrap_to_pi(pan_rad)) + TWO_PI * np.arange(-2, 3)
        inside = candidates[(candidates >= lo - 1e-12) & (candidates <= hi + 1e-12)]
        if len(inside):
            return float(inside[np.argmin(np.abs(inside - current_pan_rad))]), False
        clamped = np.clip(candidates, lo, hi)
        return float(clamped[np.argmin(np.abs(clamped - candidates))]), True

    # ----------------------------------------------------------------------------------------- costs and map
    def get_distance(self, source_position_m, target_position_m) -> float:
        """GetDistance: 2-D Euclidean distance (m), or with ``useGlobalPlanner`` the planned path's length on the map;
        -1 when there is no path."""
        a = np.asarray(source_position_m, dtype=float).reshape(-1)[:2]
        b = np.asarray(target_position_m, dtype=float).reshape(-1)[:2]
        if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
            raise ValueError(f"positions must be finite, got {a.tolist()} and {b.tolist()}")
        if not self.settings.use_global_planner:
            return float(np.hypot(*(b - a)))
        if self.map is None:
            raise RuntimeError("useGlobalPlanner is set but the model has no map")
        path = self.map.planner(self.settings.col_thresh).plan(a, b, self.settings.tolerance_m)
        return -1.0 if path is None else polyline_length(path)

    def navigation_path(self, source_position_m, target_position_m) -> np.ndarray | None:
        """The planned path (k, 2) in metres on the map, None when there is none."""
        if self.map is None:
            raise RuntimeError("the model has no map")
        a = np.asarray(source_position_m, dtype=float).reshape(-1)[:2]
        b = np.asarray(target_position_m, dtype=float).reshape(-1)[:2]
        return self.map.planner(self.settings.col_thresh).plan(a, b, self.settings.tolerance_m)

    def is_position_allowed(self, position_m) -> bool:
        """IsPositionAllowed: the inflated map's occupancy at the point lies within [0, colThresh]; unknown cells
        and points outside the map are not allowed."""
        p = np.asarray(position_m, dtype=float).reshape(-1)[:2]
        if not np.all(np.isfinite(p)):
            raise ValueError(f"position {p.tolist()} is not finite")
        if self.map is None:
            raise RuntimeError("the model has no map")
        return bool(self.map.is_allowed(p, self.settings.col_thresh))

    def movement_costs(self, source: RobotState, target: RobotState) -> MovementCosts:
        """The original's movement costs (1 = no movement): base translation exp(-d^2 / (2 mSigma^2)) with d from
        GetDistance (a missing path costs everything), pan 1 - |d pan| / pan span, tilt 1 - |d tilt| / tilt span,
        rotation 1 - (turn onto the line between the positions + turn from it to the target heading, or the turn
        in place) / 2 pi; ``weighted`` is their mean weighted by mOmegaBase, mOmegaPan, mOmegaTilt, mOmegaRot."""
        s = self.settings
        distance = self.get_distance([source.x, source.y], [target.x, target.y])
        base = 0.0 if distance < 0 else math.exp(-(distance**2) / (2.0 * s.sigma_m**2))
        pan_span = s.pan_limits_rad[1] - s.pan_limits_rad[0]
        tilt_span = s.tilt_limits_rad[1] - s.tilt_limits_rad[0]
        pan = 1.0 - abs(target.pan - source.pan) / pan_span
        tilt = 1.0 - abs(target.tilt - source.tilt) / tilt_span
        dx, dy = target.x - source.x, target.y - source.y
        if abs(dx) < 1e-5 and abs(dy) < 1e-5:
            turn = abs(float(wrap_to_pi(target.rotation - source.rotation)))
        else:
            line = math.atan2(dy, dx)
            turn = abs(float(wrap_to_pi(source.rotation - line))) + abs(float(wrap_to_pi(target.rotation - line)))
        rotation = 1.0 - turn / TWO_PI
        weights = np.array([s.omega_base, s.omega_pan, s.omega_tilt, s.omega_rot])
        values = np.array([base, pan, tilt, rotation])
        weighted = float(weights @ values / weights.sum()) if weights.sum() > 0 else float(values.mean())
        return MovementCosts(base, pan, tilt, rotation, weighted)

    # ----------------------------------------------------------------------------------------- visualisation
    def frustum_corners(self, camera_pose: np.ndarray) -> np.ndarray:
        """The 8 corners (m, map frame) of the camera's view frustum: near plane then far plane, each
        top-left, top-right, bottom-right, bottom-left as seen from the camera."""
        s = self.settings
        corners = []
        for distance in (s.ncp_m, s.fcp_m):
            half_w = distance * math.tan(0.5 * s.fovx_rad)
            half_h = distance * math.tan(0.5 * s.fovy_rad)
            for lateral, vertical in ((half_w, half_h), (-half_w, half_h), (-half_w, -half_h), (half_w, -half_h)):
                corners.append([distance, lateral, vertical])
        local = np.array(corners)
        return local @ camera_pose[:3, :3].T + camera_pose[:3, 3]
