"""Read-only arrays that stay read-only through ``copy.deepcopy`` and pickling.

A model keeps its parameter arrays read-only (``Chain.gravity``, ``Segment.stiffness_matrix``,
a schedule's values): the compiled passes use them as given at construction, so a write
would change a model behind its checks. numpy pickles every array as writeable; a class
that mixes in :class:`KeepsReadOnly` writes down which of its arrays were read-only (its
attributes, and inside their dicts, lists and tuples three levels deep) and makes them
read-only again when it is unpickled or deep-copied.
"""

from __future__ import annotations

import numpy as np

__all__ = ["KeepsReadOnly"]

_KEY = "_read_only_paths"


def _paths(x, path: tuple, out: list, depth: int) -> None:
    if isinstance(x, np.ndarray):
        if not x.flags.writeable:
            out.append(path)
    elif depth and isinstance(x, dict):
        for k, v in x.items():
            _paths(v, path + (k,), out, depth - 1)
    elif depth and isinstance(x, (list, tuple)):
        for i, v in enumerate(x):
            _paths(v, path + (i,), out, depth - 1)


class KeepsReadOnly:
    """Mixin: the read-only arrays of an instance's ``__dict__`` are read-only in its copies."""

    def __getstate__(self):
        state = dict(self.__dict__)
        ro: list = []
        _paths(state, (), ro, 4)
        state[_KEY] = ro
        return state

    def __setstate__(self, state) -> None:
        state = dict(state)
        ro = state.pop(_KEY, ())
        self.__dict__.update(state)
        for path in ro:
            x = self.__dict__
            for k in path:
                x = x[k]
            x.flags.writeable = False
