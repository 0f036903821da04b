"""The inspection with the realistic sensor error models and the speed paths: the instrument's systematic terms
widen each decision's uncertainty by exactly their share; the fast paths (threaded closest points, occupancy-table
patches) give the same answers as the plain ones; the generated dent lies where the scan measures; a hole measured
against datums of other laser sweeps carries their relative pose error."""

from __future__ import annotations

import numpy as np
import pytest

from agiprobot_measurement.inspection import cases, deviation, instrument
from agiprobot_measurement.inspection.cli import _instrument
from agiprobot_measurement.inspection.decision import COVERAGE_FACTOR
from agiprobot_measurement.inspection.errors import InspectionInputError
from agiprobot_measurement.inspection.instrument import InstrumentUncertainty, load_instrument
from agiprobot_measurement.inspection.pipeline import inspect_cloud
from agiprobot_measurement.sensors.error_models import load_error_model
from agiprobot_measurement.sensors.laser_line.model import SensorModel
from agiprobot_measurement.station.config import load_scanner_config


def test_instrument_terms_are_read_per_error_model_and_scanner(tmp_path):
    assert load_instrument("ideal", "phoxi_S") == InstrumentUncertainty()
    real = load_instrument("realistic", "phoxi_S")
    assert real.surface_mm > 0 and real.length_rel > 0
    with pytest.raises(InspectionInputError, match="no error model 'nope'"):
        load_instrument("nope", "phoxi_S")
    with pytest.raises(InspectionInputError, match="no scanner 'phoxi_Q'"):
        load_instrument("realistic", "phoxi_Q")
    bad = tmp_path / "bad.yaml"
    bad.write_text("realistic: {phoxi_S: {surface_mm: 0.01, scale: 2}}\n")
    with pytest.raises(InspectionInputError, match="unknown keys"):
        instrument.load_instrument("realistic", "phoxi_S", bad)


@pytest.fixture(scope="module")
def realistic_null():
    return cases.build_case("null", 0.0, 0, "phoxi_low", "realistic")


def test_realistic_scan_differs_from_ideal_and_the_systematic_terms_add_in_quadrature(realistic_null):
    c = realistic_null
    ideal = cases.build_case("null", 0.0, 0, "phoxi_low", "ideal")
    assert len(c.points_mm) > 0.9 * len(ideal.points_mm)
    assert not np.allclose(c.points_mm[:1000], ideal.points_mm[:1000], atol=1e-3)
    terms = InstrumentUncertainty(surface_mm=0.03, form_mm=0.02, length_rel=4e-4)
    points, sigma = c.points_mm[::3], c.sigma_mm[::3]
    plain = inspect_cloud(points, c.nominal, c.spec, c.part.nominal_placement, sigma)
    wide = inspect_cloud(points, c.nominal, c.spec, c.part.nominal_placement, sigma, instrument=terms)
    added = {"size": 4e-4 * 100.0, "flatness": 0.02}
    for before, after in zip(plain.features, wide.features, strict=True):
        u0, u1 = before.decisions[0].uncertainty_mm, after.decisions[0].uncertainty_mm
        assert np.isclose(u1**2 - u0**2, (COVERAGE_FACTOR * added[before.type]) ** 2, rtol=1e-6)
    assert wide.surface_uncertainty_mm > plain.surface_uncertainty_mm >= 0
    assert wide.surface_uncertainty_mm >= COVERAGE_FACTOR * 0.03


def test_fast_paths_answer_as_the_plain_ones(monkeypatch, realistic_null):
    c = realistic_null
    points = c.points_mm[:60000] - c.part.nominal_placement[:3, 3]
    serial = deviation.closest_points(c.nominal, points)
    monkeypatch.setattr(deviation, "PARALLEL_MIN_POINTS", 1000)
    threaded = deviation.closest_points(c.nominal, points)
    assert np.array_equal(serial.face, threaded.face) and np.array_equal(serial.signed_mm, threaded.signed_mm)
    use = np.abs(serial.signed_mm) < 3.0
    dense = deviation.patches(serial.closest_mm, serial.signed_mm, np.full(len(points), 0.05), use, 1.0, 2.0)
    monkeypatch.setattr(deviation, "DENSE_GRID_FACTOR", 0)
    plain = deviation.patches(serial.closest_mm, serial.signed_mm, np.full(len(points), 0.05), use, 1.0, 2.0)
    assert np.array_equal(dense.voxel_of_point, plain.voxel_of_point)
    assert np.allclose(dense.mean_mm, plain.mean_mm) and np.allclose(dense.centre_mm, plain.centre_mm)


