"""Where the compiled passes' workspaces lie in one flat buffer: the layout table of a chain's
size and the arrays' views by name (:mod:`qchain.algorithms.arrays`, "one flat buffer").

The allocators (``recursive.aba_workspace``, ``rnea_derivatives.rnea_workspace``,
``aba_derivatives.aba_derivatives_workspace``, ``planar.planar_workspace``) define the arrays'
shapes; the table lays them out one after another in the order of
:data:`~qchain.algorithms.arrays.KERNEL_NDIM`. The engine's workspace
(:mod:`qchain.sim.engine.system`) and :class:`qchain.arm.data.Data` hold such a buffer, which
compiled code carves with :func:`~qchain.algorithms.arrays.carve_aba` and its siblings.
"""

from __future__ import annotations

import functools

import numpy as np

from . import aba_derivatives, planar, recursive, rnea_derivatives
from .arrays import KERNEL_NDIM

__all__ = ["kernel_arrays", "kernel_layout", "kernel_views"]


def kernel_arrays(n: int, nv: int) -> list[np.ndarray]:
    """Fresh zero arrays of the four workspaces in the buffer's order (the compiled allocators'
    own code, run by numpy: their shapes without loading four cached functions)."""
    return [*recursive.aba_workspace.py_func(n, nv), *rnea_derivatives.rnea_workspace.py_func(n, nv),
            *aba_derivatives.aba_derivatives_workspace.py_func(n, nv), *planar.planar_workspace.py_func(n)]


@functools.lru_cache(maxsize=64)
def kernel_layout(n: int, nv: int) -> np.ndarray:
    """``(K + 1, 5) int64``: each workspace array's offset in the buffer and its shape (trailing
    dimensions 1); the last row's offset is the buffer's size. Shared by every chain of that
    size: never written."""
    arrays = kernel_arrays(n, nv)
    table = np.ones((len(arrays) + 1, 5), dtype=np.int64)
    o = 0
    for i, a in enumerate(arrays):
        table[i, 0] = o
        table[i, 1 : 1 + a.ndim] = a.shape
        o += a.size
    table[-1, 0] = o
    return table


def kernel_views(buf: np.ndarray, table: np.ndarray) -> list[np.ndarray]:
    """The workspace arrays as numpy views of ``buf`` (``table[-1, 0]`` floats) by the layout
    ``table``, in the buffer's order (what the compiled carvings give)."""
    ndims = [d for group in KERNEL_NDIM for d in group]
    return [buf[o : o + int(np.prod(shape[:nd]))].reshape(tuple(shape[:nd]))
            for (o, *shape), nd in zip(table[:-1].tolist(), ndims)]
