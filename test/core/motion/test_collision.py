"""Collision checking (python-fcl): known colliding and free states, batch vs single, distances, the matrix."""

import time

import numpy as np
import pytest
import trimesh

from agiprobot_measurement.motion.collision import CollisionChecker, adjacent_link_pairs
from agiprobot_measurement.motion.collision_config import AllowedEntry, CollisionConfig, load_collision_config
from agiprobot_measurement.motion.kinematics_kernels import COMPILED_FROM_STATES
from agiprobot_measurement.station import ConfigError

# Arm lowered into the table: shoulder lift +0.5 rad from home (the arm reaches out over the table).
THROUGH_TABLE = np.array([0.0, 0.5, 0.0, 0.0, 0.0, 0.0])


@pytest.fixture(scope="module")
def checker(station, kinematic_model):
    return CollisionChecker.from_station(station, model=kinematic_model)


@pytest.fixture()
def fresh_checker(station, kinematic_model):
    """A checker the test may change (obstacles, part)."""
    return CollisionChecker.from_station(station, model=kinematic_model)


@pytest.fixture(scope="module")
def random_states(kinematic_model):
    rng = np.random.default_rng(7)
    return rng.uniform(kinematic_model.lower, kinematic_model.upper, size=(400, kinematic_model.dof))


def _table_box(station):
    table = next(o for o in station.scene.objects if o.name == "table")
    return table.pose[:3, 3] - table.size_m / 2, table.pose[:3, 3] + table.size_m / 2


# --------------------------------------------------------------------------------------- configuration
def test_config_file_has_paddings_and_expected_pairs():
    config = load_collision_config()
    assert config.padding_m > 0.0 and config.self_padding_m > 0.0
    for a, b in [
        ("base_link", "shoulder_link"),
        ("wrist_3_link", "laser_scanner_link"),
        ("wrist_1_link", "wrist_2_link"),
        ("base_link", "robot_pedestal"),
    ]:
        assert config.is_allowed(a, b), (a, b)
    # the forearm folding back onto the shoulder housing is a real collision: only other elements allowed
    assert not config.is_allowed("upper_arm_link", "forearm_link", 0, 0)
    # arm links vs. scene objects other than the pedestal under the base are checked
    assert not config.is_allowed("forearm_link", "table")
    assert not config.is_allowed("laser_scanner_link", "part")


def test_adjacent_pairs_skip_links_without_geometry(kinematic_model, checker):
    pairs = adjacent_link_pairs(kinematic_model, checker.robot_links)
    assert ("laser_scanner_link", "wrist_3_link") in pairs  # through tool0, which has no geometry
    assert ("base_link", "shoulder_link") in pairs
    assert ("base_link", "upper_arm_link") not in pairs


@pytest.mark.parametrize(
    "text, message",
    [
        ("allowed_collisions:\n  - {a: base_link, b: table, reason: Maybe}\n", "unknown reason"),
        ("allowed_collisions:\n  - {a: base_link, b: base_link, reason: User}\n", "two different names"),
        ("padding_m: -0.1\n", "padding_m"),
        ("allowed_collisions:\n  - {a: base_link, reason: User}\n", "keys a, b, reason"),
        ("allowed_collisions:\n  - {a: base_link, b: x, reason: User, elements: [[0]]}\n", "element indices"),
    ],
)
def test_bad_config_names_the_problem(tmp_path, text, message):
    path = tmp_path / "collision.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_collision_config(path)


def test_matrix_with_typo_in_link_name_is_rejected(kinematic_model):
    config = CollisionConfig(allowed={frozenset(("forarm_link", "tabel")): AllowedEntry("User")})
    with pytest.raises(ConfigError, match="names no robot link"):
        CollisionChecker(kinematic_model, None, config)
    config = CollisionConfig(
        allowed={
            frozenset(("wrist_1_link", "wrist_3_link")): AllowedEntry(
                "Always", frozenset([frozenset((("wrist_1_link", 5), ("wrist_3_link", 0)))])
            )
        }
    )
    with pytest.raises(ConfigError, match="no collision element 5"):
        CollisionChecker(kinematic_model, None, config)


