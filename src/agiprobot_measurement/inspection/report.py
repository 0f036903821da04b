"""The inspection report: ``report.json`` (machine), ``report.html`` (human, offline, with the pictures),
``deviation_map.png`` (three views coloured by signed deviation), ``histogram.png`` and ``deviations.ply`` (the
registered points, CAD frame, with per-point colours and the signed deviation for CloudCompare/MeshLab).

Everything is written into a temporary folder beside the output folder and renamed at the end: a failed run
leaves no half-written report. Colours: green within +-T, blue (missing material) to red (excess) saturating at
+-3T, grey for masked points (sharp edges, outliers).
"""

from __future__ import annotations

import html
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

from agiprobot_measurement.inspection.errors import InspectionInputError
from agiprobot_measurement.inspection.pipeline import InspectionResult

__all__ = ["REPORT_FILES", "deviation_colours", "report_dict", "write_report"]

REPORT_FILES = ("report.json", "report.html", "deviation_map.png", "histogram.png", "deviations.ply")
#: points drawn in the colour map (a random subset of larger clouds)
PLOT_POINTS = 150000
_BEST_FIT_NOTE = (
    "A best fit absorbs global deviations (scale, warp): they appear split +- over the part; judge them by the "
    "features (sizes, flatness) or with a datum alignment."
)


def deviation_colours(signed_mm: np.ndarray, tolerance_mm: float, masked: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) uint8 RGB: green within +-T, blue -> red beyond, saturated at +-3T; grey where ``masked``."""
    x = np.clip(np.asarray(signed_mm, float) / (3.0 * tolerance_mm), -1.0, 1.0)
    rgb = np.zeros((len(x), 3))
    inside = np.abs(x) <= 1.0 / 3.0
    rgb[inside] = [0.1, 0.75, 0.2]
    pos, neg = (x > 1 / 3), (x < -1 / 3)
    f = (np.abs(x) - 1 / 3) * 1.5  # 0 at T, 1 at 3T
    rgb[pos] = np.stack([0.9 + 0.1 * f[pos], 0.8 * (1 - f[pos]), 0.1 * np.ones(pos.sum())], axis=1)
    rgb[neg] = np.stack([0.1 * np.ones(neg.sum()), 0.8 * (1 - f[neg]), 0.9 + 0.1 * f[neg]], axis=1)
    if masked is not None:
        rgb[np.asarray(masked, bool)] = [0.6, 0.6, 0.6]
    return (255 * np.clip(rgb, 0, 1)).astype(np.uint8)


def _rps_figures(reg) -> dict:
    """The reference-point alignment's deviations before it, residuals after it and its rank (when there was one)."""
    if reg.rps is None:
        return {}
    return {"rps": {"deviation_before_mm": reg.rps.deviation_mm, "residual_mm": reg.rps.residual_mm,
                    "rank": reg.rps.rank}}  # fmt: skip


def report_dict(result: InspectionResult, meta: dict | None = None) -> dict:
    """The JSON report's content."""
    reg, s = result.registration, result.spec.surface
    use = ~result.edge & ~result.outlier
    return {
        "part": result.spec.part,
        "verdict": result.verdict,
        "surface_flags": result.flags,
        "meta": meta or {},
        "points": {"total": len(result.points_cad), "used": int(use.sum()), "edge_masked": int(result.edge.sum()),
                   "outliers": int(result.outlier.sum()), "noise_sigma_median_mm": float(np.median(result.sigma_mm))},
        "registration": {
            "method": reg.method, "transform_cad_from_world": result.transform.tolist(),
            "residual_mm": reg.residual_mm, "points_used": reg.used, "overlap": reg.overlap,
            "iterations": reg.iterations, "converged": reg.converged,
            "sigma_rx_ry_rz_deg_tx_ty_tz_mm": [float(np.degrees(v)) if i < 3 else float(v)
                                               for i, v in enumerate(np.sqrt(np.diag(reg.covariance)))],
            "locked": list(result.spec.icp.lock),
            **_rps_figures(reg),
        },
        "instrument_systematic_1sigma": dict(result.instrument.__dict__),
        "surface": {
            "tolerance_mm": s.tolerance_mm, "patch_radius_mm": s.patch_radius_mm,
            "expanded_uncertainty_median_mm": result.surface_uncertainty_mm,
            "detection_limit_mm": s.tolerance_mm + result.surface_uncertainty_mm,
            "regions": [r.as_dict() for r in result.regions], "per_face": result.face_stats,
            "coverage": result.coverage,
        },
        "features": [f.as_dict() for f in result.features],
        "timings_s": result.timings_s,
        "notes": [_BEST_FIT_NOTE] if reg.method == "best_fit" else [],
    }  # fmt: skip


