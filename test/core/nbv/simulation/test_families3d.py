"""The generated 3D parts: fixed seeds, a tuning and a held-out half covering every family, closed meshes of 80-250
mm that the simulated station loads by name."""

from __future__ import annotations

import numpy as np
import pytest

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.simulation.families3d import FAMILIES, family_parts, is_family_part, make_family_part
from agiprobot_measurement.nbv.simulation.station3d import load_part_mesh


def test_halves_are_disjoint_and_cover_every_family():
    tuning, evaluation = family_parts("tuning"), family_parts("evaluation")
    assert len(tuning) + len(evaluation) >= 40
    assert not set(tuning) & set(evaluation)
    for half in (tuning, evaluation):
        assert {name.rsplit("_", 1)[0] for name in half} == set(FAMILIES)
    assert all(is_family_part(n) for n in family_parts("all"))
    assert not is_family_part("cup") and not is_family_part("plate_99") and not is_family_part(3)
    with pytest.raises(InputError):
        family_parts("validation")
    with pytest.raises(InputError):
        make_family_part("plate_99")


@pytest.mark.parametrize("name", [f"{family}_1" for family in FAMILIES])
def test_parts_are_closed_sized_and_reproducible(name):
    mesh = make_family_part(name)
    assert mesh.is_watertight and mesh.volume > 0
    assert 80.0 - 1.0 <= mesh.extents.max() <= 250.0 + 1.0, mesh.extents
    assert mesh.bounds[0][2] == pytest.approx(0.0, abs=1e-6)
    again = make_family_part(name)
    assert np.allclose(mesh.vertices, again.vertices)
    if name.startswith("plate"):
        assert mesh.extents[2] <= 6.5  # thin: the thickness is not scaled


def test_the_station_loads_a_generated_part_by_name():
    mesh = load_part_mesh("mech_1")
    assert 0.079 <= mesh.extents.max() <= 0.251
