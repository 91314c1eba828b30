"""Paths from outside checked before use, each check written once (the messages stay the
callers', naming their key or flag): a NUL character (:func:`has_nul`, :func:`show_nul`),
what a path that is not a regular file is (:func:`file_kind`), a file where a folder must be
(:func:`file_in_the_way`); and an output written whole or not at all (:func:`written_whole`).
Standard library only: the command line's checks run before numpy loads."""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["has_nul", "show_nul", "file_kind", "file_in_the_way", "written_whole"]

#: (test of st_mode, the word, the detailed word) of each kind of file that is not a regular one.
_KINDS = (
    (stat.S_ISDIR, "a folder", "a folder"),
    (stat.S_ISFIFO, "a FIFO", "a FIFO (named pipe)"),
    (stat.S_ISCHR, "a device", "a character device"),
    (stat.S_ISBLK, "a device", "a block device"),
    (stat.S_ISSOCK, "a socket", "a socket"),
)


def has_nul(path: str) -> bool:
    """Whether the path ``path`` holds a NUL character (no system call takes one)."""
    return "\0" in path


def show_nul(path: str, mark: str = "\\0") -> str:
    """``path`` with each NUL character written as ``mark`` (``\\0`` by default), for a
    message: a terminal shows nothing where a NUL is."""
    return path.replace("\0", mark)


def file_kind(mode: int, detailed: bool = False, other: str = "not a regular file") -> str:
    """What a file of ``st_mode`` ``mode`` is, in words for a message: ``"a folder"``,
    ``"a FIFO"``, ``"a device"`` or ``"a socket"`` (``detailed``: ``"a FIFO (named pipe)"``,
    ``"a character device"``, ``"a block device"``), else ``other`` (a regular file too:
    callers ask only of a file that is not one)."""
    for test, word, detailed_word in _KINDS:
        if test(mode):
            return detailed_word if detailed else word
    return other


def file_in_the_way(folder: Path) -> Path | None:
    """The first of ``folder`` and its parents that exists and is not a folder, or None;
    raises what ``Path.exists`` raises."""
    for parent in [folder, *folder.parents]:
        if parent.exists() and not parent.is_dir():
            return parent
    return None


@contextmanager
def written_whole(path, binary: bool = False, prefix: str = ".part-") -> Iterator:
    """Write the file ``path`` whole or not at all: yields a file opened on a temporary file
    beside it (its folder made if missing), which replaces ``path`` (after ``fsync``) when the
    block ends without an exception and is removed when it raises, leaving an earlier
    ``path`` as it was."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=path.suffix, dir=path.parent)
    try:
        with os.fdopen(fd, "wb" if binary else "w") as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        tmp = None
    finally:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
