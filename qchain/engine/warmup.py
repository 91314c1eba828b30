"""The first run after install: compile before the run, say so, and time it apart.

numba compiles the engine's kernels at their first call and caches the machine code
(``cache=True``: in ``qchain/__pycache__`` folders, or ``NUMBA_CACHE_DIR``); later processes
load it. The driver makes that happen before a run starts (:func:`prepare`), so the run's
wall time and real-time factor never include compiling or loading, and first prints one
line on stderr when the cache holds nothing for the method (:func:`announce`, with the
expected time, :data:`EXPECTED_COMPILE_S`).
"""

from __future__ import annotations

import sys
import time

import numpy as np

from . import steppers, system

__all__ = ["prepare", "prepare_energies", "loaded", "announce", "is_cached", "EXPECTED_COMPILE_S"]

#: Seconds a cold compile of each method's engine took on a 2-core machine of the kind
#: CI runs on (``benchmarks/bench_compile.py`` measures them again).
EXPECTED_COMPILE_S = {"radau5": 65, "dopri5": 30, "rk4": 30, "midpoint": 60}


def is_cached(dispatcher) -> bool | None:
    """Whether numba's on-disk cache holds machine code for ``dispatcher`` built from its
    current source (None if that cannot be told)."""
    try:
        return bool(dispatcher._cache._cache_file._load_index())
    except Exception:  # numba's cache layout is not public API: no answer, no notice
        return None


def loaded(method: str) -> bool:
    """Whether this process has ``method``'s stepper compiled or loaded."""
    return len(steppers.ADVANCE[method].overloads) > 0


def announce(method: str, stream=sys.stderr) -> None:
    """One line on ``stream`` if the on-disk cache holds nothing for ``method``'s stepper."""
    if stream is not None and any(is_cached(d) is False for d in (steppers.ADVANCE[method], system.energies_batch)):
        print(f"qchain: compiling the {method} engine for this machine: about {EXPECTED_COMPILE_S[method]} s on 2 "
              f"cores, once after install or an update (cached for later runs)", file=stream, flush=True)


def prepare(method: str, m, wk, it, out, c) -> None:
    """Compile or load ``method``'s stepper with the system it calls, without taking a step."""
    steppers.ADVANCE[method](m, wk, it, out, c, it[4][steppers.T], 0, 0)  # no output, no step


def prepare_energies(m, wk) -> float:
    """Compile or load the sample energies' pass (needed at the first sample that reports
    energies, or after the run); returns the seconds it took, 0 if this process has it."""
    if len(system.energies_batch.overloads):
        return 0.0
    t0 = time.perf_counter()
    e = np.zeros(0)
    system.energies_batch(m, wk, e, np.zeros((0, wk[0].size)), np.zeros((0, wk[1].size)), e, e.copy())
    return time.perf_counter() - t0
