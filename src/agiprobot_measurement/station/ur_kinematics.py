"""A UR arm's kinematics file: ur_calibration's output in ur_description's format, read into joint origins.

The file (``config/ur10e_default_kinematics.yaml`` is ur_description's nominal UR10e; ``ur_calibration`` writes one
per robot from the controller's calibrated DH)::

    kinematics:
      shoulder:  {x: 0, y: 0, z: 0.1807, roll: 0, pitch: 0, yaw: 0}
      upper_arm: {...}  forearm: {...}  wrist_1: {...}  wrist_2: {...}  wrist_3: {...}
      hash: calib_5119701370761913513

Each entry is the ``<origin xyz rpy>`` (metres; URDF roll-pitch-yaw, rad) of one joint in its parent link's frame:
``shoulder`` -> ``shoulder_pan_joint`` (parent ``base_link_inertia``), ``upper_arm`` -> ``shoulder_lift_joint``,
``forearm`` -> ``elbow_joint``, ``wrist_1`` .. ``wrist_3`` -> ``wrist_1_joint`` .. ``wrist_3_joint``. The hash is the
controller's calibration checksum the driver compares at start-up.

Every problem is a :class:`KinematicsFileError` (a ConfigError, i.e. an InputError) naming the file and key: a
missing or unknown link or field, a non-number, NaN/inf, an offset beyond ``MAX_OFFSET_M`` or an angle beyond
``MAX_ANGLE_RAD``, a hash that is not a ``calib_<digits>`` string.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from agiprobot_measurement.common.config import ConfigError, read_yaml
from agiprobot_measurement.common.geometry import pose_matrix

__all__ = [
    "BASE_LINK_TO_BASE",
    "MAX_ANGLE_RAD",
    "MAX_OFFSET_M",
    "UR_BASE_RPY_RAD",
    "UR_FLANGE_RPY_RAD",
    "UR_KINEMATICS_FIELDS",
    "UR_KINEMATICS_JOINTS",
    "UR_KINEMATICS_LINKS",
    "UR_TOOL0_RPY_RAD",
    "KinematicsFileError",
    "UrKinematics",
    "load_ur_kinematics",
    "parse_ur_kinematics",
]

#: ur_description's fixed frames of a UR arm: base_link -> base_link_inertia (the chain's root) and base_link ->
#: base (the DH base, the controller's Base) are both rpy(0, 0, pi); wrist_3_link -> flange -> tool0 (xyz m, rpy rad)
UR_BASE_RPY_RAD = (0.0, 0.0, math.pi)
UR_FLANGE_RPY_RAD = (0.0, -math.pi / 2, -math.pi / 2)
UR_TOOL0_RPY_RAD = (math.pi / 2, 0.0, math.pi / 2)
BASE_LINK_TO_BASE = pose_matrix((0.0, 0.0, 0.0), UR_BASE_RPY_RAD)

#: the file's link keys, in chain order, and the joint each one places
UR_KINEMATICS_LINKS = ("shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "wrist_3")
UR_KINEMATICS_JOINTS = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
UR_KINEMATICS_FIELDS = ("x", "y", "z", "roll", "pitch", "yaw")
#: bounds of a plausible entry: no UR link offset reaches 2 m (the UR10e's longest is 0.61 m); ur_calibration writes
#: Euler angles within [-pi, pi] (a little slack for rounding, and for hand-written files up to one full turn)
MAX_OFFSET_M = 2.0
MAX_ANGLE_RAD = 2.0 * math.pi + 1e-6
_HASH = re.compile(r"calib_-?[0-9]{1,40}")


class KinematicsFileError(ConfigError):
    """A robot kinematics file (ur_calibration / ur_description format) is missing, malformed or implausible."""


@dataclass(frozen=True)
class UrKinematics:
    """Joint origins of a UR arm: per joint of ``UR_KINEMATICS_JOINTS`` the xyz (m) and rpy (rad) in the parent
    link's frame, rows in chain order; ``hash`` the controller's calibration checksum; ``source`` the file."""

    xyz_m: np.ndarray  # (6, 3)
    rpy_rad: np.ndarray  # (6, 3)
    hash: str
    source: str = ""

    @property
    def joint_names(self) -> tuple[str, ...]:
        return UR_KINEMATICS_JOINTS

    def joint_origins(self) -> np.ndarray:
        """(6, 4, 4): parent link -> joint frame of each joint (before its rotation), chain order."""
        return np.stack([pose_matrix(self.xyz_m[i], self.rpy_rad[i]) for i in range(6)])

    def as_yaml_mapping(self) -> dict:
        """The file's content (``{'kinematics': {...}}``), numbers as Python floats."""
        table = {
            link: dict(
                zip(UR_KINEMATICS_FIELDS, [*map(float, self.xyz_m[i]), *map(float, self.rpy_rad[i])], strict=True)
            )
            for i, link in enumerate(UR_KINEMATICS_LINKS)
        }
        table["hash"] = self.hash
        return {"kinematics": table}


