"""The allowed-collision matrix and paddings of the collision checker, read from ``config/collision.yaml``
(regenerate it with ``tools/generate_collision_matrix.py``). Units: metres."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from agiprobot_measurement.common.config import non_negative
from agiprobot_measurement.station import CONFIG_DIR, ConfigError, read_yaml

__all__ = ["ALLOWED_REASONS", "AllowedEntry", "CollisionConfig", "load_collision_config"]

#: Reasons a pair may be listed in the allowed-collision matrix (those of MoveIt's SRDF).
ALLOWED_REASONS = ("Adjacent", "Never", "Always", "User")


@dataclass(frozen=True)
class AllowedEntry:
    """Why a pair is not checked, and which of its collision elements.

    ``elements`` None: the whole pair. Otherwise a set of element pairs ``((name_a, i), (name_b, j))`` with
    indices into each link's collision elements in URDF order (a scene object is element 0): only those are
    not checked, so e.g. the joint housings of two adjacent links may overlap while the forearm folding back
    onto the shoulder housing is still caught.
    """

    reason: str
    elements: frozenset | None = None

    def allows(self, a: str, i: int, b: str, j: int) -> bool:
        return self.elements is None or frozenset(((a, i), (b, j))) in self.elements


@dataclass
class CollisionConfig:
    """Paddings (m) and the allowed-collision matrix: unordered name pair -> :class:`AllowedEntry`.

    ``padding_m`` inflates the robot against scene objects and the part (their poses are uncertain);
    ``self_padding_m`` inflates it against itself (its own geometry is known, and a large value would forbid
    wrist poses that are physically fine).
    """

    padding_m: float = 0.01
    self_padding_m: float = 0.005
    allowed: dict[frozenset, AllowedEntry] = field(default_factory=dict)
    generation: dict = field(default_factory=dict)
    source: Path | None = None

    def is_allowed(self, a: str, b: str, i: int | None = None, j: int | None = None) -> bool:
        """Whether the pair (a, b) is not checked: as a whole, or (with i, j) for elements i of a, j of b."""
        entry = self.allowed.get(frozenset((a, b)))
        if entry is None:
            return False
        if i is None or j is None:
            return entry.elements is None
        return entry.allows(a, i, b, j)


def _element_pairs(value: object, a: str, b: str, where: str) -> frozenset:
    if not isinstance(value, list) or not value:
        raise ConfigError(f"{where}.elements: expected a non-empty list of [index_a, index_b] pairs")
    pairs = set()
    for item in value:
        if (
            not isinstance(item, list | tuple)
            or len(item) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in item)
        ):
            raise ConfigError(f"{where}.elements: expected pairs of element indices >= 0, got {item!r}")
        pairs.add(frozenset(((a, item[0]), (b, item[1]))))
    return frozenset(pairs)


def load_collision_config(path: str | Path | None = None) -> CollisionConfig:
    """Read ``config/collision.yaml`` (or ``path``); errors name the file and the bad entry."""
    path = Path(path) if path else CONFIG_DIR / "collision.yaml"
    data = read_yaml(path)
    where = str(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a mapping")
    paddings = {key: non_negative(data.get(key, 0.0), f"{where}: {key}") for key in ("padding_m", "self_padding_m")}
    allowed = {}
    entries = data.get("allowed_collisions") or []
    if not isinstance(entries, list):
        raise ConfigError(f"{where}: allowed_collisions must be a list")
    for k, entry in enumerate(entries):
        here = f"{where}: allowed_collisions[{k}]"
        if not isinstance(entry, dict) or not {"a", "b", "reason"} <= set(entry):
            raise ConfigError(f"{here}: expected a mapping with keys a, b, reason; got {entry!r}")
        a, b, reason = str(entry["a"]), str(entry["b"]), str(entry["reason"])
        if a == b:
            raise ConfigError(f"{here}: a pair needs two different names, got '{a}' twice")
        if reason not in ALLOWED_REASONS:
            raise ConfigError(f"{here}: unknown reason {reason!r}; valid: {', '.join(ALLOWED_REASONS)}")
        key = frozenset((a, b))
        if key in allowed:
            raise ConfigError(f"{here}: pair {a} - {b} listed twice")
        elements = _element_pairs(entry["elements"], a, b, here) if "elements" in entry else None
        allowed[key] = AllowedEntry(reason, elements)
    generation = data.get("generation") or {}
    if not isinstance(generation, dict):
        raise ConfigError(f"{where}: generation must be a mapping")
    return CollisionConfig(**paddings, allowed=allowed, generation=dict(generation), source=path)
