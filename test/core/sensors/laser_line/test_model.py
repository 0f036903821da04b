"""SensorModel: the reference equations, the measurability rules, and batch == per-viewpoint."""

import math
import time

import numpy as np
import pytest
import trimesh

from agiprobot_measurement.planning.candidates.viewpoint import ViewPoint, generate_viewpoint_poses
from agiprobot_measurement.planning.part_loading import load_part
from agiprobot_measurement.sensors.laser_line.model import (
    MeasurabilityResult,
    ProcessingContextError,
    SensorModel,
    supporting_faces,
)
from agiprobot_measurement.station import PACKAGE_ROOT

PARAMS = {
    "optimal_standoff_mm": 181.82,
    "minimum_standoff_mm": 127.27,
    "maximum_standoff_mm": 227.27,
    "theta_max_rad": 0.785398,
    "psi_max_rad": 0.785398,
    "K_u": 2.63e-6,
    "alpha_rad": 0.39602,
    "fan_angle_rad": 0.53669,
}
CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"
UP = np.array([0.0, 0.0, 1.0])


def u_reference(z, psi, p=PARAMS):
    """The reference page's u(z, psi), written out independently of the module."""
    xi_0 = math.sin(p["alpha_rad"]) * p["optimal_standoff_mm"]
    root = math.sqrt(z * z + xi_0 * xi_0 - 2 * z * xi_0 * math.sin(p["alpha_rad"]))
    return p["K_u"] * root / math.cos(psi) * z


@pytest.fixture(scope="module")
def model():
    return SensorModel(PARAMS)


@pytest.fixture
def plate_model():
    """A 300 x 300 x 10 mm plate (top at z = 5) with a grid of samples on its top face."""
    plate = trimesh.creation.box(extents=(300.0, 300.0, 10.0))
    xs, ys = np.meshgrid(np.arange(-80.0, 81.0, 20.0), np.arange(-80.0, 81.0, 20.0))
    points = np.column_stack([xs.ravel(), ys.ravel(), np.full(xs.size, 5.0)])
    _, _, faces = trimesh.proximity.closest_point(plate, points)
    sm = SensorModel(PARAMS)
    sm.set_processing_context(plate, points, faces)
    return sm, points


def index_of(points, xyz):
    return int(np.flatnonzero(np.all(np.isclose(points, xyz), axis=1))[0])


def head_on_pose(point, standoff=PARAMS["optimal_standoff_mm"]):
    """Looking straight down at ``point`` (x = world x, y = -world y, z = -world z)."""
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0])
    pose[:3, 3] = np.asarray(point) + standoff * UP
    return pose


# --------------------------------------------------------------------------------------------- equations
def test_uncertainty_matches_hand_computed_values(model):
    # xi_0 = sin(0.39602) * 181.82 = 0.385749 * 181.82 = 70.1370 mm
    assert model.xi_0 == pytest.approx(math.sin(0.39602) * 181.82, rel=1e-12)
    assert model.xi_0 == pytest.approx(70.1370, abs=1e-3)
    for z, psi in [(181.82, 0.0), (150.0, 0.3), (127.27, -0.5), (227.27, 0.785398)]:
        assert model.evaluate_uncertainty(z, psi) == pytest.approx(u_reference(z, psi), rel=1e-12)
    # u(181.82, 0) = 2.63e-6 * sqrt(181.82^2 + 70.1370^2 - 2 * 181.82 * 70.1370 * 0.385749) * 181.82
    #              = 2.63e-6 * 167.7478 * 181.82 = 0.080215 mm
    assert model.evaluate_uncertainty(181.82, 0.0) == pytest.approx(0.080215, abs=1e-6)


def test_uncertainty_is_nan_outside_the_limits_and_broadcasts(model):
    assert math.isnan(model.evaluate_uncertainty(100.0, 0.0))
    assert math.isnan(model.evaluate_uncertainty(230.0, 0.0))
    assert math.isnan(model.evaluate_uncertainty(180.0, 0.8))
    assert math.isnan(model.evaluate_uncertainty(float("nan"), 0.0))
    values = model.evaluate_uncertainty(np.array([130.0, 180.0, 300.0]), 0.1)
    assert values.shape == (3,)
    assert values[0] == pytest.approx(u_reference(130.0, 0.1))
    assert math.isnan(values[2])


