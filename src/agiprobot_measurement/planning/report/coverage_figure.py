"""A picture of a measurement plan's predicted coverage (PNG, no display needed).

:func:`plot_coverage` draws the sampled surface points coloured as in the original documentation (Fig. 2.1):
red = not measurable by the plan, green = measured at low uncertainty, blue = at high uncertainty (a colormap
between ``u_min`` and ``u_max``, with a colorbar in mm), and the plan's scan lines (laser_emitter_frame, mm)
as thick numbered segments with a marker where each scan starts and an arrowhead where it ends. Two views
from opposite sides show the whole part; axes are scaled equally so the part is not distorted.

Only matplotlib's object API with the Agg canvas is used (never pyplot), so importing this module does not
touch the process-wide backend and works without a display, also inside ROS nodes.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.cm import ScalarMappable
from matplotlib.colors import LinearSegmentedColormap, Normalize, to_rgba
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from agiprobot_measurement.common.files import atomic_write
from agiprobot_measurement.planning.errors import PlanningInputError

__all__ = [
    "DEFAULT_VIEWS",
    "MAX_MESH_FACES",
    "NOT_EXECUTABLE_COLOR",
    "NOT_MEASURABLE_COLOR",
    "NOT_PLANNED_COLOR",
    "SCAN_LINE_COLORS",
    "UNCERTAINTY_CMAP",
    "plot_coverage",
]

#: Low uncertainty -> high uncertainty (green -> teal -> blue), as in the documentation's figure.
UNCERTAINTY_CMAP = LinearSegmentedColormap.from_list("coverage_uncertainty", ["#1a9641", "#1f9e9a", "#2c4fc7"])
NOT_MEASURABLE_COLOR = "#d7191c"
#: measurable by the sensor model from some candidate view, but no such view's scan line can be driven
NOT_EXECUTABLE_COLOR = "#e7298a"
#: measurable by an executable view, but the plan does not (views left out, time limit)
NOT_PLANNED_COLOR = "#ff9f1c"
# Scan line colours avoid red, green and blue, which already mean something in this figure.
SCAN_LINE_COLORS = ("#ff7f0e", "#7b3294", "#8c564b", "#e377c2", "#404040", "#bcbd22", "#c2a5cf", "#000000")
#: (elevation, azimuth) in degrees of the two panels: from the front left and from the back right.
DEFAULT_VIEWS = ((28.0, -60.0), (28.0, 120.0))
# More faces than this make the translucent mesh slow to draw and add nothing readable; they are skipped.
MAX_MESH_FACES = 20_000


def _as_points(points_mm) -> np.ndarray:
    points = np.asarray(points_mm, dtype=float)
    if points.size == 0:
        return np.zeros((0, 3))
    if points.ndim != 2 or points.shape[1] != 3:
        raise PlanningInputError(f"points_mm must have shape (N, 3), got {points.shape}")
    if not np.all(np.isfinite(points)):
        raise PlanningInputError("points_mm contains NaN or infinite coordinates")
    return points


def _as_lines(scan_lines) -> list[tuple[np.ndarray, np.ndarray]]:
    lines = []
    for k, line in enumerate(scan_lines or ()):
        try:
            start, end = line
        except (TypeError, ValueError):
            raise PlanningInputError(f"scan line {k + 1} must be a (start_mm, end_mm) pair") from None
        start, end = np.asarray(start, dtype=float), np.asarray(end, dtype=float)
        if start.shape != (3,) or end.shape != (3,) or not (np.all(np.isfinite(start)) and np.all(np.isfinite(end))):
            raise PlanningInputError(f"scan line {k + 1} needs two finite (3,) positions in mm")
        lines.append((start, end))
    return lines


def _mesh_triangles(mesh) -> np.ndarray | None:
    """(F, 3, 3) triangles in mm from a trimesh.Trimesh or a (vertices, faces) pair; None if too many."""
    if mesh is None:
        return None
    if hasattr(mesh, "vertices") and hasattr(mesh, "faces"):
        vertices, faces = mesh.vertices, mesh.faces
    else:
        vertices, faces = mesh
    vertices = np.asarray(vertices, dtype=float)
    faces = np.asarray(faces, dtype=np.int64)
    if len(faces) == 0 or len(faces) > MAX_MESH_FACES:
        return None
    return vertices[faces]


def _equal_limits(ax, lo: np.ndarray, hi: np.ndarray) -> None:
    """Limits around the data with one scale on all three axes (the part keeps its shape)."""
    centre = 0.5 * (lo + hi)
    half = 0.5 * np.maximum(hi - lo, 1e-6)
    # a flat dimension (a plate) would otherwise collapse the box: keep at least a quarter of the largest extent
    half = np.maximum(half, 0.25 * half.max()) * 1.05
    ax.set_xlim(centre[0] - half[0], centre[0] + half[0])
    ax.set_ylim(centre[1] - half[1], centre[1] + half[1])
    ax.set_zlim(centre[2] - half[2], centre[2] + half[2])
    ax.set_box_aspect(tuple(half / half.max()))


def _summary(uncertainties: np.ndarray, measured: np.ndarray, n_lines: int, metrology=None, executable=None) -> str:
    n = len(uncertainties)
    if n == 0:
        return "no samples"
    text = f"{n} samples: {int(measured.sum())} covered ({100.0 * measured.mean():.1f} %), "
    if metrology is not None and executable is not None:
        text += (
            f"{int(metrology.sum())} measurable, {int(executable.sum())} of them by executable views, "
            f"{int((~metrology).sum())} not measurable; {n_lines} scan lines"
        )
    else:
        text += f"{int((~measured).sum())} not measurable; {n_lines} scan lines"
    if measured.any():
        text += (
            f"; uncertainty mean {uncertainties[measured].mean():.4f} mm, max {uncertainties[measured].max():.4f} mm"
        )
    return text


def plot_coverage(
    path,
    points_mm,
    uncertainties_mm,
    scan_lines: Sequence = (),
    u_min: float | None = None,
    u_max: float | None = None,
    title: str = "Predicted coverage of the measurement plan",
    mesh=None,
    views: Sequence[tuple[float, float]] = DEFAULT_VIEWS,
    dpi: int = 100,
    metrology_coverable=None,
    executable_coverable=None,
) -> Path:
    """Write a PNG of the plan's predicted coverage to ``path`` (atomically) and return the path.

    :param points_mm: (N, 3) sampled surface points (mm).
    :param uncertainties_mm: (N,) best predicted uncertainty per point (mm); ``inf`` (or NaN) = not measured.
    :param scan_lines: ``[(start_mm, end_mm), ...]`` laser_emitter_frame positions, in execution order.
    :param u_min, u_max: ends of the green -> blue colour scale (mm), e.g. the sensor model's
        ``get_min_uncertainty()`` and ``get_max_uncertainty()``; default: the range of the measured values.
    :param mesh: optional part mesh in the same frame (trimesh.Trimesh or (vertices, faces)), drawn translucent.
    :param views: (elevation, azimuth) in degrees per panel.
    :param metrology_coverable, executable_coverable: optional (N,) masks of the points some candidate view
        measures, and some executable view does: unmeasured points are then coloured by why (red: no view
        measures it, magenta: measurable but not executable, orange: executable but not in the plan).
    """
    path = Path(path)
    points = _as_points(points_mm)
    uncertainties = np.asarray(uncertainties_mm, dtype=float).reshape(-1)
    if uncertainties.shape[0] != points.shape[0]:
        raise PlanningInputError(f"{uncertainties.shape[0]} uncertainties for {points.shape[0]} points")
    lines = _as_lines(scan_lines)
    measured = np.isfinite(uncertainties)
    if u_min is None:
        u_min = float(uncertainties[measured].min()) if measured.any() else 0.0
    if u_max is None:
        u_max = float(uncertainties[measured].max()) if measured.any() else 1.0
    u_min, u_max = float(u_min), float(u_max)
    if not (np.isfinite(u_min) and np.isfinite(u_max)):
        raise PlanningInputError(f"u_min and u_max must be finite, got {u_min}, {u_max}")
    if u_max < u_min:
        raise PlanningInputError(f"u_max ({u_max}) must not be below u_min ({u_min})")
    if u_max == u_min:
        # one value everywhere: widen the scale so the colorbar stays readable
        u_min, u_max = u_min - 0.5 * max(abs(u_min), 1e-3), u_max + 0.5 * max(abs(u_max), 1e-3)
    if not views:
        raise PlanningInputError("at least one (elevation, azimuth) view is needed")

    norm = Normalize(vmin=u_min, vmax=u_max, clip=True)
    colors = np.empty((len(points), 4))
    colors[measured] = UNCERTAINTY_CMAP(norm(uncertainties[measured]))
    colors[~measured] = to_rgba(NOT_MEASURABLE_COLOR)
    masks = []
    for mask, name in ((metrology_coverable, "metrology_coverable"), (executable_coverable, "executable_coverable")):
        if mask is not None:
            mask = np.asarray(mask, dtype=bool).reshape(-1)
            if mask.shape[0] != points.shape[0]:
                raise PlanningInputError(f"{name} has {mask.shape[0]} entries for {points.shape[0]} points")
        masks.append(mask)
    metrology, executable = masks
    if metrology is not None:
        colors[~measured & metrology] = to_rgba(NOT_EXECUTABLE_COLOR)
    if executable is not None:
        colors[~measured & executable] = to_rgba(NOT_PLANNED_COLOR)
    triangles = _mesh_triangles(mesh)

    part_extent = [points] if triangles is None else [points, triangles.reshape(-1, 3)]
    line_extent = [np.vstack(line) for line in lines]
    # points shrink as they get denser so that the surface stays readable at 10,000 samples
    marker_size = float(np.clip(15000.0 / max(len(points), 1), 2.0, 24.0))
    # the scan lines float a standoff (about 180 mm) above the surface, which makes the part small in a picture
    # that shows them: one overview with the lines, then the part alone from each of ``views``
    panels = [(*DEFAULT_VIEWS[0], True)] if lines else []
    panels += [(elevation, azimuth, False) for elevation, azimuth in views]

    fig = Figure(figsize=(5.4 * len(panels) + 1.2, 6.0), dpi=dpi)
    FigureCanvasAgg(fig)
    fig.suptitle(title, fontsize=13)
    fig.text(
        0.5,
        0.915,
        _summary(uncertainties, measured, len(lines), metrology, executable),
        ha="center",
        fontsize=9,
        color="#333333",
    )
    width = 0.87 / len(panels)
    # measured first, red last: the points that need attention are drawn on top
    order = np.argsort(measured, kind="stable")[::-1]
    for panel, (elevation, azimuth, with_lines) in enumerate(panels):
        ax = fig.add_axes((0.005 + panel * width, 0.08, width, 0.8), projection="3d")
        if triangles is not None:
            ax.add_collection3d(Poly3DCollection(triangles, facecolor=(0.8, 0.8, 0.83, 0.12), edgecolor="none"))
        if len(points):
            ax.scatter(
                points[order, 0],
                points[order, 1],
                points[order, 2],
                c=colors[order],
                s=marker_size * (0.4 if with_lines else 1.0),
                depthshade=False,
                linewidths=0,
            )
        extent = part_extent + (line_extent if with_lines else [])
        extent = [e for e in extent if len(e)] or [np.zeros((1, 3))]
        lo, hi = np.vstack(extent).min(axis=0), np.vstack(extent).max(axis=0)
        size = float(np.max(hi - lo)) or 1.0
        for k, (start, end) in enumerate(lines if with_lines else ()):
            color = SCAN_LINE_COLORS[k % len(SCAN_LINE_COLORS)]
            ax.plot(*np.vstack([start, end]).T, color=color, linewidth=3.0, solid_capstyle="round")
            ax.plot(*start[:, None], marker="o", markersize=6, color=color, markeredgecolor="black")
            tail = end - 0.25 * (end - start)
            ax.quiver(*tail, *(end - tail), color=color, arrow_length_ratio=0.8, linewidth=2.0)
            ax.text(*(start + 0.02 * size), str(k + 1), fontsize=9, fontweight="bold", color="black")
        _equal_limits(ax, lo, hi)
        ax.view_init(elev=elevation, azim=azimuth)
        ax.set_xlabel("x [mm]", fontsize=8)
        ax.set_ylabel("y [mm]", fontsize=8)
        ax.set_zlabel("z [mm]", fontsize=8)
        ax.tick_params(labelsize=7)
        for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
            axis.set_major_locator(MaxNLocator(5))
        label = "plan: scan lines in execution order" if with_lines else f"part (azimuth {azimuth:.0f}°)"
        ax.text2D(0.5, 0.97, label, transform=ax.transAxes, ha="center", fontsize=9)

    cax = fig.add_axes((0.905, 0.2, 0.012, 0.56))
    colorbar = fig.colorbar(ScalarMappable(norm=norm, cmap=UNCERTAINTY_CMAP), cax=cax)
    colorbar.set_label("predicted uncertainty [mm]")
    handles = [
        Line2D([], [], linestyle="", marker="o", color=NOT_MEASURABLE_COLOR, label="not measurable"),
        *(
            [Line2D([], [], linestyle="", marker="o", color=NOT_EXECUTABLE_COLOR, label="measurable, not executable")]
            if metrology is not None
            else []
        ),
        *(
            [Line2D([], [], linestyle="", marker="o", color=NOT_PLANNED_COLOR, label="executable, not planned")]
            if executable is not None
            else []
        ),
        Line2D([], [], linestyle="", marker="o", color=UNCERTAINTY_CMAP(0.0), label="low uncertainty"),
        Line2D([], [], linestyle="", marker="o", color=UNCERTAINTY_CMAP(1.0), label="high uncertainty"),
        Line2D([], [], color=SCAN_LINE_COLORS[0], linewidth=3, marker="o", label="scan line (o = start)"),
    ]
    fig.legend(
        handles=handles, loc="lower center", ncol=len(handles), fontsize=9, frameon=False, bbox_to_anchor=(0.45, 0.0)
    )

    atomic_write(path, lambda tmp: fig.savefig(tmp, format="png", dpi=dpi), suffix=".png")
    return path