# ------------------------------------------------------------------------------------------ kinematics
@pytest.mark.parametrize("count", [50, COMPILED_FROM_STATES])  # numpy, compiled
def test_shape_poses_follow_the_kinematic_model(checker, kinematic_model, count):
    states = np.random.default_rng(5).uniform(kinematic_model.lower, kinematic_model.upper, (count, 6))
    reference = kinematic_model.link_poses_batch(states)
    poses = checker.shape_poses(states)
    for s, shape in enumerate(checker.shapes):
        geometry = kinematic_model.urdf.collision[shape.link][shape.element]
        np.testing.assert_allclose(poses[:, s], reference[shape.link] @ geometry.origin, atol=1e-12)


# ------------------------------------------------------------------------------------------ known states
@pytest.mark.parametrize("name", ["home", "up"])
def test_named_states_are_free(checker, station, name):
    q = station.named_states[name]
    assert checker.is_state_valid(q), checker.explain(q)
    assert checker.colliding_pairs(q) == []
    assert checker.min_distance(q).distance_m > 0.0


def test_arm_through_the_table_collides(checker, station, kinematic_model):
    lo, hi = _table_box(station)
    wrist = kinematic_model.link_poses_batch(THROUGH_TABLE[None], ["wrist_1_link"])["wrist_1_link"][0, :3, 3]
    assert np.all(wrist > lo) and np.all(wrist < hi), "the test state must put the wrist inside the table"
    assert not checker.is_state_valid(THROUGH_TABLE)
    assert ("wrist_1_link", "table") in checker.colliding_pairs(THROUGH_TABLE)
    assert checker.min_distance(THROUGH_TABLE).distance_m <= 0.0
    assert "table" in checker.explain(THROUGH_TABLE)


def test_scanner_into_the_part_collides(fresh_checker, station, kinematic_model):
    up = station.named_states["up"]
    emitter = kinematic_model.link_poses_batch(up[None], ["laser_emitter_frame"])["laser_emitter_frame"][0]
    cube = trimesh.creation.box((0.1, 0.1, 0.1))
    # a 10 cm part whose centre sits 3 cm inside the housing's front face
    pose = emitter.copy()
    pose[:3, 3] += emitter[:3, 2] * 0.02
    fresh_checker.set_part(cube, pose=pose)
    assert not fresh_checker.is_state_valid(up)
    assert ("laser_scanner_link", "part") in fresh_checker.colliding_pairs(up)
    # 5 cm in front of the window (outside the 1 cm padding) the same state is free
    pose[:3, 3] += emitter[:3, 2] * 0.08
    fresh_checker.set_part(cube.vertices * 1000.0, cube.faces, pose, scale_to_m=0.001)
    assert fresh_checker.is_state_valid(up), fresh_checker.explain(up)


def test_shape_wholly_inside_a_closed_part_collides(fresh_checker, station, kinematic_model):
    # FCL's mesh BVH only sees surface contact; the checker must catch a housing enclosed by the part
    up = station.named_states["up"]
    housing = kinematic_model.link_poses_batch(up[None], ["laser_scanner_link"])["laser_scanner_link"][0]
    fresh_checker.set_part(trimesh.creation.box((0.6, 0.6, 0.6)), pose=housing)
    assert ("laser_scanner_link", "part") in fresh_checker.colliding_pairs(up)
    assert not fresh_checker.is_state_valid(up)


def test_padding_is_applied_to_the_robot(fresh_checker, station, kinematic_model):
    up = station.named_states["up"]
    emitter = kinematic_model.link_poses_batch(up[None], ["laser_emitter_frame"])["laser_emitter_frame"][0]
    padding = fresh_checker.padding_m
    for gap, free in ((0.5 * padding, False), (1.5 * padding, True)):
        pose = emitter.copy()  # the housing's front face is the emitter window
        pose[:3, 3] += emitter[:3, 2] * (0.025 + gap)
        fresh_checker.add_box("probe", [0.05, 0.05, 0.05], pose)
        assert fresh_checker.is_state_valid(up) == free, gap
        distance, pair = fresh_checker.min_distance(up)
        if free:
            assert pair == ("laser_scanner_link", "probe")
            assert distance == pytest.approx(gap - padding, abs=1e-6)


