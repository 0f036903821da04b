"""Reading and checking configuration: YAML files and the validators every loader uses.

Every error is a :class:`ConfigError` whose message names the file (or request) and the bad key.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from agiprobot_measurement.errors import InputError

__all__ = ["ConfigError", "positive", "read_yaml", "require", "vector"]


class ConfigError(InputError):
    """A configuration file is missing, malformed, or has a bad or missing key."""


def read_yaml(path: str | Path) -> object:
    """Read a YAML file with ``safe_load``; errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{path}: file not found")
    try:
        with path.open() as stream:
            return yaml.safe_load(stream)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: malformed YAML: {exc}") from exc


def require(mapping: object, key: str, where: str) -> object:
    if not isinstance(mapping, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(mapping).__name__}")
    if key not in mapping:
        raise ConfigError(f"{where}: missing key '{key}'")
    return mapping[key]


def vector(value: object, length: int, where: str) -> np.ndarray:
    try:
        vec = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: expected {length} numbers, got {value!r}") from exc
    if vec.shape != (length,):
        raise ConfigError(f"{where}: expected {length} numbers, got {value!r}")
    if not np.all(np.isfinite(vec)):
        raise ConfigError(f"{where}: values must be finite, got {value!r}")
    return vec


def positive(value: object, where: str) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: expected a number, got {value!r}") from exc
    if not math.isfinite(number) or number <= 0.0:
        raise ConfigError(f"{where}: must be a positive number, got {value!r}")
    return number
