"""Joint-space motion planning with OMPL, checked with the FCL collision checker.

:class:`MotionPlanner` plans collision-free paths between two joint states (rad) of the station's robot: a
RealVectorStateSpace bounded by the joint limits, a planner chosen by name (RRTConnect by default), motions
validated at ``resolution_rad`` with the batch checker of :mod:`agiprobot_measurement.motion.collision`, the solution
shortened with OMPL's PathSimplifier, then interpolated and verified once more. Failures come back as a
:class:`PlanningResult` with a reason, within a time budget and a bounded number of attempts.

Contract: every state of ``interpolate_path(result.path, planner.resolution_rad)`` is valid (joint limits,
no collision with the paddings of ``config/collision.yaml``).
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from agiprobot_measurement.motion.collision import CollisionChecker
from agiprobot_measurement.motion.errors import MotionInputError
from agiprobot_measurement.motion.point_to_point import point_to_point
from agiprobot_measurement.motion.time_parameterization import TimeParameterizationError, time_optimal_trajectory
from agiprobot_measurement.motion.trajectory import JointTrajectory

__all__ = [
    "DEFAULT_PLANNER",
    "LOG",
    "PLANNERS",
    "MotionPlanner",
    "PlanningResult",
    "available_planners",
    "collision_free_trajectory",
    "interpolate_path",
    "path_trajectory",
]

#: a planned path's spline is tried through waypoints at most this far apart (rad), densest last
PATH_WAYPOINT_STEPS_RAD = (0.01, 0.002)

LOG = logging.getLogger(__name__)

DEFAULT_PLANNER = "RRTConnect"
_COARSE_STRIDE = 8  # the motion validator's first pass checks every 8th state


def _planner_classes() -> dict[str, type]:
    return {
        name: cls
        for name in dir(og)
        if isinstance(cls := getattr(og, name), type) and issubclass(cls, ob.Planner) and cls is not ob.Planner
    }


#: Geometric planners of the installed OMPL bindings, by name (RRTConnect, RRT, RRTstar, PRM, KPIECE1, ...).
PLANNERS: dict[str, type] = _planner_classes()


def available_planners() -> list[str]:
    return sorted(PLANNERS)


_ompl_seed: list[int] = []  # the seed given to OMPL in this process, if any


def _seed_ompl(seed: int) -> None:
    """Seed OMPL's global RNG once: later calls cannot take effect (OMPL logs an error), so they are skipped."""
    if not _ompl_seed:
        ou.RNG.setSeed(seed)
        _ompl_seed.append(seed)
    elif _ompl_seed[0] != seed:
        LOG.info("OMPL is already seeded with %d in this process; seed %d is ignored", _ompl_seed[0], seed)


def _planner_class(name: str) -> type:
    if name not in PLANNERS:
        raise MotionInputError(f"unknown planner '{name}'; valid planners: {', '.join(available_planners())}")
    return PLANNERS[name]


@dataclass
class PlanningResult:
    """Outcome of :meth:`MotionPlanner.plan`.

    ``path``: (K, dof) waypoints in rad, the start first and the goal last (K >= 2); (0, dof) on failure.
    ``reason``: empty on success, otherwise why planning failed (e.g. which pair collides at the goal).
    ``planning_time``: wall-clock seconds of the whole call (checks, planning, simplification, verification).
    """

    success: bool
    path: np.ndarray
    reason: str = ""
    planning_time: float = 0.0
    planner: str = ""
    attempts: int = 0
    stats: dict = field(default_factory=dict)

    def __bool__(self) -> bool:
        return self.success


def interpolate_path(path: np.ndarray, max_step_rad: float) -> np.ndarray:
    """Subdivide (K, dof) waypoints so no joint moves more than ``max_step_rad`` (rad) between two states.

    Keeps every waypoint; straight lines in joint space between them, as the planner validated them.
    """
    path = np.asarray(path, dtype=float)
    if path.ndim != 2 or len(path) == 0:
        raise MotionInputError(f"expected (K, dof) waypoints, got shape {path.shape}")
    if not max_step_rad > 0:
        raise MotionInputError(f"max_step_rad must be positive, got {max_step_rad}")
    pieces = [path[:1]]
    for a, b in itertools.pairwise(path):
        steps = max(1, math.ceil(float(np.max(np.abs(b - a))) / max_step_rad - 1e-9))
        fractions = np.arange(1, steps + 1)[:, None] / steps
        pieces.append(a + fractions * (b - a))
    return np.concatenate(pieces)


def _state_array(state, dof: int) -> np.ndarray:
    return np.array([state[i] for i in range(dof)])


def _validity_function(checker: CollisionChecker, dof: int):
    # a closure over the checker only: a reference back to the MotionPlanner would make a cycle through
    # OMPL's C++ objects that Python's garbage collector cannot see
    def valid(state) -> bool:
        return checker.is_state_valid(_state_array(state, dof))

    return valid


