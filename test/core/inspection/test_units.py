"""The inspection's building blocks on synthetic data with exact answers: fits, minimum zone, decisions, spec
checks, signed distances, registration with locks, 3-2-1 datums and reference points (RPS)."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from agiprobot_measurement._paths import CONFIG_DIR
from agiprobot_measurement.inspection import actual, decision, fitting, registration
from agiprobot_measurement.inspection.deviation import closest_points, edge_mask
from agiprobot_measurement.inspection.errors import InspectionInputError, RegistrationError, SpecError
from agiprobot_measurement.inspection.spec import load_spec, parse_spec

RNG = np.random.default_rng(7)


def test_plane_circle_sphere_cylinder_fits_recover_their_parameters():
    xy = RNG.uniform(-20, 20, (2000, 2))
    plane = np.c_[xy, 0.01 * xy[:, 0] + 3 + RNG.normal(0, 0.01, 2000)]
    fit = fitting.fit_plane(plane, (0, 0, 1))
    assert fit.normal[2] > 0 and abs(fit.centroid[2] - 3) < 0.01
    angles = RNG.uniform(0, np.pi, 500)  # half a circle
    circle = np.c_[5 + 4 * np.cos(angles), -2 + 4 * np.sin(angles), np.zeros(500)] + RNG.normal(0, 0.005, (500, 3))
    c = fitting.fit_circle(circle, (0, 0, 0), (0, 0, 1))
    assert np.allclose(c.centre[:2], (5, -2), atol=0.005) and abs(c.radius - 4) < 0.005
    d = RNG.normal(size=(3000, 3))
    sphere = (1, 2, 3) + 12.5 * d / np.linalg.norm(d, axis=1, keepdims=True)
    s = fitting.fit_sphere(sphere)
    assert np.allclose(s.centre, (1, 2, 3), atol=1e-6) and abs(s.radius - 12.5) < 1e-6
    t = RNG.uniform(0, 2 * np.pi, 2000)
    cyl = np.c_[3 * np.cos(t) + 1, 3 * np.sin(t), RNG.uniform(-10, 10, 2000)]
    y = fitting.fit_cylinder(cyl, (0.8, 0.1, 0), (0.02, 0, 1), 2.8)
    assert abs(y.radius - 3) < 1e-6 and abs(abs(y.axis[2]) - 1) < 1e-9


def test_min_zone_flatness_is_the_narrowest_zone():
    xy = RNG.uniform(-50, 50, (5000, 2))
    # a tilted plane with heights in [0, 0.2] and the extremes present: zone 0.2 whatever the tilt
    h = RNG.uniform(0, 0.2, 5000)
    h[:3], h[3:6] = 0.0, 0.2
    pts = np.c_[xy, h + 0.05 * xy[:, 0]]
    assert fitting.min_zone_flatness(pts, (0, 0, 1)) == pytest.approx(0.2, abs=1e-6)


def test_iso_14253_decisions_use_the_guard_bands():
    assert decision.decide("x", 0.05, 0.1, 0.02).verdict == decision.CONFORM
    assert decision.decide("x", 0.09, 0.1, 0.02).verdict == decision.INDETERMINATE
    assert decision.decide("x", 0.13, 0.1, 0.02).verdict == decision.NOT_CONFORM
    d = decision.decide("size", 99.85, 100.1, 0.01, lower=99.9)
    assert d.verdict == decision.NOT_CONFORM and d.detection_limit_mm == pytest.approx(100.11)


SPEC = {
    "part": "cube",
    "faces": {"top": {"normal": [0, 0, 1], "point": [0, 0, 50]}, "px": {"normal": [1, 0, 0], "point": [50, 0, 0]}},
    "features": [{"name": "f", "type": "flatness", "face": "top", "tolerance_mm": 0.1}],
}


def test_spec_errors_name_the_problem():
    cube = actual.cube()
    parse_spec(SPEC).check_against(cube)
    with pytest.raises(SpecError, match="unknown face 'side'"):
        parse_spec({**SPEC, "features": [{"name": "f", "type": "flatness", "face": "side", "tolerance_mm": 0.1}]})
    moved = {**SPEC, "faces": {**SPEC["faces"], "top": {"normal": [0, 0, 1], "point": [0, 0, 40]}}}
    with pytest.raises(SpecError, match="matches no triangle"):
        parse_spec(moved).check_against(cube)
    with pytest.raises(SpecError, match="unknown type"):
        parse_spec({**SPEC, "features": [{"name": "f", "type": "roundness"}]})
    with pytest.raises(SpecError, match="lacks"):
        parse_spec({**SPEC, "features": [{"name": "f", "type": "flatness", "face": "top"}]})
    with pytest.raises(SpecError, match="degrees of freedom"):
        parse_spec({**SPEC, "alignment": {"lock": ["qx"]}})


def test_signed_distance_is_positive_outside_and_edges_are_masked():
    cube = actual.cube()
    pts = np.array([[0, 0, 50.2], [0, 0, 49.7], [49.9, 0, 50.1], [10, 10, 50.0]])
    cp = closest_points(cube, pts)
    assert cp.signed_mm[:2] == pytest.approx([0.2, -0.3])
    assert edge_mask(cube, cp.closest_mm, 1.0).tolist() == [False, False, True, False]


def _surface_points(mesh, n, noise, rng):
    pts, _ = trimesh.sample.sample_surface(mesh, n, seed=int(rng.integers(1 << 30)))
    return pts + rng.normal(0, noise, pts.shape)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_icp_recovers_a_placement_error(seed):
    rng = np.random.default_rng(seed)
    cube = actual.cube()
    pts = _surface_points(cube, 60000, 0.05, rng)
    pts = pts[pts @ np.array([1, 1, 1]) > -40]  # three faces and parts of the others
    error = actual.placement_error(rng, 2.0, 1.0)
    world = registration.apply(error, pts)
    reg = registration.icp(world, cube)
    err_mm, err_deg = registration.transform_error(reg.transform, np.linalg.inv(error), cube.vertices)
    assert reg.converged and err_mm <= 0.01 and err_deg <= 0.005


def test_locked_degrees_of_freedom_stay_fixed():
    rng = np.random.default_rng(3)
    cube = actual.cube()
    pts = _surface_points(cube, 30000, 0.02, rng)
    shift = np.eye(4)
    shift[:3, 3] = (0.5, -0.4, 0.3)
    reg = registration.icp(registration.apply(shift, pts), cube, registration.IcpSettings(lock=("tx", "rz")))
    t = reg.transform
    assert abs(t[0, 3]) < 1e-4  # x not corrected (only the rotations about the centroid move it, by nm)
    assert t[1, 3] == pytest.approx(0.4, abs=0.005) and t[2, 3] == pytest.approx(-0.3, abs=0.005)
    assert abs(Rotation.from_matrix(t[:3, :3]).as_rotvec()[2]) < 1e-8
    with pytest.raises(InspectionInputError):
        registration.IcpSettings(lock=("bogus",))


def test_datum_321_maps_measured_datums_onto_the_nominal():
    rng = np.random.default_rng(4)
    error = actual.placement_error(rng, 0.3, 0.2)
    a = np.c_[rng.uniform(-40, 40, (500, 2)), np.full(500, 50.0)]
    b = np.c_[np.full(500, -50.0), rng.uniform(-40, 40, (500, 2))]
    c = np.c_[rng.uniform(-40, 40, 500), np.full(500, -50.0), rng.uniform(-40, 40, 500)]
    measured = [registration.apply(error, p) for p in (a, b, c)]
    nominal = [((0, 0, 50.0), np.array([0, 0, 1.0])), ((-50.0, 0, 0), np.array([-1.0, 0, 0])),
               ((0, -50.0, 0), np.array([0, -1.0, 0]))]  # fmt: skip
    correction = registration.datum_frame(measured, nominal)
    assert np.allclose(correction @ error, np.eye(4), atol=1e-9)


def _cube_surface(count=60000):
    points, _ = trimesh.sample.sample_surface(actual.cube(), count, seed=3)
    return points


def test_rps_3_2_1_undoes_a_known_rigid_motion_and_follows_a_moved_datum_face():
    spec = load_spec(CONFIG_DIR / "inspection" / "cube_100_rps.yaml")
    assert spec.alignment == "rps" and len(spec.rps_points) == 6
    truth = np.eye(4)
    truth[:3, :3] = Rotation.from_rotvec(np.radians([0.15, -0.1, 0.2])).as_matrix()
    truth[:3, 3] = (0.3, -0.2, 0.25)
    surface = _cube_surface()
    moved = registration.apply(truth, surface)
    result = registration.rps_alignment(moved, spec.rps_points, spec.rps_radius_mm)
    assert result.rank == 6
    error_mm, error_deg = registration.transform_error(result.correction, np.linalg.inv(truth), surface)
    assert error_mm < 1e-6 and error_deg < 1e-6
    assert max(abs(v) for v in result.residual_mm.values()) < 1e-8
    # the top face (datum A) 0.04 mm low: the RPS lifts the whole part by 0.04 mm, the other datums stay met
    low = surface.copy()
    low[np.isclose(low[:, 2], 50.0), 2] -= 0.04
    lifted = registration.rps_alignment(low, spec.rps_points, spec.rps_radius_mm)
    assert np.allclose(lifted.correction[:3, 3], (0, 0, 0.04), atol=1e-9)
    assert np.allclose(lifted.correction[:3, :3], np.eye(3), atol=1e-9)
    assert np.allclose([lifted.deviation_mm[n] for n in ("A1", "A2", "A3")], -0.04, atol=1e-9)
    # rotations locked: the same lift by translation alone
    lift = registration.rps_alignment(low, spec.rps_points, spec.rps_radius_mm, lock=("rx", "ry", "rz"))
    assert np.allclose(lift.correction[:3, 3], (0, 0, 0.04), atol=1e-9) and lift.rank == 3
    # tz locked, the part shifted 0.1 mm along x: moved back along x, nothing else
    shifted = surface + np.array([0.1, 0.0, 0.0])
    kept = registration.rps_alignment(shifted, spec.rps_points, spec.rps_radius_mm, lock=("tz",))
    assert np.allclose(kept.correction[:3, 3], (-0.1, 0, 0), atol=1e-9) and kept.rank == 5
    assert np.allclose(kept.correction[:3, :3], np.eye(3), atol=1e-9)


def test_rps_spec_errors_name_the_problem():
    base = {"faces": {"top": {"normal": [0, 0, 1], "point": [0, 0, 50]}}}
    with pytest.raises(SpecError, match=r"needs alignment\.rps\.points"):
        parse_spec({**base, "alignment": {"method": "rps"}})
    with pytest.raises(SpecError, match="zero direction"):
        parse_spec({**base, "alignment": {"method": "rps", "rps": {"points": [{"point": [0, 0, 50],
                                                                              "direction": [0, 0, 0]}]}}})  # fmt: skip
    with pytest.raises(SpecError, match="method is 'best_fit'"):
        parse_spec({**base, "alignment": {"rps": {"points": []}}})
    with pytest.raises(RegistrationError, match="RPS point far"):
        registration.rps_alignment(_cube_surface(2000), [registration.RpsPoint("far", np.array([0, 0, 80.0]),
                                                                                  np.array([0, 0, 1.0]))])  # fmt: skip


def test_flatness_of_a_bowed_face_measured_to_its_edges_reads_the_whole_bow():
    # the top face of the warped plate measured everywhere (0.3 mm grid, 30 um noise): the zone's ends lie at the
    # face's edges; a fixed 1 mm edge margin and patch centroids as the filter's ends read a bow ~4 % short
    from agiprobot_measurement.inspection.pipeline import inspect_cloud

    bow, sigma = 0.5, 0.03
    part = actual.warped(bow_mm=bow)
    x, y = np.meshgrid(np.arange(-99.95, 100.0, 0.3), np.arange(-49.95, 50.0, 0.3), indexing="ij")
    x, y = x.ravel(), y.ravel()
    z = 2.5 + bow * (1 - (2 * x / 200.0) ** 2) + RNG.normal(0, sigma, x.size)
    hover = np.flatnonzero(x > 99.0)[::3]  # mixed points off the face near its edge: left out
    z[hover] += RNG.uniform(0.3, 2.0, hover.size)
    spec = load_spec(CONFIG_DIR / "inspection" / "plate_warp.yaml")
    result = inspect_cloud(np.c_[x, y, z], part.nominal, spec, np.eye(4), np.full(x.size, sigma))
    flat = next(f for f in result.features if f.type == "flatness")
    assert flat.values["edge_margin_mm"] == pytest.approx(0.6, rel=0.05)  # two point spacings
    assert abs(flat.values["flatness_mm"] - bow) <= 0.006
    assert flat.values["dropped_points"] >= np.count_nonzero(x[hover] <= 100.0 - flat.values["edge_margin_mm"])
