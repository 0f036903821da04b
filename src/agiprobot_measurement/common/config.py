"""Reading and checking configuration: YAML files and the validators every loader uses.

Every error is a :class:`ConfigError` whose message names the file (or request) and the bad key.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from agiprobot_measurement.errors import InputError

__all__ = [
    "YAML_MAX_BYTES",
    "YAML_MAX_DEPTH",
    "YAML_MAX_EXPANDED_NODES",
    "ConfigError",
    "load_yaml_text",
    "non_negative",
    "number",
    "number_list",
    "positive",
    "read_yaml",
    "require",
    "vector",
    "whole",
]


class ConfigError(InputError):
    """A configuration file is missing, malformed, or has a bad or missing key."""


#: YAML read from outside (files, requests) is refused beyond these: a file of this many bytes, nesting this deep,
#: or this many nodes once every alias is expanded (an alias bomb is a few KB that expand to billions of nodes).
YAML_MAX_BYTES = 64 * 1024 * 1024
YAML_MAX_DEPTH = 64
YAML_MAX_EXPANDED_NODES = 20_000_000


def _expanded_node_count(root: yaml.Node, limit: int, where: str) -> int:
    """Nodes of ``root`` counted with every alias expanded, without expanding anything (memoised per node)."""
    sizes: dict[int, int] = {}
    open_nodes: set[int] = set()  # entered, not yet counted: a child among them is a cycle (`a: &a [*a]`)
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, children_done = stack.pop()
        if id(node) in sizes:
            continue
        if isinstance(node, yaml.ScalarNode):
            sizes[id(node)] = 1
            continue
        children = (
            [child for pair in node.value for child in pair] if isinstance(node, yaml.MappingNode) else list(node.value)
        )
        if not children_done:
            if any(id(child) in open_nodes or child is node for child in children):
                raise ConfigError(f"{where}: a YAML alias refers to a node that contains it (a cycle); refused")
            open_nodes.add(id(node))
            stack.append((node, True))
            stack.extend((child, False) for child in children if id(child) not in sizes)
            continue
        open_nodes.discard(id(node))
        total = 1 + sum(sizes.get(id(child), 1) for child in children)
        if total > limit:
            raise ConfigError(f"{where}: YAML expands to more than {limit:,} nodes (aliases/anchors); refused")
        sizes[id(node)] = total
    return sizes[id(root)]


def _check_depth(root: yaml.Node, limit: int, where: str) -> None:
    stack, seen = [(root, 1)], set()
    while stack:
        node, depth = stack.pop()
        if depth > limit:
            raise ConfigError(f"{where}: YAML nested deeper than {limit} levels; refused")
        if isinstance(node, yaml.ScalarNode) or id(node) in seen:
            continue
        seen.add(id(node))
        children = (
            [child for pair in node.value for child in pair] if isinstance(node, yaml.MappingNode) else node.value
        )
        stack.extend((child, depth + 1) for child in children)


def load_yaml_text(
    text: str | bytes,
    where: str = "YAML",
    max_bytes: int = YAML_MAX_BYTES,
    max_depth: int = YAML_MAX_DEPTH,
    max_expanded_nodes: int = YAML_MAX_EXPANDED_NODES,
    loader: type = yaml.SafeLoader,
) -> object:
    """``safe_load`` with bounds: size, nesting depth and alias-expanded node count are checked on the composed
    node graph before any Python object is built, so hostile YAML is refused in bounded time and memory.

    ``loader`` may be a subclass of ``yaml.SafeLoader`` (e.g. one that adds constructors for a file format).
    Errors are :class:`ConfigError` naming ``where``.
    """
    size = len(text)
    if size > max_bytes:
        raise ConfigError(f"{where}: {size:,} bytes of YAML, more than the limit of {max_bytes:,}")
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ConfigError(f"{where}: not a UTF-8 text file ({exc.reason} at byte {exc.start})") from exc
    instance = loader(text)
    try:
        root = instance.get_single_node()
        if root is None:
            return None
        _check_depth(root, max_depth, where)
        _expanded_node_count(root, max_expanded_nodes, where)
        return instance.construct_document(root)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{where}: malformed YAML: {exc}") from exc
    except RecursionError as exc:
        raise ConfigError(f"{where}: YAML nested too deeply; refused") from exc
    finally:
        instance.dispose()


def read_yaml(path: str | Path, max_bytes: int = YAML_MAX_BYTES, loader: type = yaml.SafeLoader) -> object:
    """Read a YAML file with :func:`load_yaml_text`'s bounds; errors name the file."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{path}: is a directory, not a file")
    if not path.is_file():
        raise ConfigError(f"{path}: file not found")
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise ConfigError(f"{path}: {size:,} bytes of YAML, more than the limit of {max_bytes:,}")
        data = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    return load_yaml_text(data, str(path), max_bytes=max_bytes, loader=loader)