def test_the_generated_dent_lies_where_the_scan_measures():
    # seed 118 once drew the dent in the corner the single view's depth range does not reach
    c = cases.build_case("dent", 0.3, 118, "phoxi_low")
    cad = np.linalg.inv(c.part.actual_placement)
    points = c.points_mm @ cad[:3, :3].T + cad[:3, 3]
    centre, radius = np.asarray(c.truth["dent_centre_mm"]), c.truth["dent_radius_mm"]
    ring = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    probes = centre[:2] + np.c_[np.cos(ring), np.sin(ring)] * radius
    top = points[np.abs(points[:, 2] - 50.0) < 1.0][:, :2]
    for probe in np.vstack([centre[:2], probes]):
        assert np.min(np.linalg.norm(top - probe, axis=1)) < 1.0


def test_the_command_line_names_the_instrument_as_model_and_scanner():
    assert _instrument(None) is None
    assert _instrument("realistic:phoxi_S") == load_instrument("realistic", "phoxi_S")
    with pytest.raises(InspectionInputError, match="ERROR_MODEL:SCANNER"):
        _instrument("realistic")


def test_the_stitching_term_is_derived_from_the_error_models_pose_chain(tmp_path):
    laser = load_instrument("realistic", "laser_line")
    chain = dict(load_error_model("realistic").laser["pose_chain"])
    standoff = SensorModel(load_scanner_config().sensor_parameters).optimal_standoff
    assert laser.stitching_mm == pytest.approx(instrument.pose_chain_stitching_mm(chain, standoff))
    assert laser.stitching_mm > chain["hand_eye_translation_mm"]  # two orientations: sqrt(2) x the per-view error
    wider = instrument.pose_chain_stitching_mm({**chain, "hand_eye_translation_mm": 2 * chain["hand_eye_translation_mm"]},
                                               standoff)  # fmt: skip
    assert wider > laser.stitching_mm
    assert instrument.pose_chain_stitching_mm({**chain, "enabled": False}, standoff) == 0.0
    assert instrument.pose_chain_stitching_mm(None, standoff) == 0.0
    assert load_instrument("realistic", "phoxi_S").stitching_mm == 0.0
    assert load_instrument("ideal", "laser_line").stitching_mm == 0.0
    given = tmp_path / "given.yaml"
    given.write_text("realistic: {laser_line: {stitching_mm: 0.05}}\n")
    assert load_instrument("realistic", "laser_line", given).stitching_mm == 0.05


def test_realistic_laser_hole_against_datums_of_other_sweeps_is_not_called_wrong():
    # the hole (top sweeps) and its datums B, C (side sweeps) are stitched by the head's poses: the hand-eye error
    # shifts them against each other; without the stitching term this run's 0.05 mm shift (conform) read not conform
    c = cases.build_case("hole", 0.05, 0, "laser", "realistic")
    terms = load_instrument("realistic", "laser_line")
    result = inspect_cloud(c.points_mm, c.nominal, c.spec, c.part.nominal_placement, c.sigma_mm, instrument=terms)
    hole = next(f for f in result.features if f.type == "hole")
    position = hole.decisions[0]
    assert position.verdict != "not conform"
    assert abs(position.value_mm - c.truth["hole_position_deviation_mm"]) <= position.uncertainty_mm
    assert position.uncertainty_mm >= 2 * COVERAGE_FACTOR * terms.stitching_mm


