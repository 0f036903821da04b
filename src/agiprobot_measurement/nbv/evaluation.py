"""Run metrics: the measurable boundary (brute force), coverage, path, transfers and the JSON summary.

*Boundary* cells are full cells of the ground truth with an empty 4-neighbour (an exposed edge). A boundary cell
is *measurable* when some valid pose sees it: a laser line in one of ``n_directions`` directions, through one of a
few points across the cell, whose first hit is the cell, with the source at the standoff from the hit (so the hit
sits on the camera's central line; the sources form a ring at the standoff around the body) and a camera, on
either side, whose return path touches no other full cell. Coverage is the fraction of measurable cells that the
model holds as full: the planner is judged only on what the sensor could see at all.

A *transfer* is a sensor move (source displacement between consecutive measurements) longer than three times the
median move; moves of zero length (re-measuring from the same place) are left out of the median.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from .grid import EMPTY, FULL, dilate4
from .traversal import _segment_box_entry, _supercover_first

__all__ = ["boundary_cells", "coverage", "measurable_boundary", "path_metrics", "summarize"]


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