class _BatchMotionValidator(ob.MotionValidator):
    """OMPL motion validator that checks a straight-line motion with batch calls to the checker.

    OMPL assumes the first state valid (as its DiscreteMotionValidator does) and needs the rest checked, at
    most ``resolution_rad`` apart in every joint.
    """

    def __init__(self, si: ob.SpaceInformation, checker: CollisionChecker, dof: int, resolution_rad: float):
        super().__init__(si)
        self.checker, self.dof, self.resolution_rad = checker, dof, resolution_rad
        self.motion_checks = 0
        self.states_checked = 0

    def checkMotion(self, s1, s2) -> bool:
        self.motion_checks += 1
        a, b = _state_array(s1, self.dof), _state_array(s2, self.dof)
        steps = max(1, math.ceil(float(np.max(np.abs(b - a))) / self.resolution_rad - 1e-9))
        states = a + (np.arange(1, steps + 1)[:, None] / steps) * (b - a)
        if steps <= 2 * _COARSE_STRIDE:
            self.states_checked += steps
            return bool(self.checker.check_states(states).all())
        # coarse to fine: most rejected motions (planner extensions, shortcut attempts) fail on the coarse
        # pass, which costs a fraction of the full one
        coarse = np.zeros(steps, dtype=bool)
        coarse[_COARSE_STRIDE - 1 :: _COARSE_STRIDE] = True
        coarse[-1] = True
        for group in (coarse, ~coarse):
            self.states_checked += int(group.sum())
            if not self.checker.check_states(states[group]).all():
                return False
        return True


