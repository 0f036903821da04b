"""reconstruct.py's parts are read and checked as the planner reads them: STEP in its own unit, non-finite
vertices refused, and parts the station cannot scan (far too large or too small) refused instead of simulated."""

import importlib.util
import struct
import time

import numpy as np
import pytest
import trimesh

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.simulation.station3d import load_part_mesh


def write_stl(path, triangles):
    with path.open("wb") as f:
        f.write(b"\0" * 80 + struct.pack("<I", len(triangles)))
        for tri in triangles:
            f.write(struct.pack("<3f", 0, 0, 0) + b"".join(struct.pack("<3f", *v) for v in tri) + b"\0\0")
    return path


def cube_triangles(side_mm: float) -> list:
    return trimesh.creation.box((side_mm, side_mm, side_mm)).triangles.tolist()


def test_a_nan_vertex_is_refused_not_dropped(tmp_path):
    triangles = [*cube_triangles(100.0), [[float("nan"), 0, 0], [1, 0, 0], [0, 1, 0]]]
    path = write_stl(tmp_path / "nan.stl", triangles)
    t0 = time.perf_counter()
    with pytest.raises(InputError, match="NaN, infinite"):
        load_part_mesh(str(path), "mm")
    assert time.perf_counter() - t0 < 5.0


def test_a_part_of_a_thousand_kilometres_is_refused(tmp_path):
    path = write_stl(tmp_path / "huge.stl", cube_triangles(1e9))
    with pytest.raises(InputError, match="outside what the station scans"):
        load_part_mesh(str(path), "mm")


@pytest.mark.parametrize("extent_m", [1e6, 1e-9])
def test_an_absurd_rescaling_is_refused(extent_m):
    with pytest.raises(InputError, match="outside what the station scans"):
        load_part_mesh("cup", "mm", extent_m)


def test_a_plausible_file_still_loads_in_metres(tmp_path):
    mesh = load_part_mesh(str(write_stl(tmp_path / "cube.stl", cube_triangles(100.0))), "mm")
    assert np.max(mesh.extents) == pytest.approx(0.1)


def test_step_is_read_in_the_unit_it_declares(shared_dir):
    if importlib.util.find_spec("cascadio") is None:
        pytest.skip("no STEP reader (cascadio) installed")
    # featuretype.STEP declares inches: 127 mm across, whatever --units says (its default is mm)
    mesh = load_part_mesh(str(shared_dir / "parts" / "featuretype.STEP"), "mm")
    assert np.max(mesh.extents) == pytest.approx(0.127, abs=0.002)
