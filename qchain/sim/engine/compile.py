"""Compiling the whole engine ahead of a run (:func:`compile_all`): for an image, a cluster
node or a test session to start warm. A run compiles only what it needs, on first use
(:mod:`qchain.sim.engine.warmup`)."""

from __future__ import annotations

import sys

import numpy as np

from . import driver, steppers, warmup

__all__ = ["compile_all"]


def compile_all(methods=None, stream=sys.stderr) -> None:
    """Compile every part of the engine of each of ``methods`` (default: all) for both
    right-hand sides, with the energies' pass, into the cache: in parallel worker processes,
    or here if there are none. For an image or a cluster node to start warm."""
    if methods is None:
        methods = list(steppers.ADVANCE)
    elif isinstance(methods, str) or not isinstance(methods, (list, tuple)) or not all(
            isinstance(m, str) and m in steppers.ADVANCE for m in methods):
        raise ValueError(f"methods must be None (all) or a list of the compiled methods {tuple(steppers.ADVANCE)}, "
                         f"got {methods!r}")
    else:
        methods = list(methods)
    for method in methods:
        for planar_kernel in (False, True):
            warmup.start(method, planar_kernel, energies=True, stream=stream)
    warmup._wait()
    for method in methods:
        for planar_kernel in (False, True):
            m, wk, it, out, c = warmup.standin(method, planar_kernel)
            warmup.prepare(method, m, wk, it, out, c, energies=True, stream=stream)  # loads what the workers cached
    if any(m in ("dopri5", "rk4") for m in methods):  # the explicit methods' stability limit: the exact derivatives
        ch = warmup._standin_chain()
        driver.stability_limit(ch, ch.neutral(), np.zeros(ch.nv), np.zeros(ch.nu), np.zeros(ch.nv), 0.0)