def _write_ply(path: Path, points: np.ndarray, rgb: np.ndarray, signed: np.ndarray, smoothed: np.ndarray) -> None:
    table = np.empty(len(points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"),
                                         ("blue", "u1"), ("deviation", "<f4"), ("patch_deviation", "<f4")])  # fmt: skip
    for k, name in enumerate("xyz"):
        table[name] = points[:, k]
    for k, name in enumerate(("red", "green", "blue")):
        table[name] = rgb[:, k]
    table["deviation"] = signed
    table["patch_deviation"] = smoothed
    header = (
        "ply\nformat binary_little_endian 1.0\ncomment inspection: signed deviation (mm) from the nominal, CAD frame;"
        " patch_deviation: its patch's mean (NaN where masked), colours from it\n"
        f"element vertex {len(points)}\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\n"
        "property uchar green\nproperty uchar blue\nproperty float deviation\nproperty float patch_deviation\n"
        "end_header\n"
    )
    with path.open("wb") as stream:
        stream.write(header.encode("ascii"))
        stream.write(table.tobytes())


def _pyplot():
    import matplotlib  # heavy: loaded when a report draws its pictures

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _figures(result: InspectionResult, folder: Path) -> None:
    plt = _pyplot()
    t = result.spec.surface.tolerance_mm
    masked = result.edge | result.outlier
    rng = np.random.default_rng(0)
    idx = np.arange(len(result.points_cad))
    if len(idx) > PLOT_POINTS:
        idx = np.sort(rng.choice(idx, PLOT_POINTS, replace=False))
    smooth = np.nan_to_num(result.smoothed_mm[idx])
    pts, rgb = result.points_cad[idx], deviation_colours(smooth, t, masked[idx]) / 255.0
    fig, axes = plt.subplots(1, 3, figsize=(15, 5))
    for ax, (a, b, c, title) in zip(axes, ((0, 1, 2, "top (x-y)"), (0, 2, 1, "front (x-z)"), (1, 2, 0, "side (y-z)")),
                                     strict=True):  # fmt: skip
        order = np.argsort(pts[:, c]) if title.startswith("top") else np.argsort(-pts[:, c])
        ax.scatter(pts[order, a], pts[order, b], c=rgb[order], s=0.5, linewidths=0)
        for region in [r for r in result.regions if r.verdict == "not conform"][:10]:
            loc = region.location_mm
            ax.annotate(f"{region.extreme_mm:+.3f}", (loc[a], loc[b]), fontsize=8, color="k")
        ax.set_aspect("equal")
        ax.set_title(title)
        ax.set_xlabel("xyz"[a] + " (mm)")
        ax.set_ylabel("xyz"[b] + " (mm)")
    fig.suptitle(f"{result.spec.part}: signed deviation (patch means within {result.spec.surface.patch_radius_mm} mm), "
                 f"green within +-{t:g} mm, blue/red saturate at +-{3 * t:g} mm; labels: regions out of tolerance")  # fmt: skip
    fig.tight_layout()
    fig.savefig(folder / "deviation_map.png", dpi=90)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 4))
    values = result.signed_mm[~masked]
    span = max(3 * t, float(np.percentile(np.abs(values), 99.9)) if len(values) else 3 * t)
    ax.hist(values, bins=200, range=(-span, span), color="0.3")
    for x in (-t, t):
        ax.axvline(x, color="r", linestyle="--")
    ax.set_xlabel("signed deviation (mm)")
    ax.set_ylabel("points")
    ax.set_title(f"{len(values)} points (edges and outliers masked)")
    fig.tight_layout()
    fig.savefig(folder / "histogram.png", dpi=90)
    plt.close(fig)


