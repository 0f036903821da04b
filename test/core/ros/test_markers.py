"""rviz markers of a station scene: every object, the part, and a chessboard drawn with its dark squares."""

import numpy as np

from agiprobot_measurement.ros.markers import scene_marker_array
from agiprobot_measurement.station import CONFIG_DIR, load_scene


def test_every_object_and_the_part_have_a_marker():
    scene = load_scene(CONFIG_DIR / "scene.yaml")
    markers = scene_marker_array(scene).markers
    assert len(markers) == len(scene.objects) + 1
    assert len({(m.ns, m.id) for m in markers}) == len(markers)  # rviz replaces markers with equal ns and id
    table = next(m for m in markers if m.ns == "scene" and m.id == scene.object_names().index("table"))
    assert (table.scale.x, table.scale.y, table.scale.z) == (1.6, 1.6, 0.9)


def test_chessboard_is_its_board_and_dark_squares():
    from visualization_msgs.msg import Marker

    scene = load_scene(CONFIG_DIR / "calibration_scene.yaml")
    markers = scene_marker_array(scene).markers
    assert len({(m.ns, m.id) for m in markers}) == len(markers)
    (squares,) = [m for m in markers if m.type == Marker.CUBE_LIST]
    board = next(o for o in scene.objects if o.type == "chessboard")
    rows, cols = board.inner_corners
    assert len(squares.points) == ((rows + 1) * (cols + 1) + 1) // 2  # every other square of a 9 x 12 grid
    xs = np.array([p.x for p in squares.points])
    ys = np.array([p.y for p in squares.points])
    # square centres lie half a square beyond the outermost inner corners
    assert np.isclose(xs.max() - xs.min(), cols * board.square_m)
    assert np.isclose(ys.max() - ys.min(), rows * board.square_m)
    index = scene.object_names().index("calibration_chessboard")
    backing = next(m for m in markers if m.ns == "scene" and m.id == index)
    assert backing.type == Marker.CUBE
    assert np.isclose(backing.pose.position.z, board.pose[2, 3] - board.thickness_m / 2.0)
