"""Strategies 0, 1 and 2 of the report as an explicit state machine (report Fig. 6).

Every measurement made for the chosen candidate ``cc`` is classified from the model *before* the update:

====  =========================================  =====  =====  =====
kind  what the laser hit                          S0     S1     S2
====  =========================================  =====  =====  =====
A     the target ``cc``                           A0     A1     A2
B     another candidate (unknown, next to         B0     B1     A2
      empty and full)
C     another unknown cell                        C0     B1     B2
D     an already seen cell (known in ``M``)        D0     C1     C2
E     nothing (no return)                         E0     D1     D2
====  =========================================  =====  =====  =====

Strategy 2 has no fixed target: any candidate is its success (A2). The transitions are :data:`TRANSITIONS`:
the report's where it gives one, otherwise a documented choice (marked "choice" below):

- S0: A0 advance the growth point; B0 the seen candidate is treated as the target (the growth point moves there,
  the old ``cc`` is released); C0 re-plan ``cc``; D0 error: forbid the configuration, re-plan; E0 forbid and switch
  (to S1 in ``fullpix``, S2 in ``stratpix``: choice). No plannable view -> ``cc`` is unmeasurable (report). Choice:
  when views are visible but every one would, if ``cc`` were empty, land on an already seen cell (a D0 in the
  making), S0 hands ``cc`` to S1, whose look-through views are made for exactly that.
- S1: A1 success (-> S0, choice); B1 re-plan; C1 ``cc`` is empty, take the next candidate and stay in S1 until a
  full cell is hit; D1 undetected occlusion, switch (-> S2 in ``stratpix``, -> S0 in ``fullpix``: choice). No view
  -> unmeasurable (report: S1 detects unmeasurable candidates with the circle of visibility).
- S2: A2 success (-> S0); B2 switch to S1; C2 a full turn, switch (choice: ``cc`` unmeasurable, back to S0);
  D2 normal, next angle on the circle; a full turn (``s2_max_turn_deg``, 360 by default) without a return -> ``cc``
  unmeasurable.

A re-plan or a switch always forbids the configuration just used, a candidate gets at most
``max_switches_per_candidate`` strategy switches, and no cell is a candidate twice: together they bound the number
of measurements per candidate, which is what guarantees termination on a finite grid.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum, IntEnum

import numpy as np

from agiprobot_measurement.nbv.planar.grid import EMPTY, FULL, UNKNOWN
from agiprobot_measurement.nbv.planar.scoring import ScoreConfig, ViewSet, score_views
from agiprobot_measurement.nbv.planar.traversal import first_blocking, segment_box_entry
from agiprobot_measurement.nbv.planar.visibility import N_SECTORS, make_circle_of_visibility

__all__ = [
    "LABELS",
    "SCRIPTS",
    "TRANSITIONS",
    "Action",
    "Kind",
    "NoView",
    "Plan",
    "Strategy",
    "classify",
    "label_of",
    "orbit_motion_to",
    "plan_s0",
    "plan_s1",
    "plan_s2",
]

SCRIPTS = ("circpix", "fullpix", "stratpix")


class Strategy(IntEnum):
    S0 = 0
    S1 = 1
    S2 = 2


class Kind(Enum):
    """What a measurement saw, independent of the strategy."""

    A = "target"
    B = "other candidate"
    C = "other unknown"
    D = "already seen"
    E = "nothing"


class Action(Enum):
    SUCCESS = "success"
    RETARGET = "retarget"
    REPLAN = "replan"
    SWITCH = "switch"
    NEXT_CANDIDATE = "next_candidate"
    NEXT_ANGLE = "next_angle"
    UNMEASURABLE = "unmeasurable"


LABELS = {
    Strategy.S0: {Kind.A: "A0", Kind.B: "B0", Kind.C: "C0", Kind.D: "D0", Kind.E: "E0"},
    Strategy.S1: {Kind.A: "A1", Kind.B: "B1", Kind.C: "B1", Kind.D: "C1", Kind.E: "D1"},
    Strategy.S2: {Kind.A: "A2", Kind.B: "A2", Kind.C: "B2", Kind.D: "C2", Kind.E: "D2"},
}

_COMMON = {
    "A0": (Action.SUCCESS, Strategy.S0),
    "B0": (Action.RETARGET, Strategy.S0),
    "C0": (Action.REPLAN, Strategy.S0),
    "D0": (Action.REPLAN, Strategy.S0),
    "A1": (Action.SUCCESS, Strategy.S0),
    "B1": (Action.REPLAN, Strategy.S1),
    "C1": (Action.NEXT_CANDIDATE, Strategy.S1),
}
TRANSITIONS = {
    "fullpix": {**_COMMON, "E0": (Action.SWITCH, Strategy.S1), "D1": (Action.SWITCH, Strategy.S0)},
    "stratpix": {
        **_COMMON,
        "E0": (Action.SWITCH, Strategy.S2),
        "D1": (Action.SWITCH, Strategy.S2),
        "A2": (Action.SUCCESS, Strategy.S0),
        "B2": (Action.SWITCH, Strategy.S1),
        "C2": (Action.UNMEASURABLE, Strategy.S0),
        "D2": (Action.NEXT_ANGLE, Strategy.S2),
    },
}


def is_strict_candidate(w: np.ndarray, cell) -> bool:
    """``cell`` is unknown and 8-adjacent to an empty and to a full cell (a ``getcandidates2d`` candidate)."""
    return _is_strict_candidate(w, cell)


def _is_strict_candidate(w: np.ndarray, cell) -> bool:
    i, j = cell
    if w[i, j] != UNKNOWN:
        return False
    block = w[max(i - 1, 0) : i + 2, max(j - 1, 0) : j + 2]
    return bool((block == EMPTY).any() and (block == FULL).any())


def classify(hit_cell, cc, m_before: np.ndarray, w_before: np.ndarray, general_candidates: bool = False) -> Kind:
    """The kind of a measurement (see the module table); ``hit_cell`` is ``None`` for no return.

    ``general_candidates`` uses the report's general candidate rule for kind B (an unknown cell 8-adjacent to a full
    cell) instead of ``getcandidates2d``'s stricter one: strategy 2's candidates are the points of the unit circle
    around the growth point, whatever is known about the empty side (see :func:`plan_s2`).
    """
    if hit_cell is None:
        return Kind.E
    hit = (int(hit_cell[0]), int(hit_cell[1]))
    if cc is not None and hit == (int(cc[0]), int(cc[1])):
        return Kind.A
    if m_before[hit] != UNKNOWN:
        return Kind.D
    if _is_strict_candidate(w_before, hit):
        return Kind.B
    if general_candidates:
        i, j = hit
        if (w_before[max(i - 1, 0) : i + 2, max(j - 1, 0) : j + 2] == FULL).any():
            return Kind.B
    return Kind.C


def label_of(strategy: Strategy, kind: Kind) -> str:
    """The report's outcome label (A0 .. E0, A1 .. D1, A2 .. D2)."""
    return LABELS[Strategy(strategy)][kind]


