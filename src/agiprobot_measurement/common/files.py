"""The one way the package writes a file: atomically, with the permissions a plain ``open()`` would give.

The data goes to a temporary file in the target's folder and is renamed over the target, so a reader sees the old
file or the new one, never half of one, and a failure leaves the old file untouched. ``mkstemp`` creates files
0600; the result is given ``0666 & ~umask`` (0644 under the usual umask 022), like any other file the user writes.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path

__all__ = ["atomic_write", "atomic_write_bytes", "atomic_write_text", "current_umask"]


def current_umask() -> int:
    """The process umask (read without changing it for longer than the call)."""
    umask = os.umask(0)
    os.umask(umask)
    return umask


def atomic_write(path: str | Path, write: Callable[[Path], None], suffix: str = "", make_parents: bool = False) -> Path:
    """Call ``write(temporary_path)``, then rename the temporary file to ``path``; returns ``path``.

    ``suffix`` is appended to the temporary name for writers that choose a format by extension (e.g. ``.png``).
    A missing parent folder is an error (``FileNotFoundError``) unless ``make_parents`` is true.
    """
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    elif not path.parent.is_dir():
        raise FileNotFoundError(f"{path}: folder {path.parent} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=f".tmp{suffix}", dir=path.parent)
    os.close(fd)
    try:
        write(Path(tmp))
        os.chmod(tmp, 0o666 & ~current_umask())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_write_bytes(path: str | Path, data: bytes, make_parents: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically (flushed to disk before the rename)."""

    def write(tmp: Path) -> None:
        with tmp.open("wb") as stream:
            stream.write(data)
            stream.flush()
            os.fsync(stream.fileno())

    return atomic_write(path, write, make_parents=make_parents)


def atomic_write_text(path: str | Path, text: str, encoding: str = "utf-8", make_parents: bool = False) -> Path:
    """Write ``text`` to ``path`` atomically."""
    return atomic_write_bytes(path, text.encode(encoding), make_parents=make_parents)