def test_real_self_collision_is_detected(checker, kinematic_model, random_states):
    """A sampled state where the scanner housing overlaps the forearm, confirmed by point sampling."""
    zero_padding = CollisionChecker(kinematic_model, None, CollisionConfig(padding_m=0.0, self_padding_m=0.0))
    for q in random_states:
        if ("forearm_link", "laser_scanner_link") in zero_padding.colliding_pairs(q):
            break
    else:
        pytest.fail("no sampled state with the scanner in the forearm")
    poses = kinematic_model.link_poses_batch(q[None])
    housing = kinematic_model.urdf.collision["laser_scanner_link"][0]
    tube = kinematic_model.urdf.collision["forearm_link"][0]
    grid = np.stack(np.meshgrid(*[np.linspace(-0.5, 0.5, 25)] * 3), axis=-1).reshape(-1, 3) * housing.size
    world = poses["laser_scanner_link"][0] @ housing.origin @ np.c_[grid, np.ones(len(grid))].T
    local = (np.linalg.inv(poses["forearm_link"][0] @ tube.origin) @ world)[:3].T
    inside = (np.hypot(local[:, 0], local[:, 1]) < tube.radius) & (np.abs(local[:, 2]) < tube.length / 2)
    assert inside.any(), "the housing and the forearm tube really overlap"
    assert not checker.is_state_valid(q)


def test_joint_limits_are_part_of_validity(checker, station):
    q = station.named_states["up"].copy()
    q[2] = 0.5  # elbow limit is 0.1 rad
    assert not checker.is_state_valid(q)
    assert "elbow_joint" in checker.explain(q)


# ------------------------------------------------------------------------------------------ consistency
def test_batch_equals_single_and_exhaustive(checker, random_states):
    batch = checker.check_states(random_states)
    assert 0.1 < batch.mean() < 0.95, "the sample should hold valid and invalid states"
    single = np.array([checker.is_state_valid(q) for q in random_states])
    np.testing.assert_array_equal(batch, single)
    within = checker.model.within_limits(random_states)
    exhaustive = np.array([w and not checker.colliding_pairs(q) for q, w in zip(random_states, within, strict=True)])
    np.testing.assert_array_equal(batch, exhaustive)


def test_the_compiled_broad_phase_gives_the_numpy_candidates(checker, random_states, monkeypatch):
    import agiprobot_measurement.motion.collision as collision

    # states spread over the joint ranges and states near the first ones (close to the scene, the part, itself)
    rng = np.random.default_rng(3)
    near = random_states + rng.normal(0.0, 0.05, random_states.shape)
    states = np.concatenate([random_states, near, np.tile(random_states[:50], (6, 1))])
    assert len(states) >= COMPILED_FROM_STATES
    poses = checker.shape_poses(states)
    compiled = checker._broad_phase(poses)
    monkeypatch.setattr(collision, "COMPILED_FROM_STATES", len(states) + 1)
    plain = checker._broad_phase(poses)
    assert plain[0].any() and len(plain[1]) and len(plain[2])  # each kind of outcome occurs
    for got, expected in zip(compiled, plain, strict=True):
        np.testing.assert_array_equal(got, expected)
    batch = checker.check_states(states)
    monkeypatch.setattr(collision, "COMPILED_FROM_STATES", COMPILED_FROM_STATES)
    np.testing.assert_array_equal(checker.check_states(states), batch)


def test_min_distance_sign_matches_validity(checker, random_states):
    within = checker.model.within_limits(random_states[:150])
    for q, valid, ok in zip(random_states[:150], checker.check_states(random_states[:150]), within, strict=True):
        distance = checker.min_distance(q).distance_m
        assert (distance > 0.0) == valid or not ok, (q, distance, checker.colliding_pairs(q))


def test_allowed_pairs_are_not_reported(checker, station):
    home = station.named_states["home"]
    everything = checker.colliding_pairs(home, include_allowed=True)
    assert ("base_link", "robot_pedestal") in everything  # the robot stands on it
    assert ("base_link", "shoulder_link") in everything  # joint housings overlap by construction
    assert checker.colliding_pairs(home) == []


