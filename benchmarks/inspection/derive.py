"""A-priori terms of the realistic scanners from their error model: `python -m benchmarks.inspection.derive
[--sensor phoxi|laser] [--devices 60] [--first-seed 0] [--json FILE]`.

The PhoXi's per-device calibration error (config/error_models/realistic.yaml, ``phoxi.calibration``: the true
camera and projector against the nominal ones plus the local decoding residual, scaled to the stated accuracy)
moves every point by a smooth, device-fixed field. What an inspection cannot remove of it is propagated here by
Monte Carlo (GUM Supplement 1 style) through the inspection itself: for each simulated device (the model's own
calibration draw, seeded from the device serial), the benchmark's hole plate (hole not shifted) and null cube
(2 mm / 1 deg placement error) are scanned **noise-free with only the calibration block on**, and inspected; the
hole centre's error against its datums and the registration's error are the calibration's share alone (the noise
is the fit's own term, the other blocks average out or are masked). Seeds are development seeds (< 100): the
evaluation devices (seeds 100-119) are not among them.

Printed (and written with ``--json``): the hole centre's per-axis RMS error, which is the instrument's
``centre_mm`` (config/inspection/instruments.yaml), the 95 % radius of its 2-D Gaussian and the empirical 95th
percentile of the radial error; the null part's registration error (translation over the part's vertices, mm;
rotation, deg): RMS, 95th percentile and maximum.

``--sensor laser``: the realistic laser line scanner's per-device errors (calibration, material, edges and the pose
chain of the robot-carried head: hand-eye, kinematic residual, repeatability; config/error_models/realistic.yaml,
``laser``) do not vary across a face the way noise does: a sweep sees a whole face at one standoff and head
orientation, so the linearity error there and the hand-eye error shift the face along its normal, and opposite
faces, seen in opposite orientations, move apart or together (a size error the best fit cannot remove). Each
development device scans the null cube noise-free with every systematic block on and is inspected with no
instrument terms; printed: the largest |patch mean deviation| of each run (its 95th percentile over the devices,
halved, is the instrument's ``surface_mm``: U with k = 2 then covers the worst patch of 95 % of devices), the
100 mm size errors (their RMS is ``size_mm``) and the registration error (95th percentiles: the stated
registration limits).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

from agiprobot_measurement.inspection import cases
from agiprobot_measurement.inspection.instrument import InstrumentUncertainty, load_instrument
from agiprobot_measurement.inspection.pipeline import inspect_cloud
from agiprobot_measurement.inspection.registration import transform_error
from agiprobot_measurement.sensors.error_models import load_error_model

#: the evaluation seeds start here; the derivation stays below
EVALUATION_SEED0 = 100
#: radius holding 95 % of a 2-D isotropic Gaussian, in units of its per-axis sigma: sqrt(-2 ln 0.05)
RADIUS_95_SIGMAS = float(np.sqrt(-2.0 * np.log(0.05)))


def calibration_only(name: str = "realistic"):
    """The named error model with only the PhoXi's calibration block on (fixed pattern, material, edges and
    interreflection off)."""
    return load_error_model(name).with_blocks("phoxi", fixed_pattern=None, material=None, edges=None,
                                              interreflection=None)  # fmt: skip


def device_run(seed: int, model) -> dict:
    """One simulated device: the hole centre's error (x, y, mm, datum frame) and the null part's registration
    error, both from noise-free scans with the calibration error only."""
    hole = cases.build_case("hole", 0.0, seed, "phoxi", model, noise=False)
    result = inspect_cloud(hole.points_mm, hole.nominal, hole.spec, hole.part.nominal_placement, hole.sigma_mm)
    feature = next(f for f in result.features if f.name == "hole_1")
    centre = np.asarray(feature.values["centre_offset_mm"])[:2] + np.asarray(hole.spec.features[0].params["centre"])[:2]
    error = centre - np.asarray(hole.truth["hole_centre_mm"])[:2]
    null = cases.build_case("null", 0.0, seed, "phoxi", model, noise=False)
    reg = inspect_cloud(null.points_mm, null.nominal, null.spec, null.part.nominal_placement, null.sigma_mm)
    reg_mm, reg_deg = transform_error(reg.transform, np.linalg.inv(null.part.actual_placement), null.nominal.vertices)
    return {"seed": seed, "serial": cases.device_serial(seed), "centre_error_mm": error.tolist(),
            "hole_method": feature.values["method"], "registration_mm": reg_mm,
            "registration_deg": reg_deg}  # fmt: skip


def laser_device_run(seed: int, model) -> dict:
    """One simulated laser head: the null cube scanned noise-free with all systematic blocks and inspected: the
    largest and the RMS |patch mean deviation| (mm), the size errors (mm) and the registration error. The
    instrument's stitching term is passed only so that the residual check accepts the noise-free cloud; no value
    read here depends on the instrument terms (they enter uncertainties only)."""
    null = cases.build_case("null", 0.0, seed, "laser", model, noise=False)
    stitching = InstrumentUncertainty(stitching_mm=load_instrument(model.name, "laser_line").stitching_mm)
    result = inspect_cloud(null.points_mm, null.nominal, null.spec, null.part.nominal_placement, null.sigma_mm,
                           instrument=stitching)  # fmt: skip
    patch = result.smoothed_mm[np.isfinite(result.smoothed_mm)]
    sizes = {f.name: f.values["deviation_mm"] for f in result.features if f.type == "size"}
    reg_mm, reg_deg = transform_error(result.transform, np.linalg.inv(null.part.actual_placement),
                                      null.nominal.vertices)  # fmt: skip
    return {"seed": seed, "serial": cases.device_serial(seed), "patch_max_mm": float(np.abs(patch).max()),
            "patch_rms_mm": float(np.sqrt(np.mean(patch * patch))), "size_errors_mm": list(sizes.values()),
            "face_means_mm": {k: v["mean_mm"] for k, v in result.face_stats.items() if "mean_mm" in v},
            "registration_mm": reg_mm, "registration_deg": reg_deg}  # fmt: skip


def _registration_summary(runs: list[dict]) -> dict:
    """RMS, 95th percentile and maximum of the runs' registration errors (mm, deg)."""
    out = {}
    for key in ("registration_mm", "registration_deg"):
        v = np.array([r[key] for r in runs])
        out.update({f"{key}_rms": float(np.sqrt(np.mean(v * v))), f"{key}_p95": float(np.percentile(v, 95)),
                    f"{key}_max": float(v.max())})  # fmt: skip
    return out


