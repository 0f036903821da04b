"""Generated 2D bodies to generalise over: five families at random parameters, fixed seeds, a tuning and a held-out
evaluation half.

Every body lives on the 400 x 400 grid of :mod:`.objects` (1 cell = 1 mm), centred, within a radius of 130 cells,
rasterised by cell centre. The families are the shapes that broke planners tuned on the six substitutes:

==========  ===========================================================================================
``star``    4-7 spikes, outer radius 80-125, inner radius 0.30-0.55 of it: tip angles of 15-60 degrees
``comb``    a bar 140-200 long with 3-5 teeth 8-18 wide and 40-80 long (deep, narrow gaps)
``spiral``  an arm 14-24 thick wound 1.1-1.6 turns (a concave channel that closes on itself)
``poly``    a star-shaped random polygon of 5-11 vertices at radii 45-125 (random acute and reflex corners)
``blob``    a smooth radius function with 2-5 harmonics (mild curvature, shallow concavities)
==========  ===========================================================================================

Names are ``<family>_<k>`` with ``k`` = 0..5; the parameters of a name come from ``numpy.random.default_rng((SEED,
family, k))``, so a name is the same body on every machine. Even ``k`` is the tuning half, odd ``k`` the evaluation
half (every family in both). ``star5`` is the fixed regular five-pointed star with acute spikes (radii 60 / 120),
the body nobody tuned on that exposed the edge-midpoint collapse; it belongs to neither half.
"""

from __future__ import annotations

import math

import numpy as np

from agiprobot_measurement.nbv.planar.errors import NbvInputError
from agiprobot_measurement.nbv.planar.grid import validate_truth
from agiprobot_measurement.nbv.planar.objects import GRID_SHAPE, OBJECT_NAMES, make_object, polygon_mask

__all__ = ["FAMILIES", "FAMILY_SETS", "SEED", "family_bodies", "make_body", "star_vertices"]

#: the generator's seed: changing it changes every body (and invalidates every figure measured on the family)
SEED = 20261207
FAMILIES = ("star", "comb", "spiral", "poly", "blob")
PER_FAMILY = 6
FAMILY_SETS = ("tuning", "evaluation", "all")


def family_bodies(which: str = "evaluation") -> list[str]:
    """The names of one half (``tuning``: even k, ``evaluation``: odd k) or ``all``, family by family."""
    if which not in FAMILY_SETS:
        raise NbvInputError(f"unknown body set {which!r}; one of {', '.join(FAMILY_SETS)}")
    keep = {"tuning": (0,), "evaluation": (1,), "all": (0, 1)}[which]
    return [f"{f}_{k}" for f in FAMILIES for k in range(PER_FAMILY) if k % 2 in keep]


def star_vertices(points: int, r_out: float, r_in: float, phase_rad: float = 0.0, centre=None) -> np.ndarray:
    """The 2 ``points`` vertices of a star (outer radius ``r_out``, inner ``r_in``, cells), first tip at
    ``phase_rad``."""
    cx, cy = centre if centre is not None else ((GRID_SHAPE[0] - 1) / 2, (GRID_SHAPE[1] - 1) / 2)
    a = phase_rad + np.arange(2 * points) * math.pi / points
    r = np.where(np.arange(2 * points) % 2 == 0, r_out, r_in)
    return np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)])


def _centre():
    return (GRID_SHAPE[0] - 1) / 2, (GRID_SHAPE[1] - 1) / 2


def _star(rng) -> np.ndarray:
    n = int(rng.integers(4, 8))
    r_out = rng.uniform(80, 125)
    return star_vertices(n, r_out, r_out * rng.uniform(0.30, 0.55), rng.uniform(0, 2 * math.pi))


def _comb(rng) -> np.ndarray:
    cx, cy = _centre()
    teeth = int(rng.integers(3, 6))
    length, bar = rng.uniform(140, 200), rng.uniform(25, 40)
    width = rng.uniform(8, 18)
    tooth_len = rng.uniform(40, 80)
    x0, y0 = -length / 2, -(bar + tooth_len) / 2
    pts = [(x0, y0), (x0 + length, y0), (x0 + length, y0 + bar)]
    xs = np.linspace(x0 + length - width, x0, teeth)  # teeth from the right end to the left end, gaps between
    for x in xs:
        pts += [(x + width, y0 + bar), (x + width, y0 + bar + tooth_len), (x, y0 + bar + tooth_len), (x, y0 + bar)]
    pts.append((x0, y0 + bar))
    angle = rng.uniform(0, 2 * math.pi)
    c, s = math.cos(angle), math.sin(angle)
    p = np.asarray(pts) @ np.array([[c, s], [-s, c]])
    return p + np.array([cx, cy])


def _spiral(rng) -> np.ndarray:
    cx, cy = _centre()
    thick = rng.uniform(14, 24)
    turns = rng.uniform(1.1, 1.6)
    r0 = rng.uniform(25, 35)
    pitch = rng.uniform(2.6, 3.4) * thick  # the gap between the windings is 1.6-2.4 arm widths
    t = np.linspace(0, 2 * math.pi * turns, 160)
    r = r0 + pitch * t / (2 * math.pi)
    scale = min(1.0, 125.0 / (r[-1] + thick / 2))
    r, thick_s = r * scale, thick * scale
    a = t + rng.uniform(0, 2 * math.pi)
    outer = np.column_stack([(r + thick_s / 2) * np.cos(a), (r + thick_s / 2) * np.sin(a)])
    inner = np.column_stack([(r - thick_s / 2) * np.cos(a), (r - thick_s / 2) * np.sin(a)])
    return np.vstack([outer, inner[::-1]]) + np.array([cx, cy])


def _poly(rng) -> np.ndarray:
    cx, cy = _centre()
    k = int(rng.integers(5, 12))
    a = np.sort(rng.uniform(0, 2 * math.pi, k))
    a = a[np.concatenate([[True], np.diff(a) > 0.25])]  # no two vertices within 14 degrees (no slivers)
    r = rng.uniform(45, 125, len(a))
    return np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)])


def _blob(rng) -> np.ndarray:
    cx, cy = _centre()
    t = np.linspace(0, 2 * math.pi, 240, endpoint=False)
    r = np.ones_like(t)
    for h in range(2, 6):
        r += rng.uniform(0.0, 0.22 / h**0.5) * np.cos(h * t + rng.uniform(0, 2 * math.pi))
    r *= rng.uniform(70, 115) / r.max()
    return np.column_stack([cx + r * np.cos(t), cy + r * np.sin(t)])


_MAKERS = {"star": _star, "comb": _comb, "spiral": _spiral, "poly": _poly, "blob": _blob}


def make_body(name: str) -> np.ndarray:
    """The ground truth (FULL 1 / EMPTY -1, 400 x 400) of a generated body, ``star5``, or a named substitute of
    :mod:`.objects`."""
    if name in OBJECT_NAMES:
        return make_object(name)
    if name == "star5":
        return validate_truth(polygon_mask(GRID_SHAPE, star_vertices(5, 120.0, 60.0, math.pi / 2)), name)
    family, _, index = name.rpartition("_")
    if family not in _MAKERS or not index.isdigit() or int(index) >= PER_FAMILY:
        known = ", ".join([*OBJECT_NAMES, "star5", *family_bodies("all")])
        raise NbvInputError(f"unknown body {name!r}; one of {known}")
    rng = np.random.default_rng((SEED, FAMILIES.index(family), int(index)))
    return validate_truth(polygon_mask(GRID_SHAPE, _MAKERS[family](rng)), name)
