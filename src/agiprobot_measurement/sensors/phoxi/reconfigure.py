"""The phoxi_camera node's reconfigurable parameters as a dynamic_reconfigure description, written by hand.

``dynamic_reconfigure.server.Server(phoxi_config, callback)`` takes this module in place of a ``*Config.py``
generated from a ``.cfg`` file (it reads ``config_description``, ``defaults``, ``min``, ``max``), so the package needs
no dynamic_reconfigure code generation in CMake. Names, ranges, defaults and levels follow the real driver's
``phoxi_camera.cfg`` and the reference (``send_depth_map``, ``coordinate_space``); ``organized_cloud`` and
``free_run_rate_hz`` are the simulator's additions. Pure data: importable without ROS.
"""

from __future__ import annotations

__all__ = [
    "PARAMETERS",
    "STATIC_PARAMETERS",
    "all_level",
    "config_description",
    "defaults",
    "level",
    "max",
    "min",
    "type",
]


def _const(name: str, kind: str, value, description: str) -> dict:
    ctype = {"int": "int", "double": "double", "bool": "bool", "str": "std::string"}[kind]
    return {
        "name": name,
        "type": kind,
        "value": value,
        "description": description,
        "srcline": 0,
        "srcfile": "phoxi_config.py",
        "ctype": ctype,
        "cconsttype": f"const {ctype}",
    }


def _enum(description: str, *constants) -> str:
    # rqt_reconfigure evaluates edit_method as a Python literal, as the generator writes it
    return repr({"enum": [_const(*c) for c in constants], "enum_description": description})


_EXPOSURE_ENUM = _enum(
    "Time for projecting one pattern (ms)",
    *[
        (f"Exposure_{str(ms).replace('.', '_')}", "int", i, f"{ms} ms")
        for i, ms in enumerate(
            (10.24, 14.336, 20.48, 24.576, 30.72, 34.816, 40.96, 49.152, 75.776, 79.872, 90.112, 100.352)
        )
    ],
)

#: name, type, level, description, default, min, max, edit_method
PARAMETERS = (
    (
        "resolution",
        "int",
        1 << 1,
        "Resolution: 1 High (2064x1544), 0 Low (1032x772)",
        1,
        0,
        1,
        _enum(
            "Resolution",
            ("Low", "int", 0, "Low resolution (1032x772)"),
            ("High", "int", 1, "High resolution (2064x1544)"),
        ),
    ),
    ("scan_multiplier", "int", 1 << 2, "Scans averaged into one frame", 1, 1, 50, ""),
    ("shutter_multiplier", "int", 1 << 3, "Exposures per pattern", 1, 1, 20, ""),
    (
        "trigger_mode",
        "int",
        1 << 4,
        "Trigger mode: 0 free run (continuous), 1 software trigger",
        1,
        0,
        1,
        _enum("Trigger mode", ("Freerun", "int", 0, "Free run"), ("Software", "int", 1, "Software trigger")),
    ),
    ("timeout", "int", 1 << 5, "Timeout (ms): 0 zero, -1 infinite, -2 last stored, -3 default", -3, -3, 3600000, ""),
    ("confidence", "double", 1 << 6, "Max inaccuracy (mm) of a kept point", 3.0, 0.0, 10.0, ""),
    ("send_point_cloud", "bool", 1 << 7, "Publish the point cloud", True, False, True, ""),
    ("send_normal_map", "bool", 1 << 8, "Publish the normal map", True, False, True, ""),
    ("send_confidence_map", "bool", 1 << 9, "Publish the confidence map", True, False, True, ""),
    ("send_texture", "bool", 1 << 10, "Publish texture and rgb_texture", True, False, True, ""),
    ("send_depth_map", "bool", 1 << 11, "Publish the depth map", True, False, True, ""),
    (
        "coordinate_space",
        "int",
        1 << 12,
        "Coordinate space of the cloud",
        1,
        1,
        5,
        _enum(
            "Coordinate space",
            ("CameraSpace", "int", 1, "Camera space"),
            ("MountingSpace", "int", 2, "Mounting space"),
            ("MarkerSpace", "int", 3, "Marker space"),
            ("RobotSpace", "int", 4, "Robot space"),
            ("CustomSpace", "int", 5, "Custom space"),
        ),
    ),
    (
        "ambient_light_suppression",
        "bool",
        1 << 13,
        "Ambient light suppression (shutter multiplier 2)",
        False,
        False,
        True,
        "",
    ),
    ("single_pattern_exposure", "int", 1 << 14, "Single pattern exposure (index)", 2, 0, 11, _EXPOSURE_ENUM),
    ("camera_only_mode", "bool", 1 << 15, "2D camera only: texture, no 3D points", False, False, True, ""),
    (
        "organized_cloud",
        "bool",
        1 << 16,
        "Organised cloud (H x W, zeros kept) or valid points only",
        True,
        False,
        True,
        "",
    ),
    ("free_run_rate_hz", "double", 1 << 17, "Frame rate in free-run mode (Hz)", 1.0, 0.01, 30.0, ""),
)

config_description = {
    "name": "Default",
    "type": "",
    "state": True,
    "cstate": "true",
    "id": 0,
    "parent": 0,
    "parameters": [
        {
            "name": name,
            "type": kind,
            "level": level,
            "description": description,
            "default": default,
            "min": low,
            "max": high,
            "edit_method": edit_method,
            "srcline": 0,
            "srcfile": "phoxi_config.py",
            "ctype": {"int": "int", "double": "double", "bool": "bool"}[kind],
            "cconsttype": {"int": "const int", "double": "const double", "bool": "const bool"}[kind],
        }
        for name, kind, level, description, default, low, high, edit_method in PARAMETERS
    ],
    "groups": [],
    "srcline": 0,
    "srcfile": "phoxi_config.py",
    "class": "DEFAULT",
    "parentclass": "",
    "parentname": "Default",
    "field": "default",
    "upper": "DEFAULT",
    "lower": "groups",
}

# the attribute names of a generated *Config.py (they shadow builtins here, as they do there)
defaults = {p["name"]: p["default"] for p in config_description["parameters"]}
min = {p["name"]: p["min"] for p in config_description["parameters"]}
max = {p["name"]: p["max"] for p in config_description["parameters"]}
level = {p["name"]: p["level"] for p in config_description["parameters"]}
type = {p["name"]: p["type"] for p in config_description["parameters"]}
all_level = 0
for _level in level.values():
    all_level |= _level

#: parameters of the reference that are not reconfigurable (read once at start-up), with their defaults
STATIC_PARAMETERS = {
    "scanner_id": "",
    "frame_id": "PhoXi3Dscanner_sensor",
    "latch_topics": False,
    "topic_queue_size": 1,
    "init_from_config": False,
}
