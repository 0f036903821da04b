"""The one place that bounds what the package reads, checked before the work starts, and the one way an error quotes
what it was given.

Every reader of a user's or a client's input (files, images, meshes, data files, service and goal fields) checks
its size against :data:`LIMITS` first, with :func:`check_file_size` and :func:`check_count`, so that a hostile or
careless input is refused in bounded time and memory with an :class:`InputTooLarge` naming what, how much and the
bound. Error messages quote inputs only through :func:`excerpt` (a short, printable excerpt), so that a bad line of
a 60 MB file gives a message of a hundred characters, not 60 MB.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from agiprobot_measurement.errors import InputError

__all__ = [
    "EXCERPT_CHARS",
    "LIMITS",
    "InputLimits",
    "InputTooLarge",
    "check_count",
    "check_file_size",
    "excerpt",
    "local_worker_limit",
]

#: characters of an input quoted in an error message at most
EXCERPT_CHARS = 60

MiB = 1024 * 1024


@dataclass(frozen=True)
class InputLimits:
    """Upper bounds of the inputs the package accepts (sizes in bytes, counts in items)."""

    #: a text file read whole (calibration data, plans, reports)
    text_file_bytes: int = 64 * MiB
    #: lines of a text data file (a calibration data file: 4 lines per sample)
    data_file_lines: int = 400_000
    #: a mesh file (STL, OBJ, PLY, ...)
    mesh_file_bytes: int = 200 * MiB
    #: a STEP file (its tessellation takes 35 to 50 times the file's size in memory)
    step_file_bytes: int = 20 * MiB
    #: faces of a part's mesh
    mesh_faces: int = 2_000_000
    #: pixels of an image or array read as a 2D object
    image_pixels: int = 16_000_000
    #: voxels of a 3D map a request may ask for
    map_voxels: int = 64_000_000
    #: local worker processes per core
    workers_per_core: int = 2


#: the package's limits
LIMITS = InputLimits()


class InputTooLarge(InputError):
    """An input is larger than the package's bound for it (:class:`InputLimits`)."""


def excerpt(value: object, max_chars: int = EXCERPT_CHARS) -> str:
    """``repr`` of at most ``max_chars`` characters of ``value`` (bytes or text; anything else by its ``str``),
    followed by the total length when cut: safe to put into a message whatever ``value`` holds."""
    if isinstance(value, bytes | bytearray):
        head, total = bytes(value[: max_chars + 1]), len(value)
    else:
        text = value if isinstance(value, str) else str(value)
        head, total = text[: max_chars + 1], len(text)
    if total <= max_chars:
        return repr(head)
    return f"{head[:max_chars]!r}... ({total:,} {'bytes' if isinstance(head, bytes) else 'characters'})"


def check_file_size(path: str | Path, limit_bytes: int, what: str = "file") -> int:
    """The size (bytes) of the existing file ``path``; :class:`InputTooLarge` naming ``what`` when over
    ``limit_bytes``. The file's existence is the caller's check."""
    size = os.stat(path).st_size
    if size > limit_bytes:
        raise InputTooLarge(f"{path}: the {what} has {size:,} bytes, more than the limit of {limit_bytes:,}")
    return size


def check_count(count: int | float, limit: int | float, what: str) -> int | float:
    """``count`` when it is at most ``limit``; :class:`InputTooLarge` naming ``what``, the count and the limit
    otherwise (also for a count that is not finite)."""
    if not count <= limit:  # also NaN
        raise InputTooLarge(f"{what}: {count:,} is more than the limit of {limit:,}")
    return count


def local_worker_limit(cores: int | None = None) -> int:
    """The most local worker processes allowed: :attr:`InputLimits.workers_per_core` per core of this machine."""
    return max(1, int(cores if cores is not None else os.cpu_count() or 1)) * LIMITS.workers_per_core