def _html(data: dict) -> str:
    e = html.escape

    def row(cells, tag="td"):
        return "<tr>" + "".join(f"<{tag}>{e(str(c))}</{tag}>" for c in cells) + "</tr>"

    reg = data["registration"]
    parts = [
        f"<!doctype html><html><head><meta charset='utf-8'><title>Inspection {e(data['part'])}</title>",
        "<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}td,th{border:1px solid #aaa;"
        "padding:2px 6px}.conform{color:green}.notconform{color:#c00}.indeterminate{color:#c80}</style></head><body>",
        f"<h1>Inspection of {e(data['part'])}: <span class='{data['verdict'].replace(' ', '')}'>{e(data['verdict'])}"
        "</span></h1>",
        f"<p>{data['points']['total']} points ({data['points']['used']} used, {data['points']['edge_masked']} at sharp "
        f"edges, {data['points']['outliers']} outliers); median noise sigma {data['points']['noise_sigma_median_mm']:.4f}"
        " mm.</p>",
        f"<h2>Registration</h2><p>{e(reg['method'])}: residual {reg['residual_mm']:.4f} mm, {reg['points_used']} points"
        f", {reg['iterations']} iterations, converged {reg['converged']}; locked {e(str(reg['locked']))}.</p>",
        "<h2>Surface</h2>",
        f"<p>tolerance +-{data['surface']['tolerance_mm']} mm; median U (k=2) of a patch "
        f"{data['surface']['expanded_uncertainty_median_mm']:.4f} mm; detection limit "
        f"{data['surface']['detection_limit_mm']:.4f} mm; coverage {data['surface']['coverage']['all_percent']:.1f} %"
        "</p><img src='deviation_map.png' width='100%'><img src='histogram.png'>",
        "<table>" + row(["region", "verdict", "extreme (mm)", "U (mm)", "location (mm)", "area (mm2)"], "th"),
    ]
    for k, r in enumerate(data["surface"]["regions"]):
        loc = ", ".join(f"{v:.1f}" for v in r["location_mm"])
        parts.append(row([k + 1, r["verdict"], f"{r['extreme_mm']:+.4f}", f"{r['uncertainty_mm']:.4f}", loc,
                          f"{r['area_mm2']:.0f}"]))  # fmt: skip
    parts.append(
        "</table><h3>Per face</h3><table>" + row(["face", "points", "mean", "std", "min", "max", "in tol %"], "th")
    )
    for name, st in data["surface"]["per_face"].items():
        if st.get("points"):
            parts.append(row([name, st["points"], *(f"{st[k]:+.4f}" for k in ("mean_mm", "std_mm", "min_mm", "max_mm")),
                              f"{st['in_tolerance_percent']:.1f}"]))  # fmt: skip
    parts.append("</table><h2>Features</h2><table>"
                 + row(["feature", "type", "characteristic", "value (mm)", "lower", "upper", "U (mm)", "verdict",
                        "detection limit (mm)"], "th"))  # fmt: skip
    for f in data["features"]:
        if not f["decisions"]:
            parts.append(row([f["name"], f["type"], "-", "-", "-", "-", "-", f["verdict"], "; ".join(f["notes"])]))
        for d in f["decisions"]:
            fmt = lambda v: "-" if v is None else f"{v:.4f}"  # noqa: E731
            parts.append(row([f["name"], f["type"], d["characteristic"], f"{d['value_mm']:.4f}", fmt(d["lower_mm"]),
                              fmt(d["upper_mm"]), f"{d['uncertainty_mm']:.4f}", d["verdict"],
                              fmt(d["detection_limit_mm"])]))  # fmt: skip
    parts.append("</table>")
    parts += [f"<p><i>{e(n)}</i></p>" for n in data["notes"]]
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(
    result: InspectionResult, out_dir: str | Path, meta: dict | None = None, overwrite: bool = False
) -> Path:
    """Write the report into ``out_dir`` (created; an existing non-empty folder only with ``overwrite``)."""
    out = Path(out_dir).absolute()
    if out.exists() and (not out.is_dir() or (any(out.iterdir()) and not overwrite)):
        raise InspectionInputError(f"output folder {out} exists and is not empty (overwrite replaces it)")
    if not out.parent.is_dir():
        raise InspectionInputError(f"the output folder's parent {out.parent} does not exist")
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        data = report_dict(result, meta)
        (tmp / "report.json").write_text(json.dumps(data, indent=1))
        _figures(result, tmp)
        rgb = deviation_colours(np.nan_to_num(result.smoothed_mm), result.spec.surface.tolerance_mm,
                                result.edge | result.outlier)  # fmt: skip
        _write_ply(tmp / "deviations.ply", result.points_cad, rgb, result.signed_mm, result.smoothed_mm)
        (tmp / "report.html").write_text(_html(data))
        tmp.chmod(0o755)
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
