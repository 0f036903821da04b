"""Re-acquisition once the growth points are exhausted: sweeps round the known body (:func:`reacquire_sweep`), then
views onto the frontier next to it (:func:`reacquire_frontier`), both run on the loop's engine (:mod:`.loop`).

Frontier views: views onto the unknown cells that border known empty space, planned on the model only.

Once the growth points are exhausted (and the sweeps round the body found nothing new) the contour-following chain
may still have left boundary behind: both ends stopped at acute spike tips, the teeth of a comb hid the gap between
them from every view planned along the contour, or with edge-midpoint aiming the expansion lost the contour after
one feature. The planner does not know where the body continues, but its own model shows where it *could*: an
unknown cell next to a known empty one (a *frontier* cell) is either air nobody has looked through yet or a piece of
surface nobody has seen. Near the known body (within ``max_distance_cells`` of a known full cell) such cells are
where the unseen boundary must lie.

A frontier cell is planned like strategy 0 plans a candidate: both the laser's and the camera's sector free of
known full cells in the circle of visibility at the aim point, the predicted return free, scored by Viditelnost x
Kolmost x Pohyb, with the mean direction to the cell's known empty neighbours as the outward direction (Kolmost and
the camera-in-front rule). Unknown cells on the way are taken as air, as the circle of visibility does: should the
laser strike one, that is new surface as well; should the frontier cell be air, the laser carves it and the
frontier moves on. Requiring the laser to cross known empty cells only (tried first) planned almost nothing: the
known empty space round a body is a fan of single carved rays with unknown cells between them. The planner never
uses the ground truth.

Cells are tried nearest to the known body first; one whose view is unplannable or whose measurement taught nothing
is not tried again.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import distance_transform_edt

from agiprobot_measurement.nbv.planar.grid import EMPTY, FULL, UNKNOWN, dilate4
from agiprobot_measurement.nbv.planar.scoring import ScoreConfig, aim_points, score_views
from agiprobot_measurement.nbv.planar.strategies import NoView, Plan, predicted_return_free
from agiprobot_measurement.nbv.planar.traversal import first_blocking
from agiprobot_measurement.nbv.planar.visibility import N_SECTORS, _block, cell_sector_spans

__all__ = [
    "frontier_normal",
    "frontier_targets",
    "is_frontier_cell",
    "plan_frontier_view",
    "reacquire_frontier",
    "reacquire_sweep",
]

_NEIGHBOURS8 = np.array([(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)])


def frontier_targets(m: np.ndarray, tried: np.ndarray, max_distance_cells: float, near=None) -> np.ndarray:
    """Unknown cells 4-adjacent to a known empty cell, within ``max_distance_cells`` of a known full cell and not
    ``tried``, nearest to the known body first (ties: nearest to ``near``); k x 2."""
    full = m == FULL
    if not full.any():
        return np.zeros((0, 2), dtype=int)
    front = (m == UNKNOWN) & dilate4(m == EMPTY) & ~tried
    dist = distance_transform_edt(~full)
    cells = np.argwhere(front & (dist <= max_distance_cells))
    if len(cells) == 0:
        return cells
    d_body = np.round(dist[cells[:, 0], cells[:, 1]], 6)
    d_near = np.zeros(len(cells)) if near is None else np.hypot(*(cells - np.asarray(near, dtype=float)).T)
    return cells[np.lexsort((d_near, d_body))]


def is_frontier_cell(m: np.ndarray, cell) -> bool:
    """``cell`` is unknown and 4-adjacent to a known empty cell."""
    i, j = int(cell[0]), int(cell[1])
    if m[i, j] != UNKNOWN:
        return False
    nb = [(i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1)]
    return any(0 <= a < m.shape[0] and 0 <= b < m.shape[1] and m[a, b] == EMPTY for a, b in nb)


def frontier_normal(m: np.ndarray, cell) -> np.ndarray | None:
    """The mean unit direction from ``cell`` to its known empty 8-neighbours (None when it has none)."""
    nb = np.asarray(cell) + _NEIGHBOURS8
    ok = (nb[:, 0] >= 0) & (nb[:, 0] < m.shape[0]) & (nb[:, 1] >= 0) & (nb[:, 1] < m.shape[1])
    nb, off = nb[ok], _NEIGHBOURS8[ok].astype(float)
    off = off[m[nb[:, 0], nb[:, 1]] == EMPTY]
    if len(off) == 0:
        return None
    v = (off / np.hypot(*off.T)[:, None]).sum(axis=0)
    n = float(np.hypot(*v))
    return None if n < 1e-9 else v / n


def _circle(xs, opaque_cells: np.ndarray) -> np.ndarray:
    circ = np.ones(N_SECTORS, dtype=np.uint8)
    _block(circ, *cell_sector_spans(xs, opaque_cells))
    return circ


def plan_frontier_view(
    m: np.ndarray,
    rf,
    cell,
    aims: np.ndarray,
    full_cells: np.ndarray,
    current_source,
    cfg: ScoreConfig,
    max_checks: int = 20,
) -> Plan | NoView:
    """The best view of the frontier cell ``cell`` (see the module docstring): both sectors free of known full cells
    in the circle of visibility of the aim point, the return from the laser's entry into ``cell`` touching no known
    full cell (:func:`.strategies.predicted_return_free`)."""
    c = (int(cell[0]), int(cell[1]))
    circles = np.stack([_circle(xs, full_cells) for xs in aims])
    views = score_views(rf, aims, circles, frontier_normal(m, c), current_source, cfg)
    full = m == FULL
    for idx in views.ranked()[:max_checks]:
        pos = views.poses[idx]
        if predicted_return_free(full, pos, c):
            key = (int(views.aim_index[idx]), int(views.sector[idx]), int((1 - views.side[idx]) // 2))
            return Plan(pos, key, float(views.score[idx]))
    return NoView("unplannable")


def reacquire_frontier(eng) -> str:
    """The frontier pass of the loop's engine ``eng`` (:mod:`.loop`): views onto the frontier next to the known body until none is left (:mod:`.reacquisition`; the run's
    aim points plus the centre); every hit that leaves growth points starts an expansion. The frontier list is
    built once and worked through (cells that stopped being frontier are passed over) and rebuilt when it runs
    out or a view added full cells."""
    cfg = eng.cfg
    tried = np.zeros(eng.shape, dtype=bool)
    near = None
    views = 0
    aim_modes = ("centre",) if cfg.aim == "centre" else (cfg.aim, "centre")
    queue: list = []
    full_cells = None
    n_full = -1
    while views < cfg.reacquire_frontier_max_views:
        if int(np.count_nonzero(eng.m == FULL)) != n_full:
            queue, n_full = [], int(np.count_nonzero(eng.m == FULL))
            full_cells = np.argwhere(eng.m == FULL)
        if not queue:
            # the frontier near the known body lies within the known cells' box widened by the distance bound
            i0, i1, j0, j1 = eng.window(math.ceil(cfg.reacquire_frontier_max_distance_cells) + 1)
            offset = np.array([i0, j0])
            targets = frontier_targets(
                eng.m[i0:i1, j0:j1], tried[i0:i1, j0:j1], cfg.reacquire_frontier_max_distance_cells,
                None if near is None else np.asarray(near) - offset,
            ) + offset  # fmt: skip
            if len(targets) == 0:
                return "growth_points_exhausted"
            queue = [(int(c[0]), int(c[1])) for c in targets[::-1]]
        target = queue.pop()
        tried[target] = True
        if not is_frontier_cell(eng.m, target):
            continue
        aims = np.vstack([aim_points(target, a) for a in aim_modes])
        plan = plan_frontier_view(eng.m, eng.rf, target, aims, full_cells, eng.current_source, cfg.score)
        if isinstance(plan, NoView):
            continue
        views += 1
        _, hit, _ = eng.measure(plan.pos, target, None, "reacquire: frontier view")
        near = target
        if hit is not None and len(eng.growth_points()):
            eng.outcomes["reacquire: frontier contour"] += 1
            reason = eng.expand_with_reopening(hit)
            if reason != "growth_points_exhausted":
                return reason
    eng.outcomes["reacquire: frontier view budget"] += 1
    return "growth_points_exhausted"


def reacquire_sweep(eng) -> str:
    """One sweep of the loop's engine ``eng`` round the known body (see ``RunConfig.reacquire_sweeps``): per direction, sources on rings at the
    standoff beyond the known cells' radius (and half that radius nearer) round the known cells' centre, then
    round the scene centre, the laser through the ring's centre, either camera side, until one measures; a view is
    taken only where the laser's first cell that is not known empty is unknown (otherwise it could only return a seen cell). Every
    hit that leaves growth points starts an expansion."""
    rf, cfg = eng.rf, eng.cfg
    # rings round the known cells' centre and round the scene centre (where the a-priori search expects the
    # body), each reaching the known cells: with only a spike tip known, the first ring lies inside the body
    full = np.argwhere(eng.m == FULL).astype(float)
    rings = []
    for centre in (full.mean(axis=0), (np.array(eng.shape, dtype=float) - 1) / 2):
        radius = float(np.sqrt(((full - centre) ** 2).sum(axis=1).max()))
        rings += [(centre, radius), (centre, 0.5 * radius)]
    reach = float(eng.shape[0] + eng.shape[1])
    reason = "growth_points_exhausted"
    eng.outcomes["reacquire: sweep"] += 1
    for psi in np.arange(0.0, 360.0, cfg.reacquire_step_deg):
        u = np.array([math.cos(math.radians(psi)), math.sin(math.radians(psi))])
        for centre, ring in rings:
            src = centre + (ring + rf.standoff_cells) * u
            if not (0 <= src[0] <= eng.shape[0] - 1 and 0 <= src[1] <= eng.shape[1] - 1):
                continue
            bi, bj = first_blocking(eng.m != EMPTY, src, src - reach * u)
            if bi < 0 or eng.m[bi, bj] != UNKNOWN:
                continue
            hit = None
            for side in (1, -1):
                _, hit, _ = eng.measure(rf.pose_through(src, centre, side), None, None)
                if hit is not None:
                    break
            if hit is None:
                continue
            if len(eng.growth_points()):
                eng.outcomes["reacquire: new contour"] += 1
                reason = eng.expand_with_reopening(hit)
                if reason != "growth_points_exhausted":
                    return reason
            break
    return reason