def test_min_max_score_and_median_angle(model):
    u_min = u_reference(127.27, 0.0)
    u_max = u_reference(227.27, 0.785398)
    assert model.get_min_uncertainty() == pytest.approx(u_min, rel=1e-12)
    assert model.get_max_uncertainty() == pytest.approx(u_max, rel=1e-12)
    assert model.evaluate_score(127.27, 0.0) == pytest.approx(1.0)
    assert model.evaluate_score(227.27, 0.785398) == pytest.approx(0.0, abs=1e-12)
    z, psi = 181.82, 0.2
    assert model.evaluate_score(z, psi) == pytest.approx((u_max - u_reference(z, psi)) / (u_max - u_min))
    assert model.get_median_deviation_angle() == pytest.approx(0.785398 / 2)
    assert model.get_optimal_standoff() == 181.82
    assert model.laser_emission_perception_distance == pytest.approx(math.tan(0.39602) * 181.82)


def test_parameter_map_validation():
    with pytest.raises(ValueError, match="K_u"):
        SensorModel({k: v for k, v in PARAMS.items() if k != "K_u"})
    bad = dict(PARAMS, minimum_standoff_mm=190.0)
    with pytest.raises(ValueError, match="minimum_standoff"):
        SensorModel(bad)
    with pytest.raises(ValueError, match="positive"):
        SensorModel(dict(PARAMS, alpha_rad=-1.0))
    aliases = {
        "optimal_standoff": 181.82,
        "minimum_standoff": 127.27,
        "maximum_standoff": 227.27,
        "maximum_deviation_theta": 0.785398,
        "maximum_deviation_psi": 0.785398,
        "K": 2.63e-6,
        "alpha": 0.39602,
        "fan_angle": 0.53669,
    }
    assert SensorModel(aliases).get_max_uncertainty() == SensorModel(PARAMS).get_max_uncertainty()


def test_from_config_reads_the_station_scanner():
    sm = SensorModel.from_config()
    assert sm.get_optimal_standoff() == pytest.approx(181.82)
    assert sm.parameters["profile_rate_hz"] == 100.0


def test_scanning_frustum(model):
    frustum = model.get_scanning_frustum(100.0)
    assert frustum.is_watertight
    tan_half = math.tan(0.53669 / 2)
    z0, z1 = 127.27, 227.27
    assert frustum.volume == pytest.approx(200.0 * (z1 - z0) * (z0 + z1) * tan_half, rel=1e-9)
    assert np.allclose(frustum.bounds, [[-100, -z1 * tan_half, z0], [100, z1 * tan_half, z1]])
    inside = frustum.contains([[50.0, 0.0, 181.82], [0.0, 40.0, 180.0]])
    outside = frustum.contains([[0.0, 0.0, 120.0], [0.0, 60.0, 180.0], [120.0, 0.0, 181.82]])
    assert inside.all() and not outside.any()
    with pytest.raises(ValueError):
        model.get_scanning_frustum(0.0)


# ----------------------------------------------------------------------------------------- measurability
def test_needs_a_context():
    with pytest.raises(ProcessingContextError):
        SensorModel(PARAMS).process_viewpoint_metrologically(np.eye(4), 1.0)


def test_plate_head_on_at_optimal_standoff(plate_model):
    sm, points = plate_model
    centre = index_of(points, (0.0, 0.0, 5.0))
    indices, uncertainties, t0 = sm.process_viewpoint_metrologically(head_on_pose(points[centre]), 0.5)
    expected_u = u_reference(181.82, 0.0)  # |s . n| = 1 head-on
    assert centre in indices
    assert np.allclose(uncertainties, expected_u, rtol=1e-9)  # every point at z = optimal, psi = 0
    assert t0[list(indices).index(centre)] == pytest.approx(0.0, abs=1e-9)
    # the laser line sweeps along x: t0 is the x offset; the fan reaches |y| <= 181.82 tan(fan / 2) = 50.4
    assert np.allclose(t0, points[indices, 0])
    assert set(np.unique(points[indices, 1])) == {-40.0, -20.0, 0.0, 20.0, 40.0}
    assert len(indices) == 9 * 5


