"""Values shown in messages, on one line: text from outside (:func:`printable`, defined in
:mod:`qchain.errors`, which a ``SceneError`` needs), paths (:func:`show_path`), vectors
(:func:`show_vector`), matrices (:func:`show_matrix`). Standard library only at import (the
command line's error path)."""

from __future__ import annotations

import os

from ..errors import printable

__all__ = ["printable", "show_path", "show_vector", "show_matrix"]


def show_path(path, limit: int | None = None) -> str:
    """A path as text any terminal shows (bytes that are not UTF-8 escaped), its middle left
    out beyond ``limit`` characters."""
    text = os.fsencode(path).decode("utf-8", "backslashreplace") if isinstance(path, (str, bytes, os.PathLike)) \
        else str(path)
    return text if limit is None or len(text) <= limit else f"{text[:limit - 30]}...{text[-27:]}"


def show_vector(x, most: int | None = None) -> str:
    """A vector as messages show it, ``(1, 0.5, 0)``: each entry to 6 significant digits (the
    first ``most`` entries, then ``...``); what is no array of numbers, as its repr (60 characters)."""
    import numpy as np  # (here: where a vector is shown, numpy is loaded)

    try:
        a = np.asarray(x, dtype=float).ravel()
    except (TypeError, ValueError):
        return repr(x)[:60]
    cut = most is not None and a.size > most
    return "(" + ", ".join(f"{v:.6g}" for v in (a[:most] if cut else a)) + (", ..." if cut else "") + ")"


def show_matrix(a) -> str:
    """A matrix as messages show it, one line, row by row: ``((1, 0), (0, 2))`` (each row as
    :func:`show_vector` shows it)."""
    import numpy as np

    return "(" + ", ".join(show_vector(row) for row in np.atleast_2d(np.asarray(a, dtype=float))) + ")"
