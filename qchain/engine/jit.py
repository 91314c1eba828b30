"""The engine's numba decorators, in one place.

The engine runs without numba's reference counting (``_nrt=False``): with it every array
view (a row of a workspace, a slice of the state) costs an atomic count and its release,
which was half of a step's time. Such code cannot allocate arrays nor assign an array to a
slice (loops do); what it calls is compiled the same way.
"""

from __future__ import annotations

import numba

__all__ = ["ejit", "ejit_inner", "inline"]

#: entry points, called from Python
ejit = numba.njit(cache=True, error_model="numpy", _nrt=False)
#: called only from compiled code: the model and workspace tuples (dozens of arrays) get no
#: CPython wrapper to unbox them (calling one from Python crashes the process)
ejit_inner = numba.njit(cache=True, error_model="numpy", _nrt=False, no_cpython_wrapper=True)
#: inlined into the caller: a separately compiled function is linked into and optimised
#: again with every caller, and a call passing the tuples copies them
inline = numba.njit(cache=True, error_model="numpy", _nrt=False, inline="always")
