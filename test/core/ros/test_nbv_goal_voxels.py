"""The NBV node's voxel limit (~max_voxels) holds for every goal, also one that leaves the ROI at its default."""

import pytest

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.msg import ReconstructObjectGoal
from agiprobot_measurement.ros.nbv_messages import request_mapping_from_goal

DEFAULT_ROI_M = (0.28, 0.28, 0.28)


def test_a_fine_grid_over_the_default_roi_is_refused():
    goal = ReconstructObjectGoal(resolution_m=0.0009)  # 311^3 = 30.4 M voxels
    with pytest.raises(InputError, match=r"default ROI.*~max_voxels"):
        request_mapping_from_goal(goal, {"resolution_m": 0.002}, 2e7, DEFAULT_ROI_M)


def test_the_same_grid_spelled_out_is_refused_alike():
    goal = ReconstructObjectGoal(resolution_m=0.0009)
    goal.roi_size.x = goal.roi_size.y = goal.roi_size.z = 0.28
    with pytest.raises(InputError, match=r"roi_size.*~max_voxels"):
        request_mapping_from_goal(goal, {"resolution_m": 0.002}, 2e7, DEFAULT_ROI_M)


def test_the_default_grid_is_accepted():
    values = request_mapping_from_goal(ReconstructObjectGoal(), {"resolution_m": 0.002}, 2e7, DEFAULT_ROI_M)
    assert values["resolution_m"] == 0.002 and "roi_size_m" not in values