@dataclass(frozen=True)
class Plan:
    """A planned pose and the configuration key that a failure forbids (aim index, sector, side index)."""

    pos: np.ndarray
    key: tuple[int, int, int] | None
    score: float


@dataclass(frozen=True)
class NoView:
    """No view could be planned; ``reason`` is ``"unplannable"``, ``"look_through_only"`` or ``"full_turn"``."""

    reason: str


def _continuation_first(m: np.ndarray, aim, laser_dir, cc, reach_cells: float):
    """First cell beyond the aim point along the laser that is not known empty in ``m`` (``cc`` ignored)."""
    far = np.asarray(aim, dtype=float) + reach_cells * np.asarray(laser_dir, dtype=float)
    return first_blocking(m != EMPTY, aim, far, skip=cc)


def predicted_return_free(full: np.ndarray, pos, cc) -> bool:
    """The return from where the laser enters cell ``cc`` to the camera touches no known full cell but ``cc``.

    Documented choice: the circle of visibility is built at the aim point (the cell centre or an edge midpoint), but
    a return leaves from the laser's entry point on the cell's boundary. With a long laser-camera distance the camera
    ray is nearly tangent to the contour, and from the entry point it grazes the known full neighbour that the
    sectors at the centre miss (on the long-baseline rotated rectangle this was the cause of most E0s). The
    report's two-ray condition ("neither ray may cross a full region") is therefore checked on the predicted rays.
    """
    src, cam, aim = np.asarray(pos, dtype=float)
    d = (aim - src) / np.hypot(*(aim - src))
    far = aim + 2.0 * d
    t = segment_box_entry(src, far, cc)
    if t < 0:
        return True
    hit = src + t * (far - src)
    return first_blocking(full, hit, cam, skip=(int(cc[0]), int(cc[1])))[0] < 0