def summarise_laser(runs: list[dict]) -> dict:
    """The laser's derived terms (see the module docstring)."""
    worst = np.array([r["patch_max_mm"] for r in runs])
    sizes = np.concatenate([r["size_errors_mm"] for r in runs])
    out = {"devices": len(runs), "surface_mm": float(np.percentile(worst, 95) / 2.0),
           "patch_max_p95_mm": float(np.percentile(worst, 95)), "patch_max_max_mm": float(worst.max()),
           "patch_rms_mm": float(np.sqrt(np.mean([r["patch_rms_mm"] ** 2 for r in runs]))),
           "size_mm": float(np.sqrt(np.mean(sizes * sizes))), "size_mean_mm": float(sizes.mean()),
           "size_abs_max_mm": float(np.abs(sizes).max())}  # fmt: skip
    return {**out, **_registration_summary(runs)}


def summarise(runs: list[dict]) -> dict:
    """The derived terms (see the module docstring)."""
    e = np.array([r["centre_error_mm"] for r in runs])
    radial = np.linalg.norm(e, axis=1)
    per_axis = float(np.sqrt(np.mean(e * e)))
    out = {"devices": len(runs), "centre_mm": per_axis, "centre_mean_mm": e.mean(axis=0).tolist(),
           "centre_radius95_gauss_mm": RADIUS_95_SIGMAS * per_axis,
           "centre_radius_p95_mm": float(np.percentile(radial, 95)),
           "centre_radius_max_mm": float(radial.max())}  # fmt: skip
    return {**out, **_registration_summary(runs)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--devices", type=int, default=60, help="simulated devices (one per seed)")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--error-model", default="realistic")
    parser.add_argument("--sensor", default="phoxi", choices=("phoxi", "laser"))
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    if args.first_seed < 0 or args.first_seed + args.devices > EVALUATION_SEED0:
        parser.error(f"the derivation's seeds must lie below the evaluation seeds ({EVALUATION_SEED0})")
    if args.sensor == "laser":
        model, one, summarise_runs = load_error_model(args.error_model), laser_device_run, summarise_laser
    else:
        model, one, summarise_runs = calibration_only(args.error_model), device_run, summarise
    runs = []
    t0 = time.perf_counter()
    for seed in range(args.first_seed, args.first_seed + args.devices):
        runs.append(one(seed, model))
        print(json.dumps({k: (np.round(v, 5).tolist() if isinstance(v, (float, list)) else v)
                          for k, v in runs[-1].items()}), file=sys.stderr, flush=True)  # fmt: skip
    summary = summarise_runs(runs)
    print(f"derivation: {args.devices} devices (seeds {args.first_seed}..{args.first_seed + args.devices - 1}), "
          f"{time.perf_counter() - t0:.0f} s, load average {os.getloadavg()[0]:.1f}")  # fmt: skip
    for key, value in summary.items():
        print(f"  {key}: {np.round(value, 5).tolist() if isinstance(value, (float, list)) else value}")
    if args.json:
        with open(args.json, "w") as stream:
            json.dump({"runs": runs, "summary": summary}, stream, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
