"""Part loading (units, transform, downward faces, bad input) and surface sampling."""

import dataclasses
import importlib.util
import math
import warnings

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from agiprobot_measurement.common import limits
from agiprobot_measurement.planning import part_loading
from agiprobot_measurement.planning.part_loading import (
    LoadedPart,
    PartLoadError,
    PartWarning,
    downward_faces,
    load_part,
    sample_surface,
    validate_rigid_transform,
)
from agiprobot_measurement.station import PACKAGE_ROOT

CUBE = PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl"


def rotation_x(angle_deg, translation=(0.0, 0.0, 0.0)):
    a = math.radians(angle_deg)
    matrix = np.eye(4)
    matrix[1:3, 1:3] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    matrix[:3, 3] = translation
    return matrix


@pytest.fixture(scope="module")
def cube() -> LoadedPart:
    with warnings.catch_warnings():
        warnings.simplefilter("error", PartWarning)  # the benchmark cube must load cleanly
        return load_part(CUBE)


def test_cube_loads_in_mm_without_its_bottom(cube):
    assert cube.mesh.is_watertight and len(cube.mesh.faces) == 12
    assert np.allclose(cube.mesh.extents, 100.0)
    assert len(cube.measurable_faces) == 10
    assert not (cube.mesh.face_normals[cube.measurable_faces, 2] < -0.9).any()
    assert cube.measurable_area == pytest.approx(50000.0)
    assert cube.measurable_mesh.area == pytest.approx(50000.0)
    assert cube.warnings == []


def test_downward_faces_follow_the_transform_and_the_threshold():
    # tilted by 15 degrees the former bottom is 15 degrees off -z: removed at 20, kept at 10
    tilted = load_part(CUBE, transform=rotation_x(15.0))
    assert len(tilted.measurable_faces) == 10
    kept = load_part(CUBE, transform=rotation_x(15.0), remove_threshold_angle_deg=10.0)
    assert len(kept.measurable_faces) == 12
    # turned on its side, a former side face is the bottom now
    turned = load_part(CUBE, transform=rotation_x(90.0, translation=(450.0, -550.0, 1000.0)))
    bottom = np.setdiff1d(np.arange(12), turned.measurable_faces)
    assert np.allclose(turned.mesh.face_normals[bottom], [0, 0, -1])
    # the cube's centre (0, 0, 50) turns to (0, -50, 0) and is then moved by the translation
    assert np.allclose(turned.mesh.bounds.mean(axis=0), [450.0, -600.0, 1000.0])
    assert len(load_part(CUBE, remove_downside=False).measurable_faces) == 12
    with pytest.raises(ValueError):
        downward_faces(turned.mesh, 120.0)


def test_sampling_count_reproducibility_and_faces(cube):
    density = 0.03
    samples = cube.sample(density, seed=4)
    assert len(samples) == round(50000.0 * density) == 1500
    again = cube.sample(density, seed=4)
    np.testing.assert_array_equal(samples.points, again.points)
    np.testing.assert_array_equal(samples.face_ids, again.face_ids)
    other = cube.sample(density, seed=5)
    assert not np.array_equal(samples.points, other.points)
    # every point lies on its face: on the face's plane, barycentric coordinates within [0, 1]
    triangles = cube.mesh.triangles[samples.face_ids]
    barycentric = trimesh.triangles.points_to_barycentric(triangles, samples.points)
    assert (barycentric > -1e-9).all() and (barycentric < 1 + 1e-9).all()
    heights = np.einsum("ij,ij->i", samples.points - triangles[:, 0], cube.mesh.face_normals[samples.face_ids])
    assert np.abs(heights).max() < 1e-9
    np.testing.assert_array_equal(samples.normals, cube.mesh.face_normals[samples.face_ids])
    # downward faces are never sampled
    assert np.isin(samples.face_ids, cube.measurable_faces).all()
    points, face_ids, normals = samples  # unpacks
    assert points.shape == (1500, 3) and face_ids.shape == (1500,) and normals.shape == (1500, 3)


def test_sampling_is_even(cube):
    samples = cube.sample(0.03, seed=1)
    spacing = math.sqrt(50000.0 / 1500)  # 5.8 mm per point on a square grid
    distances, _ = cKDTree(samples.points).query(samples.points, k=2)
    nearest = distances[:, 1]
    # uniform random sampling would leave near-coincident pairs; an even spread keeps them apart
    assert nearest.min() > 0.5 * spacing
    assert nearest.mean() == pytest.approx(0.8 * spacing, rel=0.15)
    # every face gets its share of the points
    per_face_area = np.bincount(samples.face_ids, minlength=12)
    sides = per_face_area.reshape(6, 2).sum(axis=1)
    assert sorted(sides)[1:] == pytest.approx([300] * 5, abs=25)