def test_the_benchmark_refuses_an_unknown_error_model_naming_the_known_ones(capsys):
    from benchmarks.inspection.run import main

    for argv, named in ((["--error-model", "NOSUCH"], "ideal, realistic"), (["--sensors", "phoxi,foo"], "laser"),
                        (["--cases", "dent,bend"], "warp")):  # fmt: skip
        with pytest.raises(SystemExit) as exit_info:
            main(argv)
        assert exit_info.value.code == 2
        err = capsys.readouterr().err
        assert argv[1].split(",")[-1] in err and named in err and "Traceback" not in err


def test_the_centre_bound_is_the_95_percent_radius_of_the_instruments_centre_and_stitching_terms():
    from benchmarks.inspection.run import IDEAL_CENTRE_MM, centre_limit_mm

    laser = load_instrument("realistic", "laser_line")
    bound = centre_limit_mm("laser_line", laser)
    assert centre_limit_mm("laser_line", InstrumentUncertainty()) == IDEAL_CENTRE_MM["laser_line"]
    doubled = InstrumentUncertainty(stitching_mm=2 * laser.stitching_mm)
    assert centre_limit_mm("laser_line", doubled) > 1.9 * bound  # it scales with the pose chain
    # 95 % of centres shifted by a 2-D Gaussian of per-axis sigma = the stitching term lie within the bound
    shifts = np.random.default_rng(3).normal(0.0, laser.stitching_mm, (100_000, 2))
    assert np.mean(np.linalg.norm(shifts, axis=1) <= bound) == pytest.approx(0.955, abs=0.01)
    # the PhoXi's centre term (its calibration error at the hole against the datums) enters the same way
    phoxi = load_instrument("realistic", "phoxi_S")
    assert phoxi.centre_mm > 0 and phoxi.stitching_mm == 0.0
    as_stitching = InstrumentUncertainty(stitching_mm=phoxi.centre_mm)
    assert centre_limit_mm("phoxi_S", phoxi) == pytest.approx(centre_limit_mm("phoxi_S", as_stitching))
    assert centre_limit_mm("phoxi_S", phoxi) > IDEAL_CENTRE_MM["phoxi_S"]


def test_the_centre_term_widens_a_holes_position_uncertainty_by_its_share():
    c = cases.build_case("hole", 0.2, 1, "phoxi_low", "ideal")
    points, sigma = c.points_mm[::2], c.sigma_mm[::2]
    plain = inspect_cloud(points, c.nominal, c.spec, c.part.nominal_placement, sigma)
    wide = inspect_cloud(points, c.nominal, c.spec, c.part.nominal_placement, sigma,
                         instrument=InstrumentUncertainty(centre_mm=0.03))  # fmt: skip
    u0, u1 = (next(f for f in r.features if f.type == "hole").decisions[0].uncertainty_mm for r in (plain, wide))
    # the position is twice the centre's offset: U grows by 2 x k x the per-axis term, in quadrature
    assert np.isclose(u1**2 - u0**2, (2 * COVERAGE_FACTOR * 0.03) ** 2, rtol=1e-6)


def test_the_derivation_stays_off_the_evaluation_seeds_and_summarises_per_axis():
    from benchmarks.inspection.derive import main, summarise

    with pytest.raises(SystemExit) as exit_info:
        main(["--first-seed", "90", "--devices", "20"])
    assert exit_info.value.code == 2
    runs = [{"centre_error_mm": [0.03, 0.0], "registration_mm": 0.01, "registration_deg": 0.002},
            {"centre_error_mm": [0.0, -0.03], "registration_mm": 0.03, "registration_deg": 0.004}]  # fmt: skip
    s = summarise(runs)
    assert s["centre_mm"] == pytest.approx(0.03 / np.sqrt(2))  # RMS per axis over both axes
    assert s["centre_radius_max_mm"] == pytest.approx(0.03)
    assert s["registration_deg_max"] == pytest.approx(0.004)