def test_plate_limits_of_psi_theta_and_standoff(plate_model):
    sm, points = plate_model
    centre = index_of(points, (0.0, 0.0, 5.0))
    p = points[centre]

    def measurable(**kwargs):
        standoff = kwargs.pop("standoff", 181.82)
        view = ViewPoint(p, UP, 0.0, standoff, **kwargs)
        return centre in sm.process_viewpoint_metrologically(view, 1.0)[0]

    eps = 1e-4
    assert measurable(tilt_psi=0.785398 - eps) and measurable(tilt_psi=-(0.785398 - eps))
    assert not measurable(tilt_psi=0.785398 + eps) and not measurable(tilt_psi=-(0.785398 + eps))
    assert measurable(tilt_theta=0.785398 - eps) and measurable(tilt_theta=-(0.785398 - eps))
    assert not measurable(tilt_theta=0.785398 + eps)
    assert measurable(standoff=127.27 + 1e-3) and not measurable(standoff=127.27 - 1e-3)
    assert measurable(standoff=227.27 - 1e-3) and not measurable(standoff=227.27 + 1e-3)


def test_psi_uncertainty_and_threshold(plate_model):
    sm, points = plate_model
    centre = index_of(points, (0.0, 0.0, 5.0))
    psi = 0.5
    view = ViewPoint(points[centre], UP, 0.0, 181.82, tilt_psi=psi)
    indices, uncertainties, _ = sm.process_viewpoint_metrologically(view, 1.0)
    # z = 181.82 along the boresight, |s . n| = cos(psi)
    expected = u_reference(181.82, psi) * math.cos(psi)
    value = uncertainties[list(indices).index(centre)]
    assert value == pytest.approx(expected, rel=1e-9)
    assert centre in sm.process_viewpoint_metrologically(view, expected * (1 + 1e-9))[0]
    assert centre not in sm.process_viewpoint_metrologically(view, expected * (1 - 1e-9))[0]


def test_maximum_deflection_limits_the_trajectory(plate_model):
    sm, points = plate_model
    pose = head_on_pose(points[index_of(points, (0.0, 0.0, 5.0))])
    far = index_of(points, (80.0, 0.0, 5.0))
    assert far in sm.process_viewpoint_metrologically(pose, 1.0, maximum_deflection=80.5)[0]
    assert far not in sm.process_viewpoint_metrologically(pose, 1.0, maximum_deflection=79.5)[0]


def test_a_backfacing_plate_is_not_measurable(plate_model):
    sm, points = plate_model
    pose = head_on_pose(points[0])
    pose[:3, 3] = points[0] - 181.82 * UP  # below the plate, looking up at its top face's back
    pose[:3, :3] = np.diag([1.0, 1.0, 1.0])
    assert len(sm.process_viewpoint_metrologically(pose, 1.0)[0]) == 0


def occluded_scene(bar_offset_x):
    """Plate plus a 10 x 10 x 4 mm bar 50 mm above the sample at the origin, shifted along x."""
    plate = trimesh.creation.box(extents=(300.0, 300.0, 10.0))
    bar = trimesh.creation.box(extents=(10.0, 10.0, 4.0))
    bar.apply_translation((bar_offset_x, 0.0, 55.0))
    mesh = trimesh.util.concatenate([plate, bar])
    points = np.array([[0.0, 0.0, 5.0], [30.0, 30.0, 5.0]])
    _, _, faces = trimesh.proximity.closest_point(mesh, points)
    sm = SensorModel(PARAMS)
    sm.set_processing_context(mesh, points, faces)
    return sm, points


def test_a_point_hidden_from_the_emitter_is_not_measurable():
    # emitter ray: straight down onto the sample when the emitter passes above it (t0 = 0)
    sm, points = occluded_scene(bar_offset_x=0.0)
    indices, _, _ = sm.process_viewpoint_metrologically(head_on_pose(points[0]), 1.0)
    assert 0 not in indices and 1 in indices