def test_sampling_arguments(cube):
    with pytest.raises(ValueError):
        sample_surface(cube.mesh, 0.0)
    with pytest.raises(ValueError):
        sample_surface(cube.mesh, float("nan"))
    assert len(sample_surface(cube.mesh, 1e-6)) == 0  # round(0.06) points


def test_units_scale_to_mm(shared_dir):
    inch = load_part(shared_dir / "parts" / "featuretype.STL", units="inch")
    raw = trimesh.load(shared_dir / "parts" / "featuretype.STL")
    np.testing.assert_allclose(inch.mesh.extents, raw.extents * 25.4)
    assert inch.scale_to_mm == 25.4 and inch.warnings == []
    scaled = load_part(shared_dir / "parts" / "featuretype.STL", scale=25.4)
    np.testing.assert_allclose(scaled.mesh.vertices, inch.mesh.vertices)
    decimetre = load_part(shared_dir / "parts" / "fandisk.obj", units="dm")
    assert 100.0 < decimetre.mesh.extents.max() < 200.0
    with pytest.raises(ValueError, match="unknown unit"):
        load_part(CUBE, units="furlong")


def test_a_part_in_the_wrong_unit_warns(shared_dir, tmp_path):
    with pytest.warns(PartWarning, match="did you mean"):
        small = load_part(shared_dir / "parts" / "featuretype.STL", units="mm")  # 5 mm: really inches
    assert any("inch" in text for text in small.warnings)
    box = trimesh.creation.box(extents=(5.0, 4.0, 3.0))
    box.export(tmp_path / "tiny.stl")
    with pytest.warns(PartWarning, match="implausible"):
        load_part(tmp_path / "tiny.stl")
    with pytest.warns(PartWarning, match="did you mean .*mm"):
        load_part(CUBE, units="m")  # a 100 m cube


def test_busted_mesh_merges_to_watertight(shared_dir):
    path = shared_dir / "parts" / "busted.STL"
    assert not trimesh.load(path, process=False).is_watertight
    with warnings.catch_warnings():
        warnings.simplefilter("error", PartWarning)
        part = load_part(path)
    assert part.mesh.is_watertight and part.mesh.volume > 0
    with pytest.warns(PartWarning, match="disconnected.*merge_vertices"):
        load_part(path, merge_vertices=False)


def test_triangle_soup_warns_but_loads(shared_dir):
    with pytest.warns(PartWarning, match="soup"):
        part = load_part(shared_dir / "parts" / "soup.stl", scale=100.0)
    assert len(part.mesh.faces) == 100
    assert len(part.sample(0.01, seed=0)) > 0


def test_missing_and_unreadable_files_raise_naming_the_file(tmp_path):
    missing = tmp_path / "nothing_here.stl"
    with pytest.raises(PartLoadError, match=r"nothing_here\.stl"):
        load_part(missing)
    garbage = tmp_path / "garbage.stl"
    garbage.write_bytes(np.random.default_rng(0).bytes(500))
    with pytest.raises(PartLoadError, match=r"garbage\.stl"):
        load_part(garbage)
    empty = tmp_path / "empty.stl"
    empty.write_bytes(b"")
    with pytest.raises(PartLoadError, match=r"empty\.stl.*no triangles"):
        load_part(empty)
    ascii_empty = tmp_path / "solid.stl"
    ascii_empty.write_text("solid x\nendsolid x\n")
    with pytest.raises(PartLoadError, match="no triangles"):
        load_part(ascii_empty)
    with pytest.raises(PartLoadError, match="not a file"):
        load_part(tmp_path)
    other = tmp_path / "part.xyz3"
    other.write_text("1 2 3\n")
    with pytest.raises(PartLoadError, match="unsupported"):
        load_part(other)


def test_step_needs_a_converter(shared_dir):
    if importlib.util.find_spec("cascadio") is not None:
        pytest.skip("a STEP reader is installed")
    with pytest.raises(PartLoadError, match="STEP needs a converter") as info:
        load_part(shared_dir / "parts" / "featuretype.STEP", units="inch")
    assert "featuretype.STEP" in str(info.value)


def test_bad_transforms_are_rejected():
    nan = np.eye(4)
    nan[0, 3] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        load_part(CUBE, transform=nan)
    with pytest.raises(ValueError, match="not rigid"):
        load_part(CUBE, transform=np.diag([2.0, 2.0, 2.0, 1.0]))
    with pytest.raises(ValueError, match="not rigid"):
        load_part(CUBE, transform=np.diag([1.0, 1.0, -1.0, 1.0]))  # a mirror
    with pytest.raises(ValueError, match="4x4"):
        load_part(CUBE, transform=np.eye(3))
    shear = np.eye(4)
    shear[3, 0] = 1.0
    with pytest.raises(ValueError, match="last row"):
        validate_rigid_transform(shear)