def _key(views: ViewSet, idx: int) -> tuple[int, int, int]:
    return int(views.aim_index[idx]), int(views.sector[idx]), int((1 - views.side[idx]) // 2)


def plan_s0(
    m: np.ndarray,
    rf,
    cc,
    aims: np.ndarray,
    circles: np.ndarray,
    normal,
    current_source,
    cfg: ScoreConfig,
    forbidden: np.ndarray,
    max_checks: int = 60,
    loose: bool = True,
    near_cells: float = 5.0,
    return_check: bool = True,
    continuation_check: bool = True,
) -> Plan | NoView:
    """Strategy 0: the best perpendicular view of ``cc`` by Viditelnost x Kolmost x Pohyb.

    The ranked views are checked on the model beyond the aim, to avoid D0 (an already seen cell answering because
    ``cc`` was empty): the best view with no known full cell on the laser within the camera's depth window behind
    ``cc`` is taken; if there is none and ``loose`` is set, the best view whose first not-known-empty cell behind
    ``cc`` is not known full and that has no known full cell within ``near_cells`` behind the aim (such a view can
    still end in a D0 when the unknown cells it crosses are empty); if
    there is none either, ``cc`` goes to strategy 1 ("look_through_only").

    With ``return_check`` a view is taken only if the return the model predicts is free: the laser enters ``cc`` on
    its boundary, not at the aim point the circle of visibility is built on, and from there the camera ray must touch
    no known full cell (see :func:`predicted_return_free`).
    """
    views: ViewSet = score_views(rf, aims, circles, normal, current_source, cfg, forbidden)
    ranked = views.ranked()
    if len(ranked) == 0:
        return NoView("unplannable")
    # a return can only come from within the camera's depth window: known full cells further away cannot give a D0
    reach = min(rf.depth_window_cells()[1], float(m.shape[0] + m.shape[1])) - rf.standoff_cells + 2.0
    full = m == FULL
    # fallbacks by preference: loose with the continuation's return free, strict without, loose without
    fallback: list = [None, None, None]
    for idx in ranked[:max_checks]:
        pos = views.poses[idx]
        d = (pos[2] - pos[0]) / np.hypot(*(pos[2] - pos[0]))
        if return_check and not predicted_return_free(full, pos, cc):
            continue
        # should cc be empty, the laser goes on through unknown cells that may be empty too: a known full cell on
        # that stretch could answer (a D0). Preferred: no known full cell within the reach (strict); accepted
        # when no view is strict: the first cell beyond cc that is not known empty is not known full (loose).
        far = pos[2] + max(reach, 1.0) * d
        strict = first_blocking(full, pos[2], far, skip=cc)[0] < 0
        ci, cj = _continuation_first(m, pos[2], d, cc, reach)
        # should cc be empty, the unknown cell the laser reaches next may answer: a view whose return from there is
        # blocked by a known full cell would then see nothing (an E0 that teaches nothing); such views come last
        cont_ok = not continuation_check or ci < 0 or m[ci, cj] != UNKNOWN or predicted_return_free(full, pos, (ci, cj))
        if strict and cont_ok:
            return Plan(pos, _key(views, idx), float(views.score[idx]))
        if strict:
            if fallback[1] is None:
                fallback[1] = idx
            continue
        if loose:
            # the first cell may be an unknown one the laser only grazes: a known full cell right behind cc
            # (within ``near_cells``) would still answer, so that is excluded as well
            near_full = first_blocking(full, pos[2], pos[2] + near_cells * d, skip=cc)[0] >= 0
            if (ci < 0 or m[ci, cj] != FULL) and not near_full:
                k = 0 if cont_ok else 2
                if fallback[k] is None:
                    fallback[k] = idx
    for f in fallback:
        if f is not None:
            return Plan(views.poses[f], _key(views, f), float(views.score[f]))
    return NoView("look_through_only")


def plan_s1(
    m: np.ndarray,
    w: np.ndarray,
    rf,
    cc,
    aims: np.ndarray,
    circles: np.ndarray,
    normal,
    current_source,
    cfg: ScoreConfig,
    forbidden: np.ndarray,
    reach_cells: float = 3.0,
    max_checks: int = 60,
) -> Plan | NoView:
    """Strategy 1: look *through* ``cc`` onto a full cell within ``reach_cells`` behind it.

    Kolmost is replaced by the visibility of nearby full cells through the candidate: the sector opposite the source
    must be blocked in the circle built from the full cells within ``reach_cells`` of the aim point. The ranked views
    are then checked on the model: the laser beyond ``cc`` must reach a known full cell within the reach, and the
    return from that cell to the camera must touch no known full cell (the report: "the circle of visibility
    guarantees no occlusion for the data measured so far").
    """
    term = np.zeros((len(aims), N_SECTORS))
    for a, xs in enumerate(aims):
        near = make_circle_of_visibility(w, xs, max_distance_cells=reach_cells + 0.75)
        term[a] = 1.0 - np.roll(near, -180)  # term[m] = near sector m + 180 is blocked
    if normal is not None:
        # the source stays on the outer side of the contour line: a look-through view from the body's side would
        # cross unexplored body (the circle blocks only on full cells)
        phi = np.radians(np.arange(N_SECTORS) + 0.5)
        term *= (np.cos(phi) * normal[0] + np.sin(phi) * normal[1]) >= 0.0
    views = score_views(rf, aims, circles, None, current_source, cfg, forbidden, term=term)
    ranked = views.ranked()
    if len(ranked) == 0:
        return NoView("unplannable")
    full = m == FULL
    for idx in ranked[:max_checks]:
        pos = views.poses[idx]
        d = (pos[2] - pos[0]) / np.hypot(*(pos[2] - pos[0]))
        ci, cj = _continuation_first(m, pos[2], d, cc, reach_cells + 1.5)
        if ci < 0 or m[ci, cj] != FULL:
            continue
        # the return the model predicts: from where the laser enters that full cell back to the camera
        far = pos[2] + (reach_cells + 1.5) * d
        t = segment_box_entry(pos[0], far, (ci, cj))
        hit = pos[0] + t * (far - pos[0])
        if first_blocking(full, hit, pos[1], skip=(ci, cj))[0] >= 0:
            continue
        key = (int(views.aim_index[idx]), int(views.sector[idx]), int((1 - views.side[idx]) // 2))
        return Plan(pos, key, float(views.score[idx]))
    return NoView("unplannable")


@dataclass
class OrbitState:
    """Strategy 2's position on the unit circle around the growth point (angles in radians)."""

    centre: tuple[int, int]
    theta0_rad: float
    rotation: int
    step_rad: float
    k: int = 0
    max_turn_rad: float = 2 * math.pi
    camera: str = "away"

    @property
    def n_steps(self) -> int:
        return math.ceil(self.max_turn_rad / self.step_rad - 1e-9)


def start_orbit(
    pp,
    normal,
    direction,
    cc,
    current_source,
    step_deg: float,
    start_at: str = "normal",
    max_turn_deg: float = 360.0,
    camera: str = "away",
) -> OrbitState:
    """Begin the orbit on the outward normal of ``pp`` (where strategy 0 looked from) and turn towards where the
    contour goes on (``direction``, else towards ``cc``); without a normal, start where the sensor is. The orbit
    gives up after ``max_turn_deg`` (the report: a full turn)."""
    p = np.asarray(pp, dtype=float)
    at_sensor = current_source is not None and np.hypot(*(np.asarray(current_source) - p)) > 0
    if start_at == "sensor" and at_sensor:
        start = np.asarray(current_source, dtype=float) - p
    elif normal is not None:
        start = np.asarray(normal, dtype=float)
    elif current_source is not None and np.hypot(*(np.asarray(current_source) - p)) > 0:
        start = np.asarray(current_source, dtype=float) - p
    else:
        start = np.array([0.0, -1.0])
    ahead = direction if direction is not None else (np.asarray(cc, dtype=float) - p)
    cross = start[0] * ahead[1] - start[1] * ahead[0]
    rotation = 1 if cross >= 0 else -1
    return OrbitState(
        (int(pp[0]), int(pp[1])), math.atan2(start[1], start[0]), rotation, math.radians(step_deg),
        max_turn_rad=math.radians(max_turn_deg), camera=camera,
    )  # fmt: skip


def _laser_sees_only_known_full(m: np.ndarray, src, aim, rf) -> bool:
    """The first cell that is not known empty on the laser from ``src`` through ``aim`` is known full."""
    ray = np.asarray(aim, dtype=float) - src
    d = ray / np.hypot(*ray)
    far = src + min(rf.depth_window_cells()[1] + 2.0, float(m.shape[0] + m.shape[1])) * d
    bi, bj = first_blocking(m != EMPTY, src, far)
    return bi >= 0 and m[bi, bj] == FULL


def orbit_motion_to(rf, orbit: OrbitState, cell, current_source) -> float:
    """Predicted source motion (cells) until the orbit's laser aims at the unit-circle point towards ``cell``.

    The laser of step ``k`` aims at ``pp + u(theta_k + rotation * 90 deg)`` (:func:`plan_s2`), so ``cell`` is aimed
    at once ``theta_k`` has turned to ``atan2(cell - pp) - rotation * 90 deg``: the motion is the move from
    ``current_source`` to the first orbit pose plus the arc (radius standoff) of the remaining steps. ``inf`` when the
    orbit gives up before that angle. ``orbit`` is not advanced."""
    centre = np.asarray(orbit.centre, dtype=float)
    rel = np.asarray(cell, dtype=float) - centre
    target = math.atan2(rel[1], rel[0]) - orbit.rotation * math.pi / 2
    turn = (orbit.rotation * (target - orbit.theta0_rad)) % (2 * math.pi)
    k = max(1, math.ceil(turn / orbit.step_rad - 1e-9))
    if k > orbit.n_steps:
        return math.inf
    theta1 = orbit.theta0_rad + orbit.rotation * (orbit.k + 1) * orbit.step_rad
    first = centre + rf.standoff_cells * np.array([math.cos(theta1), math.sin(theta1)])
    lead_in = 0.0 if current_source is None else float(np.hypot(*(first - np.asarray(current_source, dtype=float))))
    chord = 2 * rf.standoff_cells * math.sin(orbit.step_rad / 2)
    return lead_in + chord * max(k - (orbit.k + 1), 0)


def plan_s2(rf, orbit: OrbitState, m: np.ndarray | None = None) -> Plan | NoView:
    """Strategy 2: orbit the growth point and test the points of the unit circle around it.

    Documented choice (the report's Fig. 9 is lost): the source moves on the circle of radius standoff around
    ``pp``, starting on the outward normal and turning towards the contour's continuation by ``step`` per measurement;
    the laser aims at the unit-circle point ``q = pp + u(theta + 90 deg)`` on the turning side, so it passes one
    cell beside ``pp``: an empty ``q`` lets it pass (D2, normal) while a surface continuing round a sharp corner is
    struck (A2). The camera goes to the side away from ``pp``. Visibility is not checked, as in the report.

    With the model ``m`` (documented choice), a step whose laser can only give a D2 is passed over without
    measuring: the first cell on the laser from the source that is not known empty is known full (``q`` known empty
    included), so the return can only come from an already seen cell. The source then goes straight to the next
    step that may teach something, a chord instead of the arc.
    """
    centre = np.asarray(orbit.centre, dtype=float)
    while True:
        orbit.k += 1
        if orbit.k > orbit.n_steps:
            return NoView("full_turn")
        theta = orbit.theta0_rad + orbit.rotation * orbit.k * orbit.step_rad
        src = centre + rf.standoff_cells * np.array([math.cos(theta), math.sin(theta)])
        side_ang = theta + orbit.rotation * math.pi / 2
        q = centre + np.array([math.cos(side_ang), math.sin(side_ang)])
        if m is None or not _laser_sees_only_known_full(m, src, q, rf):
            break
    poses = [rf.pose_through(src, q, side) for side in (1, -1)]
    if orbit.camera == "leading":
        # the camera ahead of the source in the sense of the turn, facing the surface the orbit is looking for
        rel_s = src - centre
        lead = [orbit.rotation * float(rel_s[0] * (p[1] - centre)[1] - rel_s[1] * (p[1] - centre)[0]) for p in poses]
        best = poses[int(np.argmax(lead))]
    else:
        best = max(poses, key=lambda p: float(np.hypot(*(p[1] - centre))))
    return Plan(best, None, 1.0)
