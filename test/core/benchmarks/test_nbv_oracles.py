"""The 3D NBV benchmark's oracles: the gain-quality hook scores each gain against the truly best view; the
truth-aware planners take the best pose and trade it for path."""

from __future__ import annotations

import numpy as np
import pytest

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.simulation.ground_truth import GroundTruth, simulate
from agiprobot_measurement.nbv.simulation.station3d import SimulatedNBVStation
from agiprobot_measurement.nbv.volumetric.request import ReconstructionRequest
from benchmarks.nbv_oracles import GainQuality, TruthLoopPolicy, oracle_path_curve


def test_gain_quality_scores_each_gain_against_the_truly_best_view():
    station = SimulatedNBVStation(pixel_step=8)
    truth = GroundTruth(station, spacing_m=0.005, directions=16, standoffs=1, rolls=1)
    mixes = {"prox": {"proximity_count": 1.0}, "report_only": {"report": 2.0, "proximity_count": 0.0}}
    hook = GainQuality(truth, max_decisions=2, mixes=mixes)
    simulate(station, ReconstructionRequest.with_config_defaults(max_views=4), truth, chamfer=False, on_scored=hook)
    assert len(hook.decisions) == 2  # the first two scored pools of three
    for decision in hook.decisions:
        assert {"utility", "expected_surface", "proximity_count", "report", "prox", "report_only"} <= set(decision)
        assert all(0.0 <= v <= 1.0 for v in decision.values())
        # a mix of one term picks what that term picks
        assert decision["prox"] == decision["proximity_count"]
        assert decision["report_only"] == decision["report"]
    summary = hook.summary()
    assert summary["utility"] == pytest.approx(np.mean([d["utility"] for d in hook.decisions]))
    # past the coverage bound nothing is scored
    late = GainQuality(truth, max_coverage=0.0)
    simulate(station, ReconstructionRequest.with_config_defaults(max_views=2), truth, chamfer=False, on_scored=late)
    assert late.decisions == [] and late.summary() == {}


def test_the_truth_aware_planners_take_the_best_pose_and_trade_it_for_path():
    station = SimulatedNBVStation(pixel_step=8)  # the 100 mm cube of config/scene.yaml
    truth = GroundTruth(station, spacing_m=0.005, directions=24, standoffs=1, rolls=1)
    first = oracle_path_curve(truth)
    per_rad = oracle_path_curve(truth, per_rad_offset_rad=0.5)
    observable = truth.visibility.matrix.tocsr()[truth.observable]
    best_single = np.asarray(observable.sum(axis=0)).max() / observable.shape[0]
    assert first[0][0] == pytest.approx(best_single)  # coverage first: the pose seeing most
    for curve in (first, per_rad):
        coverages, paths = np.array(curve).T
        assert np.all(np.diff(coverages) > 0) and np.all(np.diff(paths) >= 0)
        assert coverages[-1] == pytest.approx(1.0)  # on to every observable point
    assert per_rad[0][1] <= first[0][1]  # per rad: a first move no longer than coverage first's


def test_the_oracle_loop_takes_the_pool_view_that_truly_sees_most_new_points():
    station = SimulatedNBVStation(pixel_step=8)
    truth = GroundTruth(station, spacing_m=0.005, directions=16, standoffs=1, rolls=1)
    pools = []

    def factory(context, planning):
        return TruthLoopPolicy(context, planning, truth, "ours")

    def hook(recon, cands, utilities):
        # the utilities handed to the hook are the true new points of the feasible candidates, as counted afresh
        todo = truth.observable & ~truth.covered
        idx = np.nonzero(cands.feasible)[0]
        caster = recon.policy._caster
        fresh = [np.count_nonzero(truth.visible_from(cands.poses[i], caster) & todo) for i in idx]
        assert np.array_equal(utilities, np.asarray(fresh, float))
        pools.append((cands.poses[idx], utilities))

    request = ReconstructionRequest.with_config_defaults(max_views=3)
    summary = simulate(station, request, truth, chamfer=False, on_scored=hook, policy_factory=factory)
    assert summary["termination_reason"] == "max_views" and len(pools) == 2
    for (poses, gains), view in zip(pools, summary["view_log"][1:], strict=True):
        # the view taken is the candidate with the most true new points (its motion did not fail here)
        assert np.allclose(view["camera_pose"], poses[int(np.argmax(gains))], atol=1e-4)
    with pytest.raises(InputError):
        TruthLoopPolicy(None, None, truth, "nowhere")
