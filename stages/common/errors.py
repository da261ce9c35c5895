"""The one exception base a user can cause. The CLI turns it into one line and exit code 1."""

from __future__ import annotations

import errno
import os
from pathlib import Path


class FieldlocError(Exception):
    """An error caused by the user's input: missing file, wrong schema, invalid field, ..."""


class DiskFullError(FieldlocError):
    """A write of ``path`` (the output the user gave) that its disk had no room (or quota)
    for. The message says to free space; what the failed run kept, if anything, is the
    command's to add (``line``): the CLI adds what a rerun finds for the commands that keep
    finished work (extract's frames, batch's runs), nothing for those that keep nothing."""

    def __init__(self, path, room: str = ""):
        self.path, self.room = path, room  # room: what it needs against what is free, if known
        super().__init__(self.line())

    def line(self, kept: str = "") -> str:
        """The message, with ``kept`` (what the run kept) in its parenthesis if given."""
        note = f"; {kept}" if kept else ""
        room = f"{self.room}: " if self.room else ""
        return (f"cannot write {self.path}: no space left on its disk ({room}free some space"
                f" or write elsewhere{note})")


class FieldSpecError(FieldlocError):
    """A field YAML is invalid; the message names the file and the key."""


class SchemaError(FieldlocError):
    """An artifact is not of the expected schema or version, or is corrupt."""


class DatasetError(FieldlocError):
    """A dataset folder is missing something or holds unreadable content."""


def shown(value, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters: a message quotes at most a few dozen
    characters of a bad value (a value of megabytes would make a "one-line" error as long)."""
    s = repr(value)
    return s if len(s) <= limit else s[:limit - 3] + "..."


def link_loop(path: Path) -> bool:
    """Whether ``path`` is a symbolic link that leads back to itself (Path.exists says False
    for it, as for nothing at all)."""
    try:
        os.stat(path)
    except OSError as e:
        return e.errno == errno.ELOOP
    except ValueError:  # a NUL byte: no path at all (file_problem says so)
        return False
    return False


def real_path(path) -> Path:
    """``path`` absolute with its symbolic links followed, never raising: Path.resolve raises
    RuntimeError for a link loop (Python < 3.13), a traceback for a path the user gave;
    os.path.realpath leaves the looping part as it is, for the file checks (file_problem) to
    name."""
    return Path(os.path.realpath(path))


def file_problem(path) -> str | None:
    """Why ``path`` is no file to read, in a message's words ("not found", "is a folder", "is
    not a regular file ..."), or None for a regular file: /dev/null was "not found"."""
    path = Path(path)
    if "\0" in str(path):  # os.stat's ValueError "embedded null byte" (trial M, M1)
        return "is no path (it holds a NUL byte)"
    if path.is_file():
        return None
    if path.is_dir():
        return "is a folder"
    if path.exists():
        return "is not a regular file (a device, pipe or socket)"
    if link_loop(path):
        return "is not a regular file (a symbolic link loop)"
    return "not found"


def check_file(path, what: str, error: type[FieldlocError] = FieldlocError) -> Path:
    """``path`` if it is a regular file to read; else ``error``: "<what> not found: <path>"
    when nothing is there, "<what>: <path> is not a regular file ..." for a FIFO, a device,
    a folder or a link loop (a FIFO was reported "not found": the wrong reason; reading it
    would block)."""
    why = file_problem(path)
    if why is None:
        return Path(path)
    if why == "not found":
        raise error(f"{what} not found: {path}")
    raise error(f"{what}: {path} {why}")


def present(path) -> bool:
    """Whether a dataset file is there (``path``: a pathlib.Path): True for a regular file,
    False when nothing is at ``path``; anything else (a FIFO, a socket, a device, a folder, a
    link loop) is a DatasetError, not an absent file (a FIFO would block its read forever;
    taking it as absent would run on silently without the odometry, the IMU or the stamps it
    names)."""
    if path.is_file():
        return True
    if not path.exists() and not link_loop(path):  # nothing there, or a link to nothing
        return False
    raise DatasetError(f"{path}: not a regular file (a pipe, socket, device, folder or link"
                       " loop)")
