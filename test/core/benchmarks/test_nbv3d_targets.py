"""The 3D NBV benchmark's bookkeeping: a budget run noting where the stopping rule fired is, up to there, the run
that stops (so one run gives both figures); the self-terminated prefix's metrics; the joint path at equal
coverage; the targets' "best volumetric metric" picked once over the objects, not per object."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agiprobot_measurement.nbv.simulation.ground_truth import GroundTruth, auc, simulate
from agiprobot_measurement.nbv.volumetric.request import ReconstructionRequest
from benchmarks.nbv3d import loop as bench


def view(path_rad, coverage, motion_s=1.0):
    return {"joint_path_rad": path_rad, "coverage": coverage, "motion_s": motion_s}


def budget_summary(stop_view=3):
    curve = [0.5, 0.7, 0.8, 0.85, 0.9]
    return {
        "termination_reason": "max_views",
        "views": 5,
        "view_log": [view(0.0, 0.5), view(1.0, 0.7), view(2.0, 0.8), view(0.5, 0.85), view(0.5, 0.9)],
        "coverage_curve": curve,
        "planning_s_per_view": [1.0, 2.0, 3.0, 4.0],
        "coverage": 0.9,
        "chamfer_mm": 0.4,
        "stop": {"view": stop_view, "reason": "gain_below_threshold", "coverage": 0.8, "chamfer_mm": 0.3},
    }


def test_the_self_terminated_run_is_the_budget_runs_prefix():
    run = bench.self_terminated(budget_summary())
    assert run["views"] == 3 and run["termination_reason"] == "gain_below_threshold"
    assert run["coverage_curve"] == [0.5, 0.7, 0.8] and run["coverage"] == 0.8
    assert run["joint_path_rad"] == 3.0 and run["motion_time_s"] == 3.0
    assert run["planning_s_per_view"] == [1.0, 2.0]  # the first view is not planned
    assert run["auc10"] == pytest.approx(auc([0.5, 0.7, 0.8], 10)) and run["n90"] is None
    assert run["chamfer_mm"] == 0.3  # the map at the stop, not at the budget
    assert run["budget_final_coverage"] == 0.9 and "stop" not in run
    # a run whose rule never fired is its own self-terminated run
    never = {**budget_summary(), "stop": {}}
    assert bench.self_terminated(never) is never


def test_the_joint_path_is_taken_up_to_the_coverage_level():
    run = budget_summary()
    assert bench.path_to(run, 0.8) == (3.0, True)
    assert bench.path_to(run, 0.5) == (0.0, True)
    assert bench.path_to(run, 0.95) == (4.0, False)


def method(c4, auc10, path_rad=1.0, final=0.9, runs=None):
    summary = {
        "c4": c4,
        "auc10": auc10,
        "joint_path_rad": path_rad,
        "final_coverage": final,
        "n95": 6,
        "planning_median_s": 1.0,
        "self_terminated": 1.0,
        "views": 6.0,
        "chamfer_mm": 0.3,
        "accuracy_mm": 0.2,
    }
    return {"summary": summary, "runs": runs or [{"view_log": [view(path_rad, final)], "coverage": final}]}


def test_the_best_volumetric_metric_is_one_metric_over_the_objects():
    a, b = bench.VOLUMETRIC[:2]
    ours_run = {"view_log": [view(1.0, 0.8), view(1.0, 0.95)], "coverage": 0.95, "views": 2,
                "termination_reason": "gain_below_threshold", "budget_final_coverage": 0.96}  # fmt: skip
    objects = {
        # metric a wins on x and y, b only on z: a has the better median, although b is z's best afterwards
        "x": {a: method(0.80, 0.78), b: method(0.60, 0.58)},
        "y": {a: method(0.70, 0.68), b: method(0.65, 0.63)},
        "z": {a: method(0.50, 0.48), b: method(0.90, 0.88)},
    }
    for methods in objects.values():
        methods["ours"] = method(0.85, 0.80, runs=[ours_run])
        methods["ours@budget"] = method(0.85, 0.80, final=0.96)
        methods["random"] = method(0.60, 0.55)
        methods[a]["runs"] = [{"view_log": [view(3.0, 0.9), view(3.0, 0.95)], "coverage": 0.95}]
    results = {"max_views": 20, "objects": {k: {"methods": v} for k, v in objects.items()}}
    out = bench.targets(results)
    assert out["best_volumetric_c4_metric"] == a and out["best_volumetric_auc10_metric"] == a
    assert out["volumetric_medians"][a]["c4"] == pytest.approx(0.70)
    assert out["volumetric_medians"][b]["c4"] == pytest.approx(0.65)
    z = out["per_object"]["z"]
    assert z["best_volumetric_c4"] == 0.50  # the chosen metric's figure on z ...
    assert z["best_volumetric_c4_per_object_max"] == 0.90 and z["best_volumetric_c4_per_object"] == b  # ... not b's
    # equal coverage 0.95: ours needed 2 rad, metric a 6 rad
    assert z["path_ratio_at_equal_coverage"] == pytest.approx(2.0 / 6.0)
    assert z["ours_stop_loss_max"] == pytest.approx(0.01)
    assert z["ours_stopped_before_budget"] == 1.0
    median = out["median"]
    assert median["ours_c4"] == 0.85 and median["random_c4"] == 0.60
    assert median["best_volumetric_c4"] == pytest.approx(0.70)
    assert median["ours_runs_stopped_before_budget"] == 1.0


def test_a_run_whose_rule_never_fired_loses_nothing_against_its_budget():
    a = bench.VOLUMETRIC[0]
    budget_only = {"view_log": [view(1.0, 0.9)], "coverage": 0.9, "views": 20, "termination_reason": "max_views"}
    methods = {a: method(0.7, 0.7), "ours": method(0.8, 0.8, runs=[budget_only]), "ours@budget": method(0.8, 0.8)}
    row = bench.targets({"max_views": 20, "objects": {"x": {"methods": methods}}})["per_object"]["x"]
    assert row["ours_stop_loss_max"] == 0.0  # not 0 - 0.9
    assert row["ours_stopped_before_budget"] == 0.0


def test_the_share_of_runs_stopping_within_one_point_of_their_budget_run():
    stop = {"view": 4, "reason": "gain_below_threshold", "coverage": 0.85}
    close = bench.self_terminated({**budget_summary(), "coverage": 0.855, "stop": stop})  # loses 0.005
    far = bench.self_terminated(budget_summary(stop_view=3))  # stops at 0.8, the budget run reaches 0.9
    never = {**budget_summary(), "stop": {}}  # the rule never fired: not stopped by itself
    row = {"summary": {"c4": 0.8, "auc10": 0.7, "final_coverage": 0.9, "n95": None}, "runs": [close, far, never]}
    assert bench.method_medians([row])["stopped_within_1pt"] == pytest.approx(1 / 3)
    # a method that stopped for real (no budget run) has no loss to measure
    real = {k: v for k, v in bench.self_terminated(budget_summary()).items() if k != "budget_final_coverage"}
    assert bench.method_medians([{**row, "runs": [real]}])["stopped_within_1pt"] is None


def test_a_budget_run_is_the_stopping_run_up_to_where_the_rule_fired():
    from agiprobot_measurement.nbv.simulation.station3d import SimulatedNBVStation

    station = SimulatedNBVStation(pixel_step=8)  # the 100 mm cube of config/scene.yaml
    truth = GroundTruth(station, spacing_m=0.005, directions=16, standoffs=1, rolls=1)
    fields = {"max_views": 4, "min_gain_area_mm2": 1e9}  # the rule fires at the second view
    stopping = simulate(station, ReconstructionRequest.with_config_defaults(**fields), truth, chamfer=False)
    budget = simulate(
        station, ReconstructionRequest.with_config_defaults(**fields), truth, chamfer=False, budget_run=True
    )
    assert stopping["termination_reason"] == "gain_below_threshold" and stopping["views"] == 2
    assert budget["termination_reason"] == "max_views" and budget["views"] == 4
    assert budget["stop"]["view"] == 2 and budget["stop"]["reason"] == "gain_below_threshold"
    assert budget["stop"]["coverage"] == pytest.approx(stopping["coverage"])
    prefix = bench.self_terminated(budget)
    assert prefix["views"] == 2 and prefix["coverage_curve"] == pytest.approx(stopping["coverage_curve"])
    # the same views, measured alike (the motions between them may differ: OMPL's random planner is seeded once
    # per process, so the second run's paths come from a later stream)
    for a, b in zip(prefix["view_log"], stopping["view_log"], strict=True):
        np.testing.assert_allclose(a["camera_pose"], b["camera_pose"], atol=1e-6)
        assert a["points"] == b["points"]
    assert budget["coverage"] >= stopping["coverage"]


def test_views_to_95_not_reached_on_an_object_count_as_never_in_the_median():
    a = bench.VOLUMETRIC[0]
    objects = {}
    for name, ours_n95, random_n95 in (("x", 3, 10), ("y", 4, None), ("z", None, None)):
        run = {"view_log": [view(1.0, 0.9)], "coverage": 0.9, "views": 5, "termination_reason": "max_views"}
        ours = method(0.85, 0.80, runs=[run])
        ours["summary"]["n95"] = ours_n95
        rnd = method(0.6, 0.5)
        rnd["summary"]["n95"] = random_n95
        objects[name] = {"methods": {a: method(0.7, 0.7), "ours": ours, "random": rnd}}
    median = bench.targets({"max_views": 20, "objects": objects})["median"]
    assert median["ours_n95"] == 4.0  # 3, 4, never; not the mean of 3 and 4
    assert median["random_n95"] == math.inf  # reached on one object of three


def test_straight_paths_and_the_truth_aware_planners_are_compared_at_equal_coverage():
    a = bench.VOLUMETRIC[0]
    home = [0.0] * 6

    def run(joints, coverages):
        log = [{"joints_rad": q, "coverage": c, "joint_path_rad": 9.0} for q, c in zip(joints, coverages, strict=True)]
        return {"view_log": log, "coverage": coverages[-1]}

    ours_run = run([[1, 0, 0, 0, 0, 0], [1, 1, 0, 0, 0, 0]], [0.5, 0.9])  # straight: 1 + 1 rad to 0.9
    metric_run = run([[0, 0, 2, 0, 0, 0], [0, 0, 2, 2, 0, 0]], [0.6, 0.9])  # 2 + 2 rad
    assert bench.straight_path_to(metric_run, 0.9, home) == 4.0
    assert bench.straight_path_to(metric_run, 0.95, home) == math.inf
    methods = {
        "ours": method(0.8, 0.8, runs=[{**ours_run, "views": 2, "termination_reason": "gain_below_threshold"}]),
        a: method(0.7, 0.7, runs=[metric_run]),
        "oracle": {
            "home_rad": home,
            "path_curves": {"coverage_first": [(0.7, 1.0), (0.95, 3.0)], "per_rad": [(0.8, 0.5)]},
        },
    }
    row = bench.targets({"max_views": 20, "objects": {"x": {"methods": methods}}})["per_object"]["x"]
    assert row["path_ratio_at_equal_coverage"] == pytest.approx(1.0)  # executed: 18 rad each
    assert row["ours_straight_path_ratio"] == pytest.approx(0.5)
    assert row["oracle_coverage_first_straight_path_ratio"] == pytest.approx(3.0 / 4.0)
    assert row["oracle_per_rad_straight_path_ratio"] == math.inf  # it never reached 0.9
