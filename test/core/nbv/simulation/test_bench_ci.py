"""CI-sized 3D NBV benchmark: two objects, ours vs random vs a fixed 12-view hemisphere, 8 views, low
resolution (8 x 8 pixel subsampling), noise on. Asserts that ours is at least as good as random (AUC over the
views, mean over objects and seeds), reaches 90 % of the observable surface, and never collides with the part."""

from __future__ import annotations

import numpy as np
import pytest

from agiprobot_measurement.nbv.simulation.ground_truth import GroundTruth, auc, simulate
from agiprobot_measurement.nbv.simulation.station3d import SimulatedNBVStation
from agiprobot_measurement.nbv.volumetric.request import ReconstructionRequest

MAX_VIEWS = 8
OBJECTS = (("parts/objectA_wuerfel.stl", "mm", None), ("l_bracket", "mm", None))


@pytest.fixture(scope="module")
def results():
    out = {}
    for part, units, extent in OBJECTS:
        station = SimulatedNBVStation(part, units, extent, pixel_step=8)
        truth = GroundTruth(station, spacing_m=0.003, directions=64, standoffs=2, rolls=1)
        runs = {}
        for method, seeds in (("ours", [0]), ("random", [0, 1]), ("hemisphere12", [0])):
            runs[method] = [
                simulate(
                    station,
                    ReconstructionRequest.with_config_defaults(gain=method, max_views=MAX_VIEWS, seed=seed),
                    truth,
                    chamfer=method == "ours",
                )
                for seed in seeds
            ]
        out[part] = runs
    return out


def test_ours_is_at_least_as_good_as_random(results):
    ours = np.mean([auc(r["coverage_curve"], MAX_VIEWS) for runs in results.values() for r in runs["ours"]])
    rand = np.mean([auc(r["coverage_curve"], MAX_VIEWS) for runs in results.values() for r in runs["random"]])
    assert ours >= rand, (ours, rand)


def test_ours_covers_the_observable_surface_safely(results):
    for part, runs in results.items():
        for method, summaries in runs.items():
            for s in summaries:
                assert s["termination_reason"] not in ("error", "nothing_found"), (part, method, s["error"])
                assert s["true_collisions"] == 0, (part, method)
        best = runs["ours"][0]
        assert best["coverage"] >= 0.9, (part, best["coverage_curve"])
        assert best["views"] <= MAX_VIEWS
        assert best["accuracy_mm"] < 1.0, part  # fused points lie on the true surface