def _field(value: object, where: str, bound: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise KinematicsFileError(f"{where}: expected a number, got {type(value).__name__} {str(value)[:40]!r}")
    result = float(value)
    if not math.isfinite(result):
        raise KinematicsFileError(f"{where}: must be a finite number, got {result}")
    if abs(result) > bound:
        raise KinematicsFileError(f"{where}: {result:g} is implausible (|value| must be <= {bound:g})")
    return result


def parse_ur_kinematics(data: object, where: str = "kinematics file") -> UrKinematics:
    """:class:`UrKinematics` from a loaded YAML document (``{'kinematics': {...}}``)."""
    if not isinstance(data, dict) or "kinematics" not in data:
        raise KinematicsFileError(f"{where}: expected a mapping with the key 'kinematics' (ur_calibration's format)")
    table = data["kinematics"]
    if not isinstance(table, dict):
        raise KinematicsFileError(
            f"{where}: 'kinematics' must be a mapping of link -> origin, got {type(table).__name__}"
        )
    unknown = sorted(str(k) for k in table if k not in (*UR_KINEMATICS_LINKS, "hash"))
    if unknown:
        raise KinematicsFileError(
            f"{where}: unknown key(s) {unknown} under 'kinematics'; expected {', '.join(UR_KINEMATICS_LINKS)}, hash"
        )
    missing = [link for link in (*UR_KINEMATICS_LINKS, "hash") if link not in table]
    if missing:
        raise KinematicsFileError(f"{where}: 'kinematics' lacks {missing}")
    xyz, rpy = np.zeros((6, 3)), np.zeros((6, 3))
    for i, link in enumerate(UR_KINEMATICS_LINKS):
        entry, here = table[link], f"{where}: kinematics.{link}"
        if not isinstance(entry, dict):
            raise KinematicsFileError(f"{here}: expected a mapping with {', '.join(UR_KINEMATICS_FIELDS)}")
        extra = sorted(str(k) for k in entry if k not in UR_KINEMATICS_FIELDS)
        absent = [k for k in UR_KINEMATICS_FIELDS if k not in entry]
        if extra or absent:
            raise KinematicsFileError(
                f"{here}: needs exactly {', '.join(UR_KINEMATICS_FIELDS)}"
                + (f"; missing {absent}" if absent else "")
                + (f"; unknown {extra}" if extra else "")
            )
        xyz[i] = [_field(entry[k], f"{here}.{k}", MAX_OFFSET_M) for k in ("x", "y", "z")]
        rpy[i] = [_field(entry[k], f"{here}.{k}", MAX_ANGLE_RAD) for k in ("roll", "pitch", "yaw")]
    checksum = table["hash"]
    if not isinstance(checksum, str) or not _HASH.fullmatch(checksum):
        raise KinematicsFileError(
            f"{where}: kinematics.hash must be a string 'calib_<digits>' (ur_calibration's), got {str(checksum)[:60]!r}"
        )
    return UrKinematics(xyz, rpy, checksum, where)


def load_ur_kinematics(path: str | Path) -> UrKinematics:
    """Read and check a kinematics file (ur_calibration's ``kinematics_config``, ur_description's format)."""
    path = Path(path)
    try:
        data = read_yaml(path)
    except KinematicsFileError:
        raise
    except ConfigError as exc:
        raise KinematicsFileError(str(exc)) from exc
    return parse_ur_kinematics(data, str(path))