def test_a_point_hidden_from_the_detector_is_not_measurable():
    # the detector ray starts 75.6 mm behind the emitter (-x); 50 mm above the sample it passes at
    # x = -75.6 * 50 / 181.82 = -20.8 mm: a bar there blocks it and leaves the emitter ray free
    baseline = math.tan(0.39602) * 181.82
    sm, points = occluded_scene(bar_offset_x=-baseline * 50.0 / 181.82)
    indices, _, _ = sm.process_viewpoint_metrologically(head_on_pose(points[0]), 1.0)
    assert 0 not in indices and 1 in indices
    # turned around (x reversed), the detector looks from +x and the bar no longer matters
    pose = head_on_pose(points[0])
    pose[:3, :3] = np.diag([-1.0, 1.0, -1.0])
    assert 0 in sm.process_viewpoint_metrologically(pose, 1.0)[0]
    # and without the bar the sample is measurable from the first pose
    sm_free, _ = occluded_scene(bar_offset_x=500.0)
    assert 0 in sm_free.process_viewpoint_metrologically(head_on_pose(points[0]), 1.0)[0]


def test_supporting_faces():
    cube = trimesh.creation.box(extents=(10, 10, 10))
    assert supporting_faces(cube).all()
    plate = trimesh.creation.box(extents=(300.0, 300.0, 10.0))
    bar = trimesh.creation.box(extents=(10.0, 10.0, 4.0))
    bar.apply_translation((0.0, 0.0, 55.0))
    mesh = trimesh.util.concatenate([plate, bar])
    support = supporting_faces(mesh)
    top_of_plate = (mesh.face_normals[:, 2] > 0.99) & (mesh.triangles_center[:, 2] < 6.0)
    assert not support[top_of_plate].any()
    assert support[~top_of_plate & (mesh.triangles_center[:, 2] < 6.0)].all()


# ----------------------------------------------------------------------------------------------- batch
def reference_measurable(sm, mesh, points, normals, pose, threshold, deflection):
    """Slow reference: the reference page's rules for one pose, rays through trimesh's own intersector."""
    t, l, s = pose[:3, 0], pose[:3, 1], pose[:3, 2]
    anchor = pose[:3, 3]
    intersector = trimesh.ray.ray_triangle.RayMeshIntersector(mesh)
    result = {}
    for i, (p, n) in enumerate(zip(points, normals, strict=True)):
        t0 = float((p - anchor) @ t)
        e = anchor + t0 * t
        v = p - e
        z = float(s @ v)
        psi = math.atan2(float(t @ n), float(-(s @ n)))
        v1 = np.array([v @ l, v @ s])
        v2 = np.array([n @ l, n @ s])
        with np.errstate(invalid="ignore", divide="ignore"):
            theta = math.acos(np.clip(-(v1 @ v2) / (np.linalg.norm(v1) * np.linalg.norm(v2)), -1, 1))
        if not (abs(t0) <= deflection and 127.27 < z < 227.27 and abs(v @ l) <= z * math.tan(0.53669 / 2)):
            continue
        if not (abs(psi) < 0.785398 and theta < 0.785398):
            continue
        u = u_reference(z, psi) * abs(float(s @ n))
        if u > threshold:
            continue
        detector = e - sm.laser_emission_perception_distance * t
        free = True
        for origin in (e, detector):
            ray = p - origin
            if ray @ n >= 0:
                free = False
                break
            length = np.linalg.norm(ray)
            locations, _, _ = intersector.intersects_location([origin], [ray / length], multiple_hits=True)
            if len(locations) and (np.linalg.norm(locations - origin, axis=1) < length - 0.05).any():
                free = False
                break
        if free:
            result[i] = (u, t0)
    return result


@pytest.fixture(scope="module")
def cube_context():
    part = load_part(CUBE)
    samples = part.sample(0.01, seed=3)
    sm = SensorModel(PARAMS)
    sm.set_processing_context(part.mesh, samples.points, samples.face_ids)
    return sm, part, samples


