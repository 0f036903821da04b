"""config/nbv.yaml read once into typed settings (unknown keys and bad values named); the policies chosen by name."""

from __future__ import annotations

import math

import pytest

from agiprobot_measurement.errors import InputError
from agiprobot_measurement.nbv.volumetric.policies.registry import POLICIES, make_policy
from agiprobot_measurement.nbv.volumetric.request import METHODS
from agiprobot_measurement.nbv.volumetric.settings import MotionSettings, NBVSettings, PlanningSettings
from agiprobot_measurement.nbv.volumetric.station3d import load_nbv_config


def test_the_configuration_reads_into_typed_settings():
    settings = NBVSettings.from_config(load_nbv_config())
    assert settings.motion.ompl_best_of == 4 and settings.motion.opening_elevation_deg == 55.0
    assert settings.planning.surprise_angle_rad == pytest.approx(math.radians(25.0))
    assert settings.candidates.cone_angles_rad == pytest.approx((0.0, math.radians(20.0), math.radians(40.0)))
    assert settings.request["gain"] == "ours"
    assert settings.planning.tour.max_plan_views == 8 and settings.planning.coverage_fallback_reach_vox == 3


def test_missing_entries_take_the_loops_defaults():
    settings = NBVSettings.from_config({})
    assert settings.motion == MotionSettings() and settings.planning == PlanningSettings()
    assert settings.motion.opening_elevation_deg == 90.0 and settings.planning.cost_schedule == "constant"
    assert settings.candidates.given() == {}


@pytest.mark.parametrize(
    ("config", "named"),
    [
        ({"motion": {"via_pose": 8}}, r"motion\.via_pose: unknown key"),
        ({"planning": {"surprise_angle": 25}}, r"planning\.surprise_angle: unknown key"),
        ({"candidates": {"joint_seed_rad": [0] * 6}}, r"candidates\.joint_seed_rad: unknown key"),
        ({"simulations": {}}, r"nbv\.simulations: unknown key"),
        ({"motion": {"velocity_scaling": "fast"}}, r"motion\.velocity_scaling"),
        ({"planning": {"gain_rays": [32]}}, r"planning\.gain_rays"),
        ({"roi": {"max_object_size_m": [0.2, 0.2]}}, r"roi\.max_object_size_m"),
        ({"motion": []}, r"motion: expected a mapping"),
        ({"planning": {"tour": {"max_plan_view": 8}}}, r"planning\.tour\.max_plan_view: unknown key"),
        ({"planning": {"tour": {"keep_share": 1.5}}}, r"planning\.tour\.keep_share"),
        ({"planning": {"open_border_weight": -1.0}}, r"planning\.open_border_weight"),
        ({"planning": {"coverage_radius_m": 0.0}}, r"planning\.coverage_radius_m"),
        ({"planning": {"sample_neighbours": 40}}, r"planning\.sample_neighbours"),
        ({"planning": {"undersampled_fade_power": "strong"}}, r"planning\.undersampled_fade_power"),
        ({"planning": {"near_best_share": 1.5}}, r"planning\.near_best_share"),
        ({"planning": {"tour": {"undersampled_min_share": -0.1}}}, r"planning\.tour\.undersampled_min_share"),
    ],
)
def test_unknown_keys_and_bad_values_are_named(config, named):
    with pytest.raises(InputError, match=named):
        NBVSettings.from_config(config)


def test_every_method_has_a_policy_and_an_unknown_one_lists_the_known():
    assert set(POLICIES) == set(METHODS)
    with pytest.raises(InputError, match=r"unknown method 'magic'; known: ours, .*report3d"):
        make_policy("magic", None, PlanningSettings())