def test_a_case_scanned_without_noise_keeps_only_the_devices_systematic_errors():
    from benchmarks.inspection.derive import calibration_only

    def off_surface(c):
        return np.abs(deviation.closest_points(c.part.placed_actual(), c.points_mm[::50]).signed_mm)

    assert np.percentile(off_surface(cases.build_case("null", 0.0, 2, "phoxi_low", "ideal", noise=False)), 99) < 1e-3
    assert np.percentile(off_surface(cases.build_case("null", 0.0, 2, "phoxi_low", "ideal")), 99) > 1e-2
    # the calibration's field alone: smooth, of the order of the stated accuracy (0.05 mm), not noise-like
    calibrated = off_surface(cases.build_case("null", 0.0, 2, "phoxi_low", calibration_only(), noise=False))
    assert 5e-3 < np.sqrt(np.mean(calibrated**2)) < 0.2


def test_the_size_term_widens_a_sizes_uncertainty_by_its_share(realistic_null):
    c = realistic_null
    points, sigma = c.points_mm[::3], c.sigma_mm[::3]
    plain = inspect_cloud(points, c.nominal, c.spec, c.part.nominal_placement, sigma)
    wide = inspect_cloud(points, c.nominal, c.spec, c.part.nominal_placement, sigma,
                         instrument=InstrumentUncertainty(size_mm=0.05))  # fmt: skip
    for before, after in zip(plain.features, wide.features, strict=True):
        u0, u1 = before.decisions[0].uncertainty_mm, after.decisions[0].uncertainty_mm
        if before.type == "size":
            assert np.isclose(u1**2 - u0**2, (COVERAGE_FACTOR * 0.05) ** 2, rtol=1e-6)
        else:  # a flatness does not suffer a size term
            assert u1 == pytest.approx(u0)


def test_derived_dent_and_size_limits_follow_the_instrument_terms():
    from benchmarks.inspection.run import (
        SURFACE_TOLERANCE_MM,
        dent_detection_limit_mm,
        depth_limit_mm,
        size_limit_mm,
    )

    laser = load_instrument("realistic", "laser_line")
    limit = dent_detection_limit_mm("laser_line", laser)
    # T + (2 + k) surface_mm, rounded up to 0.05 mm
    exact = SURFACE_TOLERANCE_MM + (2 + COVERAGE_FACTOR) * laser.surface_mm
    assert exact <= limit < exact + 0.05 and np.isclose(limit * 20, round(limit * 20))
    doubled = InstrumentUncertainty(surface_mm=2 * laser.surface_mm)
    assert dent_detection_limit_mm("laser_line", doubled) > limit
    assert depth_limit_mm("laser_line", laser, 1.0) == pytest.approx(2 * laser.surface_mm + 0.1)
    assert size_limit_mm("laser_line", InstrumentUncertainty(size_mm=0.1)) == pytest.approx(0.2)
    # the PhoXi's limits stay the stated numbers whatever its terms
    assert dent_detection_limit_mm("phoxi_S", doubled) == 0.3
    assert size_limit_mm("phoxi_S", InstrumentUncertainty(size_mm=1.0)) == 0.12


def test_the_laser_derivation_summarises_the_worst_patch_and_the_size_errors():
    from benchmarks.inspection.derive import main, summarise_laser

    with pytest.raises(SystemExit) as exit_info:
        main(["--sensor", "laser", "--first-seed", "95", "--devices", "10"])
    assert exit_info.value.code == 2
    runs = [{"patch_max_mm": 0.1 * (i + 1), "patch_rms_mm": 0.05, "size_errors_mm": [0.1, -0.1],
             "registration_mm": 0.01 * i, "registration_deg": 0.001} for i in range(20)]  # fmt: skip
    s = summarise_laser(runs)
    assert s["surface_mm"] == pytest.approx(np.percentile(0.1 * np.arange(1, 21), 95) / 2)
    assert s["size_mm"] == pytest.approx(0.1) and s["size_mean_mm"] == pytest.approx(0.0)
    assert s["patch_max_max_mm"] == pytest.approx(2.0) and s["registration_mm_max"] == pytest.approx(0.19)
