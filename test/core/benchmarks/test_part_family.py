"""The generated part family: 30 closed parts of ten kinds at three sizes, reproducible from the seed, split into
halves that both hold every kind and size; a CI-sized subset (the small parts of three kinds) plans completely."""

import numpy as np
import pytest

from agiprobot_measurement.planning.trajectory_manager import TrajectoryManager
from benchmarks.planning.part_family import HALVES, KINDS, SIZES_MM, family, write_parts


def test_the_family_has_every_kind_at_every_size_in_both_halves():
    parts = family()
    assert len(parts) >= 30 and len({p.name for p in parts}) == len(parts)
    for half in HALVES:
        chosen = [p for p in parts if p.half == half]
        assert {p.kind for p in chosen} == set(KINDS) and {p.size_mm for p in chosen} == set(SIZES_MM)


@pytest.mark.parametrize("name", ["tray_80", "housing_80", "freeform_80", "cylinder_holes_80"])
def test_parts_are_closed_reproducible_and_sized(name):
    part = next(p for p in family() if p.name == name)
    mesh = part.mesh()
    assert mesh.is_watertight and mesh.volume > 0
    assert mesh.bounds[0, 2] == pytest.approx(0.0) and 0.4 * part.size_mm <= mesh.extents.max() <= part.size_mm + 1e-6
    again = part.mesh()
    np.testing.assert_array_equal(mesh.vertices, again.vertices)
    # another seed, other dimensions
    assert not np.allclose(part.mesh(seed=1).extents, mesh.extents)


@pytest.mark.parametrize("name", ["tray_80", "bracket_80", "stepped_block_80"])
def test_small_family_parts_plan_completely(tmp_path, name):
    part = next(p for p in family() if p.name == name)
    path = write_parts(tmp_path, [part])[name]
    manager = TrajectoryManager(seed=0)
    manager.load_target_mesh(str(path), units="mm", placement="fixture")
    ordered = manager.plan(0.01, 0.1, 6, "none", "IP_basic", time_limit_s=120.0)
    report = manager.coverage_report()
    assert ordered and not report.time_limit_hit and not report.dropped_views
    assert report.verified_share == 1.0
    assert report.coverage_of_coverable >= 0.98
    assert report.views_lower_bound is not None and report.n_views >= np.ceil(report.views_lower_bound - 1e-6)
