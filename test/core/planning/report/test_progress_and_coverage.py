"""Overall planning progress, sample colours (read back by the bag tool) and measured coverage."""

import numpy as np
import pytest

from agiprobot_measurement.planning.report.coverage import (
    NOT_PLANNED_RGB,
    UNCOVERABLE_RGB,
    is_uncoverable_color,
    measured_colors,
    measured_coverage,
    uncertainty_colors,
)
from agiprobot_measurement.planning.report.progress import STAGE_WEIGHTS, STAGES, overall_progress


def test_overall_progress_runs_from_0_to_1_through_the_stages():
    assert tuple(STAGE_WEIGHTS) == STAGES and sum(STAGE_WEIGHTS.values()) == pytest.approx(1.0)
    assert overall_progress("sampling", 0.0) == 0.0
    assert overall_progress("metrology", 0.0) == pytest.approx(STAGE_WEIGHTS["sampling"])
    assert overall_progress("connection", 1.0) == pytest.approx(1.0)
    assert overall_progress("unknown stage", 0.7) == 0.0
    values = [overall_progress(stage, f) for stage in STAGES for f in (0.0, 0.5, 1.0)]
    assert values == sorted(values)


def test_uncertainty_colours_and_their_reading_back():
    u = np.array([0.01, 0.1, np.inf, np.inf])
    coverable = np.array([True, True, False, True])
    colors = uncertainty_colors(u, 0.01, 0.1, coverable)
    np.testing.assert_allclose(colors[0], (0.0, 0.85, 0.2))
    np.testing.assert_allclose(colors[1], (0.0, 0.0, 1.0))
    np.testing.assert_allclose(colors[2], UNCOVERABLE_RGB)
    np.testing.assert_allclose(colors[3], NOT_PLANNED_RGB)
    as_bytes = np.clip(np.round(colors * 255), 0, 255).astype(np.uint8)
    np.testing.assert_array_equal(is_uncoverable_color(as_bytes), [False, False, True, False])


def test_measured_coverage_counts_coverable_samples_only():
    samples = np.array([[0.0, 0, 0], [10, 0, 0], [20, 0, 0], [30, 0, 0]])
    measured_points = np.array([[0.2, 0, 0], [30.5, 0, 0]])
    coverable = np.array([True, True, True, False])
    predicted = np.array([True, True, False, False])
    result = measured_coverage(samples, measured_points, 1.0, coverable, predicted)
    np.testing.assert_array_equal(result.measured, [True, False, False, True])
    assert result.predicted_coverage == pytest.approx(2 / 3)
    assert result.measured_coverage == pytest.approx(1 / 3)
    none = measured_coverage(samples, measured_points, 1.0, np.zeros(4, bool), predicted)
    assert none.predicted_coverage == none.measured_coverage == 0.0
    assert measured_colors(result.measured).shape == (4, 3)
