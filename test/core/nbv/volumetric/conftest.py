"""Shared pieces of the volumetric tests."""

from __future__ import annotations

import math

import numpy as np
import pytest

from agiprobot_measurement.nbv.volumetric.gains import ViewModel


@pytest.fixture
def narrow_view():
    """A maker of narrow test cameras: ``fov_deg`` x ``fov_deg``, 8 x 8 rays, the projector at ``offset`` (camera
    frame, m; default its centre), range 0.05-1 m, incidence up to 75 degrees, ``extra`` ViewModel fields."""

    def make(fov_deg=4.0, offset=(0.0, 0.0, 0.0), **extra):
        return ViewModel(
            fov_h_rad=math.radians(fov_deg),
            fov_v_rad=math.radians(fov_deg),
            range_min_m=0.05,
            range_max_m=1.0,
            projector_offset_m=np.array(offset),
            rays_h=8,
            rays_v=8,
            max_incidence_rad=math.radians(75),
            **extra,
        )

    return make
