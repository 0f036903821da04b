"""The phoxi_camera node's reconfigurable parameters as a dynamic_reconfigure description, written by hand.

``dynamic_reconfigure.server.Server(phoxi_config, callback)`` takes this module in place of a ``*Config.py``
generated from a ``.cfg`` file (it reads ``config_description``, ``defaults``, ``min``, ``max``), so the package needs
no dynamic_reconfigure code generation in CMake. Names, ranges, defaults and levels follow the real driver's
``cfg/phoxi_camera.cfg`` (release 1.8.0) exactly, every parameter and nothing else (the simulator's own settings,
such as ``~free_run_rate_hz``, are private parameters read at start-up). Pure data: importable without ROS.
"""

from __future__ import annotations

__all__ = [
    "LEVEL_COORDINATE_SPACE",
    "LEVEL_RESOLUTION",
    "LEVEL_TRIGGER",
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
    "The time for projection of one pattern",
    *[
        (name, "int", i, name)
        for i, name in enumerate(
            (
                "10_240",
                "14_336",
                "20_480",
                "24_576",
                "30_720",
                "34_816",
                "40_960",
                "49_152",
                "75_776",
                "79_872",
                "90_112",
                "100_352",
            )
        )
    ],
)

#: the bits of ``level`` that name what a reconfiguration changed (the driver applies only those)
LEVEL_RESOLUTION = 1 << 1
LEVEL_TRIGGER = 1 << 4  # trigger_mode and start_acquisition
LEVEL_COORDINATE_SPACE = 1 << 12

#: name, type, level, description, default, min, max, edit_method: the driver's cfg/phoxi_camera.cfg (1.8.0), in its
#: order, with its levels, ranges, defaults and enum names
PARAMETERS = (
    (
        "resolution",
        "int",
        LEVEL_RESOLUTION,
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
    ("scan_multiplier", "int", 1 << 2, "Scan multiplier", 1, 1, 50, ""),
    ("shutter_multiplier", "int", 1 << 3, "Shutter multiplier", 1, 1, 20, ""),
    (
        "trigger_mode",
        "int",
        LEVEL_TRIGGER,
        "Trigger mode: 0 free run, 1 software trigger",
        1,
        0,
        1,
        _enum("Trigger enum", ("Freerun", "int", 0, "Freerun."), ("Software", "int", 1, "Software trigger.")),
    ),
    ("start_acquisition", "bool", LEVEL_TRIGGER, "Start acquisition", True, False, True, ""),
    (
        "timeout",
        "int",
        1 << 5,
        "Timeout (ms): 0 zero, -1 infinite, -2 last stored, -3 default (10 s)",
        -3,
        -3,
        0,
        _enum(
            "Timeout",
            ("ZeroTimeout", "int", 0, "ZeroTimeout"),
            ("Infinity", "int", -1, "Infinity"),
            ("LastStored", "int", -2, "LastStored"),
            ("Default", "int", -3, "Default timeout 10s"),
        ),
    ),
    ("confidence", "double", 1 << 6, "Max inaccuracy (mm) of a kept point", 3.0, 0.0, 10.0, ""),
    ("send_point_cloud", "bool", 1 << 7, "Send point cloud.", True, False, True, ""),
    ("send_normal_map", "bool", 1 << 8, "Send normal map.", True, False, True, ""),
    ("send_confidence_map", "bool", 1 << 9, "Send confidence map", True, False, True, ""),
    ("send_texture", "bool", 1 << 10, "Send texture", True, False, True, ""),
    ("send_depth_map", "bool", 1 << 11, "Send depth map", True, False, True, ""),
    (
        "coordinate_space",
        "int",
        LEVEL_COORDINATE_SPACE,
        "Coordinate space of the cloud",
        1,
        1,
        5,
        _enum(
            "Coordinate space",
            ("CameraSpace", "int", 1, "CameraSpace"),
            ("MountingSpace", "int", 2, "MountingSpace"),
            ("MarkerSpace", "int", 3, "MarkerSpace"),
            ("RobotSpace", "int", 4, "RobotSpace"),
            ("CustomSpace", "int", 5, "CustomSpace"),
        ),
    ),
    ("organized_cloud", "bool", 1 << 13, "Send organized cloud (if true).", True, False, True, ""),
    (
        "ambient_light_suppression",
        "bool",
        1 << 14,
        "Ambient light suppression (shutter multiplier 2)",
        False,
        False,
        True,
        "",
    ),
    ("single_pattern_exposure", "int", 1 << 15, "Single pattern exposure (index)", 2, 0, 11, _EXPOSURE_ENUM),
    ("camera_only_mode", "bool", 1 << 16, "2D camera only: texture, no 3D points", False, False, True, ""),
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