def test_step_is_read_through_cascadio_in_its_own_unit(shared_dir):
    if importlib.util.find_spec("cascadio") is None:
        pytest.skip("no STEP reader (cascadio) installed")
    step = load_part(shared_dir / "parts" / "featuretype.STEP")
    stl = load_part(shared_dir / "parts" / "featuretype.STL", units="inch")
    # the STEP file declares inches; the part comes out in mm like the STL read with units='inch'
    assert step.mesh.extents == pytest.approx(stl.mesh.extents, abs=0.05)
    assert step.scale_to_mm == 1000.0  # OpenCASCADE -> GLB gives metres
    # a coarser tessellation tolerance gives fewer triangles, the same part
    coarse = load_part(shared_dir / "parts" / "featuretype.STEP", tessellation_tolerance_mm=0.5)
    assert len(coarse.mesh.faces) < len(step.mesh.faces)
    assert coarse.mesh.extents == pytest.approx(step.mesh.extents, abs=0.5)
    with pytest.warns(PartWarning, match="declares its own unit"):
        load_part(shared_dir / "parts" / "featuretype.STEP", units="inch")


def test_unreadable_step_and_iges_get_clear_errors(tmp_path):
    fake = tmp_path / "broken.step"
    fake.write_text("solid nothing\nendsolid\n")
    with (
        pytest.raises(PartLoadError, match="not a STEP file")
        if importlib.util.find_spec("cascadio")
        else (pytest.raises(PartLoadError, match="STEP needs a converter"))
    ):
        load_part(fake)
    iges = tmp_path / "part.igs"
    iges.write_text("S      1\n")
    with pytest.raises(PartLoadError, match="IGES is not read"):
        load_part(iges)


def test_broken_part_files_are_named_with_their_problem(tmp_path):
    rng = np.random.default_rng(1)
    for suffix in ("stl", "obj"):
        path = tmp_path / f"garbage.{suffix}"
        path.write_bytes(rng.integers(0, 256, 4096, dtype=np.uint8).tobytes())
        with pytest.raises(PartLoadError, match=f"not a valid {suffix.upper()} file") as info:
            load_part(path)
        assert str(path) in str(info.value) and "charset" not in str(info.value)
    huge = tmp_path / "huge.obj"
    huge.write_text("v 5e299 0 0\nv 0 5e299 0\nv -5e299 0 1e299\nf 1 2 3\n")
    with pytest.raises(PartLoadError, match="absurd vertex coordinates"):
        load_part(huge)


def test_part_files_over_the_size_limits_are_refused_before_reading(tmp_path, monkeypatch):
    monkeypatch.setattr(
        part_loading, "LIMITS", dataclasses.replace(limits.LIMITS, mesh_file_bytes=100, step_file_bytes=100)
    )
    big = tmp_path / "big.STEP"
    big.write_bytes(b"ISO-10303-21;\n" + b" " * 200)
    with pytest.raises(limits.InputTooLarge, match="STEP file"):
        load_part(big)
    cube = tmp_path / "cube.stl"
    trimesh.creation.box((10, 10, 10)).export(cube)
    with pytest.raises(limits.InputTooLarge, match="mesh file"):
        load_part(cube)


def test_a_part_placed_absurdly_far_away_is_refused():
    transform = np.eye(4)
    transform[0, 3] = 1e300
    with pytest.raises(PartLoadError, match="more than"):
        validate_rigid_transform(transform)


def test_loading_calls_the_checkpoint_between_its_steps():
    calls = []
    load_part(PACKAGE_ROOT / "parts" / "objectA_wuerfel.stl", checkpoint=lambda: calls.append(True))
    assert len(calls) >= 3


def test_a_truncated_step_gives_one_clear_error_and_no_converter_console(shared_dir, tmp_path, capfd):
    if importlib.util.find_spec("cascadio") is None:
        pytest.skip("no STEP reader (cascadio) installed")
    text = (shared_dir / "parts" / "featuretype.STEP").read_text(errors="replace")
    broken = tmp_path / "half.STEP"
    broken.write_text(text[: len(text) // 2])
    capfd.readouterr()
    with pytest.raises(PartLoadError, match="OpenCASCADE could not parse it") as info:
        load_part(broken)
    printed = capfd.readouterr()
    # OpenCASCADE's own (coloured) parse error is quoted in the message, not printed on the console
    assert "ERR" not in printed.out + printed.err and "\x1b[" not in printed.out + printed.err
    assert "it says" in str(info.value) and "\x1b[" not in str(info.value)
