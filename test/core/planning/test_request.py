"""PlanRequest: the defaults come from config/trajectory_manager.yaml, validation names the field."""

import dataclasses

import numpy as np
import pytest

from agiprobot_measurement.common.limits import LIMITS, InputTooLarge
from agiprobot_measurement.errors import InputError
from agiprobot_measurement.planning.request import PlanRequest, PlanRequestError, load_planning_defaults
from agiprobot_measurement.station import PACKAGE_ROOT

CUBE = "parts/objectA_wuerfel.stl"


def test_defaults_are_the_configuration_file():
    config = load_planning_defaults()
    request = PlanRequest.from_defaults()
    for name, value in config.items():
        assert getattr(request, name) == value, name
    # the dataclass defaults agree with the file (the API's defaults are the node's and the CLI's)
    bare = PlanRequest()
    for name, value in config.items():
        if name != "part_file":
            assert getattr(bare, name) == value, name


def test_empty_goal_fields_keep_the_defaults():
    request = PlanRequest.from_defaults(
        {"sampling_density": 0.03, "solver_type": "IP_basic"}, sampling_density=0.0, solver_type="", seed=None
    )
    assert request.sampling_density == 0.03 and request.solver_type == "IP_basic" and request.seed == 0
    assert PlanRequest.from_defaults({}, sampling_density=0.5).sampling_density == 0.5
    with pytest.raises(TypeError, match="no field 'density'"):
        PlanRequest.from_defaults({}, density=1.0)


def test_validate_resolves_the_part_and_types_the_fields():
    request = PlanRequest.from_defaults(part_file=CUBE, orientations_around_boresight=6.0).validate(
        base_dir=PACKAGE_ROOT
    )
    assert request.part_file == str(PACKAGE_ROOT / CUBE)
    assert request.orientations_around_boresight == 6 and isinstance(request.orientations_around_boresight, int)
    np.testing.assert_array_equal(request.part_transform_mm, np.eye(4))


@pytest.mark.parametrize(
    ("fields", "field", "text"),
    [
        ({"part_file": "/nonexistent/part.stl"}, "part_file", "part file not found: /nonexistent/part.stl"),
        ({"part_file": ""}, "part_file", "no part_file given"),
        ({"sampling_density": -0.5}, "sampling_density", "sampling_density must be a positive number"),
        ({"uncertainty_threshold_mm": float("nan")}, "uncertainty_threshold_mm", "uncertainty_threshold_mm"),
        ({"solver_type": "IP_uncert"}, "solver_type", "did you mean 'IP_uncertainty'"),
        ({"viewpoint_tilt_mode": "sideways"}, "viewpoint_tilt_mode", "unknown viewpoint_tilt_mode 'sideways'"),
        ({"units": "furlong"}, "units", "unknown units 'furlong'"),
        ({"orientations_around_boresight": 0}, "orientations_around_boresight", "at least 1"),
        ({"part_transform_mm": np.full((4, 4), np.nan)}, "part_transform_mm", "NaN"),
        ({"minimum_required_overmeasure_mm": -1.0}, "minimum_required_overmeasure_mm", ">= 0"),
    ],
)
def test_validation_names_the_field(fields, field, text):
    request = dataclasses.replace(PlanRequest.from_defaults(part_file=CUBE), **fields)
    with pytest.raises(PlanRequestError, match=text.replace("(", r"\(")) as caught:
        request.validate(base_dir=PACKAGE_ROOT)
    assert caught.value.field == field
    assert isinstance(caught.value, InputError) and isinstance(caught.value, ValueError)


def test_labels_name_fields_the_callers_way():
    request = dataclasses.replace(PlanRequest.from_defaults(part_file=CUBE), sampling_density=0.0)
    with pytest.raises(PlanRequestError, match=r"^--density must be a positive number, got 0.0$"):
        request.validate(base_dir=PACKAGE_ROOT, labels={"sampling_density": "--density"})


def test_an_oversized_part_file_is_refused_by_the_request(tmp_path):
    big = tmp_path / "big.STEP"
    with big.open("wb") as handle:
        handle.truncate(LIMITS.step_file_bytes + 1)
    with pytest.raises(InputTooLarge, match="STEP file"):
        PlanRequest(part_file=str(big)).validate()
