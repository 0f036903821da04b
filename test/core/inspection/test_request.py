"""One inspection request from points or files to its report (the path the CLI and the ROS action share)."""

import numpy as np
import pytest

from agiprobot_measurement.inspection.cases import build_case, spec_path
from agiprobot_measurement.inspection.errors import InspectionInputError
from agiprobot_measurement.inspection.request import InspectionRequest, placement_from_values, run_inspection


def test_placement_from_values_takes_nothing_a_translation_or_a_matrix():
    np.testing.assert_array_equal(placement_from_values([]), np.eye(4))
    np.testing.assert_array_equal(placement_from_values([1, 2, 3])[:3, 3], [1, 2, 3])
    matrix = np.eye(4)
    matrix[:3, 3] = (4, 5, 6)
    np.testing.assert_array_equal(placement_from_values(matrix.reshape(-1)), matrix)
    for bad in ([1.0, 2.0], [np.nan, 0.0, 0.0], [0.0] * 16):
        with pytest.raises(InspectionInputError, match="placement"):
            placement_from_values(bad)


def test_points_in_metres_give_the_report_of_the_same_points_in_mm(tmp_path):
    case = build_case("dent", 1.0, 3, "phoxi_low")
    nominal = tmp_path / "cube.stl"
    case.nominal.export(nominal)
    stages = []
    points, sigma = case.points_mm[::3], case.sigma_mm[::3]  # a third of the points: the same verdicts, less work
    request = InspectionRequest(nominal, spec_path("cube_100"), tmp_path / "report", points=points / 1000.0,
                                sigma=sigma / 1000.0, placement=case.part.nominal_placement, cloud_units="m")  # fmt: skip
    result, folder = run_inspection(request, lambda stage, fraction: stages.append(stage))
    assert result.verdict == "not conform" and result.flags >= 1
    assert stages[-1] == "report" and "register" in stages
    assert (folder / "report.json").is_file()
    # the same request again refuses the existing report before any work, and leaves it as it was
    before = (folder / "report.json").read_bytes()
    with pytest.raises(InspectionInputError, match="not empty"):
        run_inspection(request)
    assert (folder / "report.json").read_bytes() == before
    with pytest.raises(InspectionInputError, match="cloud units"):
        run_inspection(InspectionRequest(nominal, spec_path("cube_100"), tmp_path / "other", points=case.points_mm,
                                         cloud_units="furlong"))  # fmt: skip
    assert not (tmp_path / "other").exists()
