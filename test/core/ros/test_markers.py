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


def test_every_marker_set_starts_with_the_one_clear_marker():
    from std_msgs.msg import Header
    from visualization_msgs.msg import Marker

    from agiprobot_measurement.ros import markers

    header = Header(frame_id="world")
    sets = [
        markers.voxel_markers(np.zeros((2, 3)), 0.01, header, "occupied_voxels"),
        markers.candidate_markers(np.tile(np.eye(4), (2, 1, 1)), [1.0, 2.0], ["", "unreachable"], header),
        markers.scan_line_markers([(np.zeros(3), np.ones(3))], header),
    ]
    for array in sets:
        assert array.markers[0].action == Marker.DELETEALL and array.markers[0].header.frame_id == "world"
    namespaces = {m.ns for m in sets[1].markers[1:]}
    assert namespaces == {"feasible", "rejected/unreachable"}


def test_both_frustums_are_line_lists_of_twelve_edges():
    from std_msgs.msg import Header
    from visualization_msgs.msg import Marker

    from agiprobot_measurement.ros import markers

    nbv = markers.frustum_marker(np.eye(4), 0.5, 0.4, (0.3, 1.0), Header(frame_id="world"))
    corners = np.array([[x, y, z] for z in (0.3, 1.0) for x, y in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    mild = markers.frustum_marker_array(corners, "map", None).markers[0]
    for marker in (nbv, mild):
        assert marker.type == Marker.LINE_LIST and len(marker.points) == 24
    assert tuple(getattr(mild.color, c) for c in "rgba") == markers.MILD_FRUSTUM_RGBA