def random_candidates(sm, samples, count, seed):
    rng = np.random.default_rng(seed)
    candidates = generate_viewpoint_poses(samples.points, samples.normals, 12, "full", sm)
    chosen = rng.choice(len(candidates.poses), size=count, replace=False)
    poses = candidates.poses[chosen].copy()
    # move a few anchors so that not every view is centred on a sample
    poses[: count // 2, :3, 3] += rng.normal(scale=15.0, size=(count // 2, 3))
    return poses


def assert_batch_equals_single(sm, poses, threshold=0.15, deflection=500.0):
    batch = sm.evaluate_viewpoints_batch(poses, threshold, deflection)
    assert isinstance(batch, MeasurabilityResult) and batch.n_views == len(poses)
    for j, pose in enumerate(poses):
        single = sm.process_viewpoint_metrologically(pose, threshold, deflection)
        for a, b in zip(batch.view(j), single, strict=True):
            np.testing.assert_array_equal(a, b)
    return batch


def test_batch_equals_per_viewpoint_on_the_cube(cube_context):
    sm, _, samples = cube_context
    batch = assert_batch_equals_single(sm, random_candidates(sm, samples, 60, seed=7))
    assert batch.nnz > 0 and (batch.counts > 0).sum() > 30


def test_batch_equals_per_viewpoint_on_a_real_part(shared_dir):
    part = load_part(shared_dir / "parts" / "featuretype.STL", units="inch")
    samples = part.sample(0.01, seed=5)
    sm = SensorModel(PARAMS)
    sm.set_processing_context(part.mesh, samples.points, samples.face_ids)
    poses = random_candidates(sm, samples, 60, seed=11)
    batch = assert_batch_equals_single(sm, poses)
    assert batch.nnz > 0
    # culling the faces on the convex hull only skips rays that cannot be blocked
    forced = SensorModel(PARAMS)
    forced.set_processing_context(part.mesh, samples.points, samples.face_ids, cull_supporting_faces=False)
    full = forced.evaluate_viewpoints_batch(poses, 0.15)
    np.testing.assert_array_equal(full.indptr, batch.indptr)
    np.testing.assert_array_equal(full.point_indices, batch.point_indices)
    np.testing.assert_array_equal(full.uncertainties, batch.uncertainties)


def test_batch_agrees_with_a_slow_reference(shared_dir):
    part = load_part(shared_dir / "parts" / "featuretype.STL", units="inch")
    samples = part.sample(0.005, seed=2)
    sm = SensorModel(PARAMS)
    sm.set_processing_context(part.mesh, samples.points, samples.face_ids)
    poses = random_candidates(sm, samples, 8, seed=3)
    batch = sm.evaluate_viewpoints_batch(poses, 0.15, 200.0)
    mismatches = 0
    total = 0
    for j, pose in enumerate(poses):
        expected = reference_measurable(sm, part.mesh, samples.points, samples.normals, pose, 0.15, 200.0)
        indices, uncertainties, t0 = batch.view(j)
        got = dict(zip(indices.tolist(), zip(uncertainties, t0, strict=True), strict=True))
        mismatches += len(set(got) ^ set(expected))
        total += len(expected)
        for i in set(got) & set(expected):
            assert got[i][0] == pytest.approx(expected[i][0], rel=1e-9)
            assert got[i][1] == pytest.approx(expected[i][1], abs=1e-9)
    assert total > 50
    # the reference's coarser occlusion tolerance may decide grazing rays differently
    assert mismatches <= max(1, total // 200)


def test_chunking_threads_and_concatenation_do_not_change_the_result(cube_context):
    sm, _, samples = cube_context
    poses = random_candidates(sm, samples, 40, seed=1)
    a = sm.evaluate_viewpoints_batch(poses, 0.15)
    calls = []
    b = sm.evaluate_viewpoints_batch(
        poses, 0.15, chunk_elements=1000, workers=2, progress=lambda done, total: calls.append((done, total))
    )
    c = sm.evaluate_viewpoints_batch(poses, 0.15, chunk_elements=1000, workers=1)
    d = MeasurabilityResult.concatenate(
        [sm.evaluate_viewpoints_batch(poses[:15], 0.15), sm.evaluate_viewpoints_batch(poses[15:], 0.15)]
    )
    for other in (b, c, d):
        assert other.n_views == a.n_views
        for name in ("indptr", "point_indices", "uncertainties", "trajectory_distances"):
            np.testing.assert_array_equal(getattr(a, name), getattr(other, name))
    assert calls[-1] == (40, 40) and [done for done, _ in calls] == sorted(done for done, _ in calls)


def test_result_accessors(cube_context):
    sm, _, samples = cube_context
    poses = random_candidates(sm, samples, 20, seed=4)
    poses[0, :3, 3] += 5000.0  # far away: sees nothing
    result = sm.evaluate_viewpoints_batch(poses, 0.15)
    assert result.counts[0] == 0 and math.isnan(result.t0_min[0]) and math.isnan(result.max_uncertainty[0])
    matrix = result.uncertainty
    assert matrix.shape == (len(samples), 20)
    assert matrix.nnz == result.nnz
    assert result.measurability.dtype == bool
    for j in range(1, 20):
        indices, uncertainties, t0 = result.view(j)
        column = matrix[:, j].toarray().ravel()
        np.testing.assert_array_equal(np.flatnonzero(column), indices)
        np.testing.assert_array_equal(column[indices], uncertainties)
        if len(t0):
            assert result.t0_min[j] == t0.min() and result.t0_max[j] == t0.max()
            assert result.max_uncertainty[j] == uncertainties.max()
    empty = sm.evaluate_viewpoints_batch(np.zeros((0, 4, 4)), 0.15)
    assert empty.n_views == 0 and empty.nnz == 0
    with pytest.raises(ValueError):
        sm.evaluate_viewpoints_batch(np.full((1, 4, 4), np.nan), 0.15)
    with pytest.raises(ValueError):
        sm.evaluate_viewpoints_batch(poses, -1.0)
    scaled = poses[:1].copy()
    scaled[0, :3, :3] *= 2.0
    with pytest.raises(ValueError, match="rigid"):
        sm.evaluate_viewpoints_batch(scaled, 0.15)


def test_without_embree_the_rays_give_the_same_result(shared_dir, monkeypatch):
    part = load_part(shared_dir / "parts" / "featuretype.STL", units="inch")
    samples = part.sample(0.005, seed=8)
    sm = SensorModel(PARAMS)
    sm.set_processing_context(part.mesh, samples.points, samples.face_ids, cull_supporting_faces=False)
    poses = random_candidates(sm, samples, 30, seed=2)
    with_embree = sm.evaluate_viewpoints_batch(poses, 0.15)
    monkeypatch.setattr(sm._context.caster, "scene", None)  # the fallback: trimesh's own ray queries
    without = sm.evaluate_viewpoints_batch(poses, 0.15)
    np.testing.assert_array_equal(with_embree.indptr, without.indptr)
    np.testing.assert_array_equal(with_embree.point_indices, without.point_indices)


def test_set_processing_context_validates(cube_context):
    _, part, samples = cube_context
    sm = SensorModel(PARAMS)
    with pytest.raises(ValueError, match="face indices"):
        sm.set_processing_context(part.mesh, samples.points, samples.face_ids[:-1])
    with pytest.raises(ValueError, match="face indices"):
        sm.set_processing_context(part.mesh, samples.points[:1], [99])


def brute_force_supporting(mesh, tolerance):
    hull = np.asarray(mesh.convex_hull.vertices)
    height = mesh.face_normals @ hull.T - np.einsum("ij,ij->i", mesh.face_normals, mesh.triangles[:, 0])[:, None]
    return (height.max(axis=1) <= tolerance) & (np.linalg.norm(mesh.face_normals, axis=1) > 0.5)


def test_supporting_faces_is_near_linear_and_equals_the_brute_force():
    rng = np.random.default_rng(0)
    bumpy = trimesh.creation.icosphere(4)
    bumpy.vertices *= 1.0 + 0.1 * rng.random((len(bumpy.vertices), 1))
    for mesh in (trimesh.creation.torus(50, 10), trimesh.creation.annulus(10, 30, 20), bumpy):
        expected = brute_force_supporting(mesh, 1e-6 * mesh.scale)
        assert np.array_equal(supporting_faces(mesh), expected)
    # a convex mesh of 327,680 faces: every face supports; the brute force took minutes
    sphere = trimesh.creation.icosphere(subdivisions=7, radius=50.0)
    sphere.convex_hull  # noqa: B018 (qhull's own time is not the test's subject)
    start = time.perf_counter()
    assert supporting_faces(sphere).all()
    assert time.perf_counter() - start < 10.0
