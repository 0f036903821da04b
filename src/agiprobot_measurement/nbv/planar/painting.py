"""The report's ``paintRF``: the model, the sensor poses and path, the transfers, the measured points and the
unmeasurable candidates, drawn with matplotlib's Agg backend (no display needed)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agiprobot_measurement.common.files import atomic_write
from agiprobot_measurement.nbv.planar.evaluation import path_metrics
from agiprobot_measurement.nbv.planar.grid import FULL

__all__ = ["paint_rf"]


def paint_rf(result, path: Path | str, title: str = "", measurable: np.ndarray | None = None, dpi: int = 110) -> Path:
    """Save the picture of a run to ``path`` (PNG); returns the path."""
    import matplotlib

    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap

    w = result.working
    # -1, -0.1, 0, 0.1, 1 -> white, pale blue, grey, pale orange, black
    levels = np.digitize(w, [-0.5, -0.05, 0.05, 0.5])
    cmap = ListedColormap(["#ffffff", "#cfe3f5", "#b0b0b0", "#f7d8b0", "#000000"])
    fig, ax = plt.subplots(figsize=(7.5, 7.5))
    ax.imshow(levels.T, origin="lower", cmap=cmap, vmin=0, vmax=4, interpolation="nearest")
    truth_full = result.truth == FULL
    ax.contour(truth_full.T.astype(float), levels=[0.5], colors=["#2a9d8f"], linewidths=0.6)
    if measurable is not None and measurable.any():
        missed = measurable & (result.model != FULL)
        mi = np.argwhere(missed)
        if len(mi):
            ax.plot(mi[:, 0], mi[:, 1], "s", ms=2.0, color="#e63946", label=f"missed measurable ({len(mi)})")
    src = result.sources
    if len(src):
        pm = path_metrics(src)
        ax.plot(src[:, 0], src[:, 1], "-", lw=0.5, color="#457b9d", label="sensor path (source)")
        ax.plot(src[:, 0], src[:, 1], ".", ms=1.5, color="#1d3557")
        for k in np.flatnonzero(pm["transfer_mask"]):
            ax.plot(src[k : k + 2, 0], src[k : k + 2, 1], "-", lw=1.2, color="#e76f51")
        ax.plot([], [], "-", color="#e76f51", label=f"transfers ({pm['transfers']})")
        last = result.records[-1].pos
        ax.plot(last[:2, 0], last[:2, 1], "-", lw=2, color="#6a4c93", label="last pose (source-camera)")
        ax.plot([last[0, 0], last[2, 0]], [last[0, 1], last[2, 1]], ":", lw=0.8, color="#6a4c93")
    pts, _, _ = result.points.of_full_cells(result.model)
    if len(pts):
        ax.plot(pts[:, 0], pts[:, 1], ".", ms=1.0, color="#ffb703", label=f"measured points ({len(pts)})")
    if result.unmeasurable:
        u = np.asarray(result.unmeasurable)
        ax.plot(u[:, 0], u[:, 1], "x", ms=3, color="#d62828", label=f"unmeasurable ({len(u)})")
    nx, ny = w.shape
    pad = 0.45 * max(nx, ny)
    ax.set_xlim(-pad, nx - 1 + pad)
    ax.set_ylim(-pad, ny - 1 + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x (cells)")
    ax.set_ylabel("y (cells)")
    ax.set_title(title, fontsize=9)
    ax.legend(loc="upper right", fontsize=6, framealpha=0.85)
    path = Path(path)
    # the format the path's extension names, else matplotlib's default (the temporary name has its own extension)
    image_format = path.suffix[1:] or matplotlib.rcParams["savefig.format"]
    atomic_write(path, lambda tmp: fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format=image_format))
    plt.close(fig)
    return path
