"""Run metrics: the measurable boundary (brute force), coverage, path, transfers and the JSON summary.

*Boundary* cells are full cells of the ground truth with an empty 4-neighbour (an exposed edge). A boundary cell
is *measurable* when some valid pose sees it: a laser line in one of ``n_directions`` directions, through one of a
few points across the cell, whose first hit is the cell, with the source at the standoff from the hit (so the hit
sits on the camera's central line; the sources form a ring at the standoff around the body) and a camera, on
either side, whose return path touches no other full cell. Coverage is the fraction of measurable cells that the
model holds as full: the planner is judged only on what the sensor could see at all.

The *plannable* boundary (:func:`plannable_boundary`, the benchmark's denominator) is
the part of it that a view *planned onto the cell* can see, the way the report plans: the laser through one of the
cell's aim points (its centre, or the four edge midpoints with the section 7.1 remedy), the source at the standoff
from that point in one of the 360 sector directions, the camera on either side, both sectors free in the circle of
visibility built at the aim point from the ground truth, and the real measurement (:func:`.range_finder.scan`:
first hit the cell, in the camera's field, return free) returning the cell. The report says of its own planner
(section 7.1) that "views are planned onto cell centres" and that beyond some laser-camera angle some points "can
no longer be reached by any planned view": the measurable set above counts those points, which the centre-aiming
planner can only ever hit as a side effect of a view planned onto another cell (U-shape, RFlength 40: 134 of the
692 measurable cells; RFlength 250: the slot's two 14-cell walls, whose 41 deg free window at the centres is
narrower than the 54 deg laser-camera angle). Every view counted is one the planner can take: the truth's full
cells include the model's, so a sector free in the truth's circle is free in the model's circle too. Both figures
are reported (``coverage`` on the plannable set, ``coverage_any_ray`` on the measurable set).

A *transfer* is a sensor move (source displacement between consecutive measurements) longer than three times the
median move; moves of zero length (re-measuring from the same place) are left out of the median.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from agiprobot_measurement.nbv.planar.grid import EMPTY, FULL, dilate4
from agiprobot_measurement.nbv.planar.scoring import aim_points
from agiprobot_measurement.nbv.planar.traversal import _segment_box_entry, _supercover_first
from agiprobot_measurement.nbv.planar.visibility import N_SECTORS, _block, cell_sector_spans, sector_of

__all__ = ["boundary_cells", "coverage", "measurable_boundary", "path_metrics", "plannable_boundary", "summarize"]


def boundary_cells(truth: np.ndarray) -> np.ndarray:
    """Full ground-truth cells with an empty 4-neighbour (k x 2)."""
    t = np.asarray(truth)
    return np.argwhere((t == FULL) & dilate4(t == EMPTY))


@numba.njit(cache=True)
def _measurable_kernel(full, cells, n_dirs, offsets, standoff, length, alpha, out):
    nx, ny = full.shape
    reach = float(nx + ny)
    for q in range(cells.shape[0]):
        ci = cells[q, 0]
        cj = cells[q, 1]
        found = False
        for di in range(n_dirs):
            if found:
                break
            phi = 2.0 * math.pi * (di + 0.5) / n_dirs
            ux = math.cos(phi)
            uy = math.sin(phi)
            half = 0.5 * (abs(ux) + abs(uy))
            for o in offsets:
                px = ci - o * half * uy
                py = cj + o * half * ux
                fx = px + reach * ux
                fy = py + reach * uy
                bi, _ = _supercover_first(full, px, py, fx, fy, ci, cj)
                if bi >= 0:
                    continue
                t = _segment_box_entry(fx, fy, px, py, ci, cj)
                if t < 0:
                    continue
                hx = fx + t * (px - fx)
                hy = fy + t * (py - fy)
                sx = hx + standoff * ux
                sy = hy + standoff * uy
                for side in (1.0, -1.0):
                    ang = phi + math.pi + side * alpha
                    cx = sx + length * math.cos(ang)
                    cy = sy + length * math.sin(ang)
                    ri, _ = _supercover_first(full, hx, hy, cx, cy, ci, cj)
                    if ri < 0:
                        found = True
                        break
                if found:
                    break
        out[q] = found


def measurable_boundary(truth: np.ndarray, rf, n_directions: int = 720, n_offsets: int = 3) -> np.ndarray:
    """Boolean grid of the measurable boundary cells (see the module docstring); brute force over poses."""
    t = np.asarray(truth)
    cells = boundary_cells(t).astype(np.int64)
    offsets = np.linspace(-0.6, 0.6, n_offsets) if n_offsets > 1 else np.zeros(1)
    out = np.zeros(len(cells), dtype=np.bool_)
    _measurable_kernel(
        np.ascontiguousarray(t == FULL),
        cells,
        int(n_directions),
        offsets,
        float(rf.standoff_cells),
        float(rf.rf_length_cells),
        float(rf.rf_alpha_rad),
        out,
    )
    mask = np.zeros(t.shape, dtype=bool)
    mask[cells[out, 0], cells[out, 1]] = True
    return mask


@numba.njit(cache=True)
def _any_pose_returns(full, poses, ci, cj, standoff, half_gamma):
    """True when one of ``poses`` (n x 3 x 2) measures cell (ci, cj) on ``full``: the rules of ``scan``."""
    nx, ny = full.shape
    for q in range(poses.shape[0]):
        sx, sy = poses[q, 0, 0], poses[q, 0, 1]
        cx, cy = poses[q, 1, 0], poses[q, 1, 1]
        ax, ay = poses[q, 2, 0], poses[q, 2, 1]
        n = math.hypot(ax - sx, ay - sy)
        dx, dy = (ax - sx) / n, (ay - sy) / n
        reach = math.hypot(sx, sy) + nx + ny + 2.0
        fx, fy = sx + reach * dx, sy + reach * dy
        hi, hj = _supercover_first(full, sx, sy, fx, fy, -1, -1)
        if hi != ci or hj != cj:
            continue
        t = _segment_box_entry(sx, sy, fx, fy, ci, cj)
        if t < 0:
            continue
        hx, hy = sx + t * (fx - sx), sy + t * (fy - sy)
        vx, vy = hx - cx, hy - cy
        wx, wy = sx + standoff * dx - cx, sy + standoff * dy - cy
        c = (vx * wx + vy * wy) / (math.hypot(vx, vy) * math.hypot(wx, wy) + 1e-300)
        if math.acos(max(-1.0, min(1.0, c))) > half_gamma:
            continue
        if _supercover_first(full, hx, hy, cx, cy, ci, cj)[0] < 0:
            return True
    return False


def plannable_boundary(truth: np.ndarray, rf, aim: str = "centre") -> np.ndarray:
    """Boolean grid of the boundary cells that a view planned onto the cell sees (see the module docstring).

    ``aim`` is the planner's aim (``"centre"`` or ``"edge_midpoints"``). Only boundary cells are opaque in the
    circles: a wedge cannot reach an interior cell without touching a boundary cell first.
    """
    t = np.asarray(truth)
    full = np.ascontiguousarray(t == FULL)
    cells = boundary_cells(t)
    phi = np.radians(np.arange(N_SECTORS) + 0.5)
    phis = np.repeat(phi, 2)
    sides = np.tile(np.array([1.0, -1.0]), N_SECTORS)
    mask = np.zeros(t.shape, dtype=bool)
    others = np.ones(len(cells), dtype=bool)
    for q, cell in enumerate(cells):
        others[q] = False
        opaque = cells[others]
        others[q] = True
        for xs in aim_points(cell, aim):
            circ = np.ones(N_SECTORS, dtype=np.uint8)
            _block(circ, *cell_sector_spans(xs, opaque))
            free = circ > 0
            if not free.any():
                continue
            poses = rf.poses(xs, phis, sides)
            cam_dir = np.arctan2(poses[:, 1, 1] - xs[1], poses[:, 1, 0] - xs[0])
            ok = free[np.arange(2 * N_SECTORS) // 2] & free[sector_of(cam_dir)]
            if ok.any() and _any_pose_returns(
                full, np.ascontiguousarray(poses[ok]), int(cell[0]), int(cell[1]), float(rf.standoff_cells),
                float(rf.fr_gamma_rad) / 2,
            ):  # fmt: skip
                mask[cell[0], cell[1]] = True
                break
    return mask


def coverage(model: np.ndarray, measurable: np.ndarray) -> float:
    """Fraction of measurable cells the model holds as full (1.0 when nothing is measurable)."""
    n = int(measurable.sum())
    return 1.0 if n == 0 else float(((np.asarray(model) == FULL) & measurable).sum() / n)


def path_metrics(sources: np.ndarray) -> dict:
    """Path length, moves, the transfers (moves > 3 x median move) and their length; all in cells."""
    s = np.asarray(sources, dtype=float).reshape(-1, 2)
    steps = np.hypot(*np.diff(s, axis=0).T) if len(s) > 1 else np.zeros(0)
    moving = steps[steps > 1e-9]
    median = float(np.median(moving)) if len(moving) else 0.0
    is_transfer = steps > 3.0 * median if median > 0 else np.zeros(len(steps), dtype=bool)
    return {
        "path_length_cells": float(steps.sum()),
        "median_move_cells": median,
        "transfers": int(is_transfer.sum()),
        "transfer_length_cells": float(steps[is_transfer].sum()),
        "transfer_mask": is_transfer,
    }


def summarize(result, measurable: np.ndarray, object_name: str) -> dict:
    """The JSON-ready summary of one run."""
    pm = path_metrics(result.sources)
    model = result.model
    truth = result.truth
    full_model = model == FULL
    n_full = int(full_model.sum())
    cfg = result.config
    rf = result.rf
    return {
        "object": object_name,
        "script": cfg.script,
        "aim": cfg.aim,
        "noise_sigma_cells": cfg.noise_sigma_cells,
        "seed": cfg.seed,
        "rf_length_cells": rf.rf_length_cells,
        "rf_alpha_rad": rf.rf_alpha_rad,
        "rf_beta_rad": rf.rf_beta_rad,
        "fr_gamma_rad": rf.fr_gamma_rad,
        "standoff_cells": rf.standoff_cells,
        "triangulation_angle_deg": math.degrees(rf.triangulation_angle_rad),
        "boundary_cells": len(boundary_cells(truth)),
        "measurable_cells": int(measurable.sum()),
        "covered_cells": int((full_model & measurable).sum()),
        "coverage": coverage(model, measurable),
        "model_full_cells": n_full,
        "false_full_cells": int((full_model & (truth != FULL)).sum()),
        "measurements": len(result.records),
        "path_length_cells": pm["path_length_cells"],
        # the camera's own path (the rig turning about the laser moves the camera, not the source)
        "camera_path_length_cells": path_metrics(result.cameras)["path_length_cells"],
        "median_move_cells": pm["median_move_cells"],
        "transfers": pm["transfers"],
        "transfer_length_cells": pm["transfer_length_cells"],
        "d0_count": result.d0_count,
        "unmeasurable_candidates": len(result.unmeasurable),
        "termination": result.termination,
        "run_time_s": result.run_time_s,
        "outcomes": dict(sorted(result.outcomes.items())),
    }