def require(mapping: object, key: str, where: str) -> object:
    if not isinstance(mapping, dict):
        raise ConfigError(f"{where}: expected a mapping, got {type(mapping).__name__}")
    if key not in mapping:
        raise ConfigError(f"{where}: missing key '{key}'")
    return mapping[key]


def vector(value: object, length: int, where: str, positive: bool = False) -> np.ndarray:
    """``length`` finite numbers as a float array (all > 0 when ``positive``); a :class:`ConfigError` names ``where``."""
    try:
        vec = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: expected {length} numbers, got {_short(value)}") from exc
    if vec.shape != (length,):
        raise ConfigError(f"{where}: expected {length} numbers, got {_short(value)}")
    if not np.all(np.isfinite(vec)):
        raise ConfigError(f"{where}: values must be finite, got {_short(value)}")
    if positive and not np.all(vec > 0.0):
        raise ConfigError(f"{where}: values must be positive, got {_short(value)}")
    return vec


def _short(value: object, limit: int = 80) -> str:
    """``repr(value)`` cut to ``limit`` characters, so a hostile value cannot flood a message."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[: limit - 3]}..."


def number(
    value: object,
    where: str,
    low: float | None = None,
    high: float | None = None,
    low_inclusive: bool = True,
    high_inclusive: bool = True,
) -> float:
    """A finite number (not a bool) within ``[low, high]`` (bounds optional, each inclusive unless told otherwise)."""
    if isinstance(value, bool):
        raise ConfigError(f"{where}: expected a number, got {_short(value)}")
    try:
        result = float(value)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ConfigError(f"{where}: expected a number, got {_short(value)}") from exc
    if not math.isfinite(result):
        raise ConfigError(f"{where}: must be a finite number, got {_short(value)}")
    if low is not None and (result < low or (not low_inclusive and result == low)):
        relation = ">=" if low_inclusive else ">"
        raise ConfigError(f"{where}: must be {relation} {low:g}, got {_short(value)}")
    if high is not None and (result > high or (not high_inclusive and result == high)):
        relation = "<=" if high_inclusive else "<"
        raise ConfigError(f"{where}: must be {relation} {high:g}, got {_short(value)}")
    return result


def whole(value: object, where: str, low: int | None = None, high: int | None = None) -> int:
    """A whole number (``3`` or ``3.0``, never ``2.5`` or a bool) within ``[low, high]``."""
    result = number(value, where, low, high)
    if result != int(result):
        raise ConfigError(f"{where}: must be a whole number, got {_short(value)}")
    return int(result)


def number_list(
    value: object,
    where: str,
    low: float | None = None,
    high: float | None = None,
    min_length: int = 1,
    max_length: int | None = None,
) -> list[float]:
    """A list of finite numbers, each within ``[low, high]``, of ``min_length``..``max_length`` entries."""
    if isinstance(value, (str, bytes, dict)) or not hasattr(value, "__iter__"):
        raise ConfigError(f"{where}: expected a list of numbers, got {_short(value)}")
    items = list(value)
    if len(items) < min_length or (max_length is not None and len(items) > max_length):
        span = f"{min_length}..{max_length}" if max_length is not None else f"at least {min_length}"
        raise ConfigError(f"{where}: expected {span} numbers, got {len(items)}")
    return [number(item, f"{where}[{i}]", low, high) for i, item in enumerate(items)]


def positive(value: object, where: str) -> float:
    """A finite number > 0."""
    result = number(value, where)
    if result <= 0.0:
        raise ConfigError(f"{where}: must be a positive number, got {_short(value)}")
    return result


def non_negative(value: object, where: str) -> float:
    """A finite number >= 0."""
    result = number(value, where)
    if result < 0.0:
        raise ConfigError(f"{where}: must be a finite number >= 0, got {_short(value)}")
    return result
