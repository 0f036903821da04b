"""What the NBV node and the bag script share: the configuration, the station the loop knows and (in simulation)
the ground truth of the scene's part, built the same way for a live run and for its bag."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from agiprobot_measurement.common.config import ConfigError
from agiprobot_measurement.nbv.simulation.ground_truth import GroundTruth
from agiprobot_measurement.nbv.simulation.station3d import SimulatedNBVStation
from agiprobot_measurement.nbv.volumetric.station3d import NBVStation, load_nbv_config

__all__ = ["nbv_station"]

#: largest distance (m) between the ground truth's part and the scene file's (what the simulated PhoXi renders)
PART_TOLERANCE_M = 1e-3


def nbv_station(config_path: str | Path | None = None, scene_path: str | Path | None = None, model: str = "",
                ground_truth: bool = False):  # fmt: skip
    """(config, station, truth): config/nbv.yaml (or ``config_path``), the :class:`~.station3d.NBVStation` of
    ``scene_path`` (what the loop may know: no part) and, when ``ground_truth`` and the scene file has a part, that
    part's observable surface (:class:`~.ground_truth.GroundTruth`, for the coverage in simulation; else None)."""
    config = load_nbv_config(config_path)
    station = NBVStation(model=model or None, scene_path=scene_path, config=config)
    truth = None
    # a scene without a part (a real station) has no truth to compare with: no coverage then
    if ground_truth and station.station.scene.part is not None:
        simulated = SimulatedNBVStation(model=model or None, scene_path=scene_path, config=config)
        _check_part_placement(simulated)
        truth = GroundTruth(simulated)
    return config, station, truth


def _check_part_placement(simulated) -> None:
    """The ground truth places the scene's part on the fixture; the simulated PhoXi renders it at the scene file's
    pose. Both must agree, else the coverage would be of another part."""
    import trimesh

    part = simulated.station.scene.part
    mesh = trimesh.load(str(part.mesh), force="mesh")
    mesh.apply_scale(part.scale_to_m)
    mesh.apply_transform(part.pose)
    offset = float(np.abs(np.asarray(mesh.bounds) - np.asarray(simulated.part_mesh.bounds)).max())
    if offset > PART_TOLERANCE_M:
        raise ConfigError(
            f"the scene file's part is {offset * 1000:.1f} mm away from its place on the fixture, where the ground "
            "truth puts it: give the part its fixture pose in the scene file, or run without ~ground_truth"
        )
