"""The outputs of a reconstruction are written as one set: a failure part-way (a full disk) leaves the previous set
untouched, with no new file beside old ones, and the result says the outputs failed."""

import errno
from types import SimpleNamespace

import pytest

from agiprobot_measurement.nbv.volumetric.outputs import attach_outputs, save_outputs
from agiprobot_measurement.nbv.volumetric.results import ReconstructionResult


class FakeMap:
    def __init__(self, fail_at: str = ""):
        self.fail_at = fail_at

    def _write(self, path, kind):
        if kind == self.fail_at:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        path.write_text(f"NEW {kind}")
        return path

    def export_cloud_ply(self, path):
        self._write(path, "cloud")
        return 10

    def save_npz(self, path):
        return self._write(path, "map")

    def save_bt(self, path):
        return False


def request():
    return SimpleNamespace(method="ours", output_dir="x")


def write(out, voxel_map):
    return save_outputs(out, voxel_map, None, request(), [0, 0, 0], [1, 1, 1], [], "max_views")


@pytest.fixture
def old_set(tmp_path):
    for name in ("cloud.ply", "map.npz", "mesh.ply", "views.yaml"):
        (tmp_path / name).write_text("OLD")
    return tmp_path


def test_a_write_failure_leaves_the_previous_set_untouched(old_set):
    result = ReconstructionResult("max_views")
    attach_outputs(result, lambda: write(old_set, FakeMap(fail_at="map")))
    assert result.outputs_error and "No space left" in result.error
    assert result.cloud_file == result.map_file == result.log_file == ""
    assert sorted(p.name for p in old_set.iterdir()) == ["cloud.ply", "map.npz", "mesh.ply", "views.yaml"]
    assert {p.read_text() for p in old_set.iterdir()} == {"OLD"}
    assert result.summary()["outputs_error"]


def test_a_complete_set_replaces_the_previous_one_whole(old_set):
    result = ReconstructionResult("max_views")
    attach_outputs(result, lambda: write(old_set, FakeMap()))
    assert not result.outputs_error
    assert (old_set / "cloud.ply").read_text() == "NEW cloud" and (old_set / "map.npz").read_text() == "NEW map"
    assert "OLD" not in (old_set / "views.yaml").read_text()
    assert not (old_set / "mesh.ply").exists()  # the old mesh does not stay beside the new map
    assert sorted(p.name for p in old_set.iterdir()) == ["cloud.ply", "map.npz", "views.yaml"]