def test_add_and_remove_obstacles(fresh_checker, station, kinematic_model):
    up = station.named_states["up"]
    wrist = kinematic_model.link_poses_batch(up[None], ["wrist_2_link"])["wrist_2_link"][0]
    fresh_checker.add_sphere("ball", 0.05, wrist)
    assert not fresh_checker.is_state_valid(up)
    assert "ball" in fresh_checker.object_names()
    fresh_checker.remove_object("ball")
    assert fresh_checker.is_state_valid(up)
    fresh_checker.add_cylinder("post", 0.05, 0.5, wrist)
    fresh_checker.allow_collision("wrist_2_link", "post")
    fresh_checker.allow_collision("wrist_1_link", "post")
    fresh_checker.allow_collision("wrist_3_link", "post")
    fresh_checker.allow_collision("laser_scanner_link", "post")
    fresh_checker.allow_collision("forearm_link", "post")
    assert fresh_checker.is_state_valid(up), fresh_checker.explain(up)
    fresh_checker.disallow_collision("wrist_2_link", "post")
    assert not fresh_checker.is_state_valid(up)
    with pytest.raises(KeyError, match="no object"):
        fresh_checker.remove_object("nothing")
    fresh_checker.remove_part()
    assert "part" not in fresh_checker.object_names()


@pytest.mark.parametrize("bad", [np.full(6, np.nan), np.zeros(5), np.zeros(7)])
def test_bad_joint_values_raise(checker, bad):
    with pytest.raises(ValueError):
        checker.is_state_valid(bad)
    with pytest.raises(ValueError):
        checker.check_states(bad[None])


def test_batch_throughput(checker, random_states):
    """>= 2000 full-robot states/s against the station scene with the cube part (measured: tens of thousands)."""
    states = np.tile(random_states, (10, 1))
    checker.check_states(states[:100])
    checker.check_states(states[:COMPILED_FROM_STATES])  # large batches load the compiled kernels once
    started = time.perf_counter()
    checker.check_states(states)
    rate = len(states) / (time.perf_counter() - started)
    assert rate >= 2000.0, f"{rate:.0f} states/s"


def test_set_part_replaces_the_part_and_rejects_bad_meshes(fresh_checker):
    cube = trimesh.creation.box((0.1, 0.1, 0.1))
    fresh_checker.set_part(cube, pose=np.eye(4), name="other_part")
    assert "other_part" in fresh_checker.object_names() and "part" not in fresh_checker.object_names()
    with pytest.raises(ValueError, match="non-finite"):
        fresh_checker.set_part(np.full((3, 3), np.nan), np.array([[0, 1, 2]]), np.eye(4))
    assert fresh_checker.part_name == "other_part" and "other_part" in fresh_checker.object_names()
    plate = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])  # flat: a zero-height box
    fresh_checker.set_part(plate, pose=np.eye(4))
    assert fresh_checker.object_names().count("part") == 1 and "other_part" not in fresh_checker.object_names()


def test_a_finely_meshed_part_split_into_trees_answers_as_one(station, kinematic_model, monkeypatch):
    # a large mesh is built as several bounding-volume trees (so that a time limit can end the build); the
    # answers must not change: the same part as one tree and as many small ones, near the scanner's window
    from agiprobot_measurement.motion import collision as collision_module

    up = station.named_states["up"]
    emitter = kinematic_model.link_poses_batch(up[None], ["laser_emitter_frame"])["laser_emitter_frame"][0]
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.1)  # 1,280 faces
    pose = np.eye(4)
    pose[:3, 3] = emitter[:3, 3] + emitter[:3, 2] * 0.11
    states = up + np.random.default_rng(3).normal(0.0, 0.05, size=(300, kinematic_model.dof))
    whole = CollisionChecker.from_station(station, model=kinematic_model)
    whole.set_part(sphere, pose=pose)
    monkeypatch.setattr(collision_module, "BVH_PIECE_FACES", 100)
    split = CollisionChecker.from_station(station, model=kinematic_model)
    split.set_part(sphere, pose=pose)
    assert len(split._objects["part"].pieces) == 13 and len(whole._objects["part"].pieces) == 1
    valid = whole.check_states(states)
    np.testing.assert_array_equal(split.check_states(states), valid)
    part_hits = 0
    for q in states[:60]:
        pairs = whole.colliding_pairs(q)
        part_hits += any("part" in pair for pair in pairs)
        assert split.colliding_pairs(q) == pairs
        split_gap, whole_gap = split.min_distance(q), whole.min_distance(q)
        assert split_gap.pair == whole_gap.pair and split_gap.distance_m == pytest.approx(
            whole_gap.distance_m, abs=1e-9
        )
    assert 5 < part_hits < 55