class MotionPlanner:
    """Joint-space planner for one robot and its :class:`CollisionChecker` (whose world may change between
    calls: the checks read it live).

    ``planner``: an OMPL geometric planner name (see :func:`available_planners`). ``resolution_rad``: largest
    joint step between checked states of a motion. ``time_budget_s``: the whole call's limit; it is shared
    by at most ``max_attempts`` fresh planner runs. ``simplify``: shorten the solution with PathSimplifier's
    shortcuts (``"full"``: also its B-spline smoothing) for at most ``simplify_time_s``. ``best_of``: keep
    planning (within the attempts and the budget) until this many solutions are found and return the shortest
    (joint path, rad): RRTConnect's simplified paths for the same move differ by factors of 4.
    ``try_direct``: take the straight line when it is free (no OMPL call). Optimizing planners (RRTstar,
    BITstar, ...) use the whole time of an attempt. ``seed``: OMPL's global seed; it takes effect only
    for the first planner of a process (OMPL seeds once), later seeds are ignored.
    """

    def __init__(
        self,
        checker: CollisionChecker,
        planner: str = DEFAULT_PLANNER,
        resolution_rad: float = math.radians(1.0),
        time_budget_s: float = 5.0,
        max_attempts: int = 3,
        simplify: bool | str = True,
        simplify_time_s: float = 0.1,
        try_direct: bool = True,
        range_rad: float | None = None,
        seed: int | None = None,
        log_level=ou.LOG_WARN,
        best_of: int = 1,
    ):
        _planner_class(planner)
        if simplify not in (True, False, "full"):
            raise MotionInputError(f"simplify must be True, False or 'full', got {simplify!r}")
        if not resolution_rad > 0:
            raise MotionInputError(f"resolution_rad must be positive, got {resolution_rad}")
        if not time_budget_s > 0:
            raise MotionInputError(f"time_budget_s must be positive, got {time_budget_s}")
        if int(max_attempts) < 1:
            raise MotionInputError(f"max_attempts must be >= 1, got {max_attempts}")
        if int(best_of) < 1:
            raise MotionInputError(f"best_of must be >= 1, got {best_of}")
        self.checker = checker
        self.model = checker.model
        self.dof = self.model.dof
        self.planner_name = planner
        self.resolution_rad = float(resolution_rad)
        self.time_budget_s = float(time_budget_s)
        self.max_attempts = int(max_attempts)
        self.best_of = int(best_of)
        self.simplify = simplify
        self.simplify_time_s = float(simplify_time_s)
        self.try_direct = try_direct
        self.range_rad = range_rad
        if seed is not None:
            _seed_ompl(int(seed))
        ou.setLogLevel(log_level)
        self.space = ob.RealVectorStateSpace(self.dof)
        bounds = ob.RealVectorBounds(self.dof)
        for i, name in enumerate(self.model.joint_names):
            bounds.setLow(i, float(self.model.lower[i]))
            bounds.setHigh(i, float(self.model.upper[i]))
            self.space.setDimensionName(i, name)
        self.space.setBounds(bounds)
        self.si = ob.SpaceInformation(self.space)
        self.si.setStateValidityChecker(_validity_function(checker, self.dof))
        self._motion_validator = _BatchMotionValidator(self.si, checker, self.dof, self.resolution_rad)
        self.si.setMotionValidator(self._motion_validator)
        self.si.setup()

    # ---------------------------------------------------------------------------------------- helpers
    def _to_array(self, state) -> np.ndarray:
        return _state_array(state, self.dof)

    def _to_state(self, q: np.ndarray):
        state = self.si.allocState()
        for i, value in enumerate(q):
            state[i] = float(value)
        return state

    def _check_input(self, q, what: str) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.shape != (self.dof,):
            raise MotionInputError(
                f"{what}: expected {self.dof} joint values ({', '.join(self.model.joint_names)}), got shape {q.shape}"
            )
        if not np.all(np.isfinite(q)):
            raise MotionInputError(f"{what}: joint values must be finite, got {q}")
        return q

    def check_path(self, path: np.ndarray, resolution_rad: float | None = None) -> int:
        """Index of the first invalid state of the interpolated ``path`` (at ``resolution_rad``), or -1."""
        dense = interpolate_path(path, resolution_rad or self.resolution_rad)
        valid = self.checker.check_states(dense)
        return -1 if valid.all() else int(np.argmin(valid))

    def _path_array(self, path) -> np.ndarray:
        return np.array([self._to_array(path.getState(i)) for i in range(path.getStateCount())])

    def _simplify(self, path, until: float) -> None:
        """Shorten ``path`` in place until the clock reaches ``until`` (perf_counter seconds) or nothing helps.

        Vertex reduction and partial shortcuts (as in PathSimplifier.simplify, without its B-spline smoothing,
        which multiplies the vertices and costs several times the planning time here). ``simplify="full"``
        then also runs OMPL's whole simplify in the time left.
        """
        simplifier = og.PathSimplifier(self.si)
        simplifier.reduceVertices(path)
        while time.perf_counter() < until:
            shortened = simplifier.partialShortcutPath(path)
            reduced = simplifier.reduceVertices(path)
            if not (shortened or reduced):
                break
        simplifier.collapseCloseVertices(path)
        left = until - time.perf_counter()
        if self.simplify == "full" and left > 0.0:
            simplifier.simplify(path, left, False)

    # ------------------------------------------------------------------------------------------- plan
    def plan(self, start, goal, planner: str | None = None, time_budget_s: float | None = None) -> PlanningResult:
        """Plan from ``start`` to ``goal`` (joint values, rad). Raises ValueError on malformed input
        (wrong joint count, NaN, unknown planner); every planning failure is a result with a reason."""
        started = time.perf_counter()
        name = planner or self.planner_name
        planner_class = _planner_class(name)
        start = self._check_input(start, "start")
        goal = self._check_input(goal, "goal")
        budget = self.time_budget_s if time_budget_s is None else float(time_budget_s)
        if not budget > 0:
            raise MotionInputError(f"time_budget_s must be positive, got {budget}")
        deadline = started + budget
        validator = self._motion_validator
        checks_before, states_before = validator.motion_checks, validator.states_checked

        timing = {"solve_s": 0.0, "simplify_s": 0.0}

        def result(success, path, reason, attempts=0, used=name):
            stats = {
                "motion_checks": validator.motion_checks - checks_before,
                "states_checked": validator.states_checked - states_before,
                **timing,
            }
            path = np.asarray(path, dtype=float).reshape(-1, self.dof)
            return PlanningResult(success, path, reason, time.perf_counter() - started, used, attempts, stats)

        for label, q in (("start", start), ("goal", goal)):
            problem = self.checker.explain(q)
            if problem:
                return result(False, [], f"{label} state {problem}")
        if np.max(np.abs(goal - start)) < 1e-9:
            return result(True, [start, goal], "", used="trivial")
        if self.try_direct and self.check_path(np.array([start, goal])) < 0:
            return result(True, [start, goal], "", used="direct")

        pdef = ob.ProblemDefinition(self.si)
        pdef.setStartAndGoalStates(self._to_state(start), self._to_state(goal))
        reasons = []
        attempts = solutions = 0
        best = None  # (path, joint path rad) of the shortest solution so far
        while attempts < self.max_attempts:
            remaining = deadline - time.perf_counter()
            if remaining <= 0.0:
                break
            attempts += 1
            attempt_time = remaining / (self.max_attempts - attempts + 1)
            ompl_planner = planner_class(self.si)
            if self.range_rad is not None and hasattr(ompl_planner, "setRange"):
                ompl_planner.setRange(float(self.range_rad))
            pdef.clearSolutionPaths()
            ompl_planner.setProblemDefinition(pdef)
            ompl_planner.setup()
            solve_started = time.perf_counter()
            status = ompl_planner.solve(attempt_time)
            timing["solve_s"] += time.perf_counter() - solve_started
            if not pdef.hasExactSolution():
                reasons.append(f"attempt {attempts}: {status.asString()} after {attempt_time:.2f} s")
                ompl_planner.clear()
                continue
            solution = og.PathGeometric(pdef.getSolutionPath())
            raw = self._path_array(solution)
            path = raw
            if self.simplify and len(raw) > 2:
                simplify_started = time.perf_counter()
                self._simplify(solution, min(simplify_started + self.simplify_time_s, deadline))
                path = self._path_array(solution)
                timing["simplify_s"] = time.perf_counter() - simplify_started
            ompl_planner.clear()
            for candidate in (path, raw):
                candidate = candidate.copy()
                # OMPL's states are exact copies, but the caller gets exactly what it asked for
                candidate[0], candidate[-1] = start, goal
                if self.check_path(candidate) < 0:
                    length = float(np.abs(np.diff(candidate, axis=0)).sum())
                    if best is None or length < best[1]:
                        best = (candidate, length)
                    solutions += 1
                    break
            else:
                reasons.append(f"attempt {attempts}: the solution failed the dense re-check")
            if solutions >= self.best_of:
                break
        if best is not None:
            timing["solutions"] = solutions
            return result(True, best[0], "", attempts)
        spent = time.perf_counter() - started
        detail = "; ".join(reasons) if reasons else "no time left"
        return result(
            False, [], f"no path found by {name} in {spent:.2f} s ({attempts} attempt(s)): {detail}", attempts
        )


