"""The one way the package writes a file: atomically, with the permissions a plain ``open()`` would give.

Two policies choose the path. A command-line user owns their files, like ``cp`` or ``gcc -o``: :func:`output_path`
takes a name as given (absolute, relative to the working directory or a base folder, ``..`` and ``~`` allowed) and
only refuses to replace an existing file without ``overwrite``. A node confines what remote clients ask it to read
or write to its configured folders: :class:`FileRoot`.

The data goes to a temporary file in the target's folder and is renamed over the target, so a reader sees the old
file or the new one, never half of one, and a failure leaves the old file untouched. ``mkstemp`` creates files
0600; the result is given ``0666 & ~umask`` (0644 under the usual umask 022), like any other file the user writes.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from agiprobot_measurement.errors import InputError

__all__ = [
    "TEXT_FILE_MAX_BYTES",
    "FileReadError",
    "FileRoot",
    "FolderNotFoundError",
    "OutputExistsError",
    "PathPolicyError",
    "atomic_write",
    "atomic_write_bytes",
    "atomic_write_text",
    "current_umask",
    "output_path",
    "read_text_file",
    "write_output",
]


class FolderNotFoundError(InputError, FileNotFoundError):
    """The folder a file is to be written into does not exist (also a ``FileNotFoundError``)."""


def current_umask() -> int:
    """The process umask (read without changing it for longer than the call)."""
    umask = os.umask(0)
    os.umask(umask)
    return umask


def atomic_write(path: str | Path, write: Callable[[Path], None], suffix: str = "", make_parents: bool = False) -> Path:
    """Call ``write(temporary_path)``, then rename the temporary file to ``path``; returns ``path``.

    ``suffix`` is appended to the temporary name for writers that choose a format by extension (e.g. ``.png``).
    A missing parent folder is an error (:class:`FolderNotFoundError`, a ``FileNotFoundError``) unless ``make_parents`` is true.
    """
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    elif not path.parent.is_dir():
        raise FolderNotFoundError(f"{path}: folder {path.parent} does not exist")
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


class PathPolicyError(InputError):
    """A requested file name breaks the file policy: outside the allowed roots, ``..``, ``~``, or an existing file
    that the request did not ask to overwrite."""


class OutputExistsError(PathPolicyError):
    """A command-line output file exists and the user did not ask to overwrite it."""


def output_path(
    name: str | Path,
    overwrite: bool = False,
    what: str = "output file",
    base: str | Path | None = None,
    suffix: str | None = None,
    make_parents: bool = False,
) -> Path:
    """The absolute path a command-line tool writes ``name`` to, checked before any work starts.

    ``name`` is taken as the user gives it: absolute, or relative to ``base`` (default: the working directory);
    ``..`` and ``~`` are followed. ``suffix`` (e.g. ``.yaml``) is appended when the name has none. Refused with an
    :class:`InputError` naming ``what``: an empty name, a directory, an existing file unless ``overwrite``
    (:class:`OutputExistsError`), a missing folder unless ``make_parents`` (:class:`FolderNotFoundError`), a
    folder that is not writable."""
    text = str(name).strip() if name is not None else ""
    if not text or "\x00" in text:
        raise PathPolicyError(f"{what}: empty or invalid file name {name!r}")
    path = Path(text).expanduser()
    if suffix and not path.suffix:
        path = path.with_name(path.name + suffix)
    if not path.is_absolute():
        path = Path(base).expanduser() / path if base is not None else Path.cwd() / path
    path = Path(os.path.normpath(path.absolute()))
    if path.is_dir():
        raise PathPolicyError(f"{what}: {path} is a directory")
    if path.exists() and not overwrite:
        raise OutputExistsError(f"{what}: {path} exists (--overwrite replaces it)")
    folder = path.parent
    while make_parents and not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise FolderNotFoundError(f"output directory does not exist: {Path(text).parent} (for {what} {text})")
    if not os.access(folder, os.W_OK):
        raise PathPolicyError(f"output directory is not writable: {folder} (for {what} {text})")
    return path


def write_output(path: str | Path, data: str | bytes | Callable[[Path], None], suffix: str = "") -> Path:
    """Write a command-line tool's output to ``path`` (from :func:`output_path`) atomically: text, bytes, or a
    writer ``data(temporary_path)`` (``suffix`` is then the temporary name's extension, for writers that choose a
    format by it); the folder is created when missing."""
    if callable(data):
        return atomic_write(path, data, suffix=suffix, make_parents=True)
    if isinstance(data, str):
        return atomic_write_text(path, data, make_parents=True)
    return atomic_write_bytes(path, data, make_parents=True)


@dataclass(frozen=True)
class FileRoot:
    """The file policy of one writer or reader: relative names resolve under ``root``; absolute names are accepted
    only inside ``root`` or one of ``extra_roots``; ``..`` and ``~`` are refused; symlinks are resolved before the
    check, so a link cannot lead outside. Writing refuses to replace an existing file unless ``overwrite``."""

    root: Path
    extra_roots: tuple[Path, ...] = ()
    purpose: str = "files"

    def __post_init__(self):
        object.__setattr__(self, "root", Path(self.root).expanduser().resolve())
        extra = dict.fromkeys(Path(r).expanduser().resolve() for r in self.extra_roots)  # ordered, no repeats
        extra.pop(self.root, None)
        object.__setattr__(self, "extra_roots", tuple(extra))

    @property
    def roots(self) -> tuple[Path, ...]:
        return (self.root, *self.extra_roots)

    def _describe_roots(self) -> str:
        return " or ".join(str(r) for r in self.roots)

    def resolve(self, name: str | Path, suffix: str | None = None) -> Path:
        """The confined absolute path of ``name``; ``suffix`` (e.g. ``.yaml``) is appended when the name has none."""
        text = str(name).strip() if name is not None else ""
        if not text or "\x00" in text:
            raise PathPolicyError(f"{self.purpose}: empty or invalid file name {name!r}")
        if text.startswith("~"):
            raise PathPolicyError(f"{self.purpose}: '~' is not expanded ({text}); names resolve under {self.root}")
        path = Path(text)
        if ".." in path.parts:
            raise PathPolicyError(f"{self.purpose}: '..' is not allowed in {text}; names resolve under {self.root}")
        if suffix and not path.suffix:
            path = path.with_name(path.name + suffix)
        candidate = (path if path.is_absolute() else self.root / path).resolve()
        if not any(candidate == r or candidate.is_relative_to(r) for r in self.roots):
            raise PathPolicyError(f"{self.purpose}: {text} is outside the allowed folder {self._describe_roots()}")
        return candidate

    def for_reading(self, name: str | Path, suffix: str | None = None) -> Path:
        """A confined path to an existing regular file (else :class:`PathPolicyError` / ``FileNotFoundError``)."""
        path = self.resolve(name, suffix)
        if path.is_dir():
            raise PathPolicyError(f"{self.purpose}: {path} is a directory, not a file")
        if not path.is_file() and suffix and not str(name).endswith(suffix):
            plain = self.resolve(name)
            if plain.is_file():
                return plain
        if not path.is_file():
            raise FileReadError(f"{self.purpose}: {path} not found (names resolve under {self.root})")
        return path

    def for_writing(self, name: str | Path, overwrite: bool = False, suffix: str | None = None) -> Path:
        """A confined path to write; an existing file is refused unless ``overwrite``; the folder must exist."""
        path = self.resolve(name, suffix)
        if path.is_dir():
            raise PathPolicyError(f"{self.purpose}: {path} is a directory")
        if path.exists() and not overwrite:
            raise PathPolicyError(f"{self.purpose}: {path} exists; ask for overwrite to replace it")
        return path


#: a text input (data file, flag points, result) larger than this is refused unread
TEXT_FILE_MAX_BYTES = 64 * 1024 * 1024


class FileReadError(InputError, FileNotFoundError):
    """An input file is missing, a directory, too large or not UTF-8 text."""


def read_text_file(path: str | Path, what: str = "file", max_bytes: int = TEXT_FILE_MAX_BYTES) -> str:
    """The UTF-8 text of ``path``; :class:`FileReadError` naming ``what``, the file and the problem otherwise."""
    path = Path(path)
    if path.is_dir():
        raise FileReadError(f"{path}: {what} is a directory, not a file")
    if not path.is_file():
        raise FileReadError(f"{path}: {what} not found")
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise FileReadError(f"{path}: {what} has {size:,} bytes, more than the limit of {max_bytes:,}")
        data = path.read_bytes()
    except OSError as exc:
        raise FileReadError(f"{path}: cannot read the {what}: {exc.strerror or exc}") from exc
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FileReadError(
            f"{path}: the {what} is not UTF-8 text (byte 0x{data[exc.start]:02x} at offset {exc.start}); "
            "is it a binary file?"
        ) from exc
