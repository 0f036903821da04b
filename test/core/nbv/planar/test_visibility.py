"""The circle of visibility against an independent brute force, after incremental updates."""

import math

import numpy as np

from agiprobot_measurement.nbv.planar.grid import EMPTY, FULL, UNKNOWN
from agiprobot_measurement.nbv.planar.visibility import make_circle_of_visibility, update_circ


def _ray_hits_square(xs, ang, c):
    """Slab test: does the ray from xs in direction ang touch the closed square of cell c."""
    d = np.array([math.cos(ang), math.sin(ang)])
    t0, t1 = 0.0, np.inf
    for a in range(2):
        lo, hi = c[a] - 0.5, c[a] + 0.5
        if abs(d[a]) < 1e-15:
            if not lo <= xs[a] <= hi:
                return False
            continue
        ta, tb = sorted(((lo - xs[a]) / d[a], (hi - xs[a]) / d[a]))
        t0, t1 = max(t0, ta), min(t1, tb)
    return t0 <= t1


def _brute(w, xs, samples=24):
    """Sector k blocked iff some sampled ray inside [k, k+1) degrees touches a full cell."""
    full = [tuple(c) for c in np.argwhere(w == FULL)]
    blocked = np.zeros(360, dtype=bool)
    for k in range(360):
        for s in range(samples):
            ang = math.radians(k + (s + 0.5) / samples)
            if any(_ray_hits_square(xs, ang, c) for c in full):
                blocked[k] = True
                break
    return blocked


def test_circle_matches_brute_force_after_incremental_updates():
    rng = np.random.default_rng(3)
    w = np.full((14, 14), UNKNOWN)
    w[rng.random(w.shape) < 0.5] = EMPTY
    xs = np.array([6.23, 7.41])
    w[6, 7] = UNKNOWN  # the reference cell
    start = rng.choice(np.argwhere(w == EMPTY), 4, replace=False)
    for c in start:
        w[tuple(c)] = FULL
    circ = make_circle_of_visibility(w, xs)
    for c in rng.choice(np.argwhere((w == EMPTY) | (w == UNKNOWN)), 6, replace=False):
        if tuple(c) == (6, 7):
            continue
        w[tuple(c)] = FULL
        circ = update_circ(circ, xs, c)
        np.testing.assert_array_equal(circ, make_circle_of_visibility(w, xs))
    blocked = circ == 0
    brute = _brute(w, xs)
    assert (brute <= blocked).all()  # whatever a ray finds blocked is blocked
    # the closed-square rule may block a sector the samples miss only where a span ends next to its boundary
    extra = np.flatnonzero(blocked & ~brute)
    assert all(brute[(k - 1) % 360] or brute[(k + 1) % 360] for k in extra)
    assert 0 < blocked.sum() < 360


def test_single_cell_span_and_block_unknown():
    w = np.full((9, 9), EMPTY)
    w[6, 4] = FULL  # seen from (4, 4): spans atan2(+-0.5, 1.5) .. atan2(+-0.5, 2.5)
    circ = make_circle_of_visibility(w, np.array([4.0, 4.0]))
    half = math.degrees(math.atan2(0.5, 1.5))
    assert (circ == 0).sum() == 2 * math.ceil(half)
    assert circ[0] == 0 and circ[359] == 0 and circ[180] == 1
    w2 = np.full((9, 9), UNKNOWN)
    w2[4, 4] = UNKNOWN  # the candidate's own cell never blocks
    assert make_circle_of_visibility(w2, np.array([4.0, 4.0])).all()
    assert not make_circle_of_visibility(w2, np.array([4.0, 4.0]), block_unknown=True).any()