def collision_free_trajectory(
    start,
    goal,
    limits,
    checker: CollisionChecker,
    planner=None,
    velocity_scaling: float = 1.0,
    planning_time_s: float = 0.2,
    attempts: int = 3,
    max_step_rad: float = 0.02,
    straight_first: bool = True,
):
    """Collision-free, time-parameterised joint trajectory (rad, s) from ``start`` to ``goal``, or None.

    The straight joint move when every state on it (at ``max_step_rad``) is free: a synchronised point-to-point
    motion, time-optimal for that path. Otherwise ``planner`` (when given) plans around the obstacles, with
    ``attempts`` tries, each with twice the previous time budget; its path is time-parameterised within the
    limits (scaled by ``velocity_scaling``) and the sampled trajectory is checked once more. ``planner``: a
    :class:`MotionPlanner`, or a function returning one (called only when the straight move is blocked).
    ``straight_first=False`` skips the straight move (the caller found it blocked already).
    """
    start = np.asarray(start, dtype=float)
    goal = np.asarray(goal, dtype=float)
    if np.abs(goal - start).max() < 1e-9:
        return JointTrajectory(list(limits.names), [0.0], start[None], np.zeros((1, len(start))))
    if straight_first and checker.check_states(interpolate_path(np.array([start, goal]), max_step_rad)).all():
        return point_to_point(start, goal, limits, velocity_scaling, velocity_scaling)
    if callable(planner):
        planner = planner()
    if planner is None:
        return None
    budget = max(float(planning_time_s), 0.05)
    for _ in range(attempts):
        result = planner.plan(start, goal, time_budget_s=budget)
        if result.success:
            trajectory = path_trajectory(result.path, limits, velocity_scaling)
            samples, _, _ = trajectory.sample(trajectory.dense_times(step_s=0.02, per_segment=2))
            if checker.check_states(samples).all():
                return trajectory
        budget *= 2.0
    return None


def path_trajectory(path, limits, velocity_scaling: float = 1.0) -> JointTrajectory:
    """A time-parameterised trajectory (rad, s) along a joint path (K, n) rad whose straight segments were checked.

    The time-optimal spline through the path's waypoints densified to :data:`PATH_WAYPOINT_STEPS_RAD` (the
    first that stays within the joint limits; next to a limit the spline may overshoot it); when every one
    leaves the limits, point-to-point moves from waypoint to waypoint, at rest at each: exactly the polyline,
    within the limits, slower. Never raises for a path within the limits.
    """
    path = np.asarray(path, dtype=float)
    for step in PATH_WAYPOINT_STEPS_RAD:
        try:
            return time_optimal_trajectory(
                path,
                limits,
                velocity_scaling_factor=velocity_scaling,
                acceleration_scaling_factor=velocity_scaling,
                max_waypoint_step_rad=step,
            )
        except TimeParameterizationError as exc:
            LOG.debug("path spline through waypoints %.3f rad apart failed: %s", step, exc)
    moves = [point_to_point(a, b, limits, velocity_scaling, velocity_scaling) for a, b in itertools.pairwise(path)]
    trajectory = moves[0]
    for move in moves[1:]:
        trajectory = trajectory.concatenated(move)
    return trajectory
