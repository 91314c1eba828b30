"""The first run after install: compile in parallel before the run, say so, and time it apart.

The engine's parts (``rhs_planar`` / ``rhs_spatial``, ``jacobian``, ``advance``,
``energies``) and how they are compiled: docs/engine.md, "The first run: compiling".
:func:`prepare` makes them ready before a run starts; :func:`start` sets the workers going
earlier (a scene does so before it builds its model). An editable install has compiled the
default method's parts already (``buildhooks/qchain_build.py``, docs/engine.md "Compiled at
install"): then nothing here is cold and nothing is said.
"""

from __future__ import annotations

import atexit
import os
import subprocess
import sys
import threading
import time

import numpy as np

from . import packing, steppers, system
from ..._jit import Kernel, cached_here, first_class_functions

__all__ = ["prepare", "prepare_energies", "start", "parts", "is_cached", "announce", "loaded", "callbacks",
           "EXPECTED_COMPILE_S", "IMPLICIT"]

#: Seconds a cold compile of each method's engine takes on a 2-core machine of the kind CI
#: runs on, with its parts compiled in parallel (``benchmarks/bench_compile.py`` measures
#: them again).
EXPECTED_COMPILE_S = {"radau5": 25, "dopri5": 15, "rk4": 15, "midpoint": 25}
#: Seconds a cold compile of the samples' energies pass takes (on its own, in one process).
EXPECTED_ENERGIES_S = 8
#: the methods whose stepper calls the Jacobian
IMPLICIT = ("midpoint", "radau5")

_workers: dict[tuple, subprocess.Popen] = {}  # ((method or '', part), ...) -> the worker compiling them


def _terminate_workers() -> None:
    for p in _workers.values():
        if p.poll() is None:
            p.kill()
    _workers.clear()


atexit.register(_terminate_workers)


# ------------------------------------------------------------------------------ the parts


def standin(method: str, planar_kernel: bool) -> tuple:
    """``(m, wk, it, out, c)`` of a one-segment chain: the argument types of every run's
    engine (the types do not depend on the chain's size, base or inputs), for compiling
    without the run's own chain."""
    chain = _standin_chain(planar_kernel)
    m = packing.pack(chain, np.zeros(chain.nu), np.zeros(chain.nv))
    wk = system.workspace(chain, m)
    it = steppers.integrator(m.idx.size, chain.nq)
    out = (np.zeros(1), np.zeros((1, chain.nq)), np.zeros((1, chain.nv)), np.zeros((1, chain.nu)))
    return m, wk, it, out, steppers.constants(method)


def _standin_chain(planar: bool = False):
    """A one-segment chain on a fixed base: what compiling needs of a chain (its types)."""
    from ...arm.chain import Chain
    from ...model.segment import Segment

    seg = Segment(length=0.1, radius=0.01, mass=0.01, chamber_area=1e-5, chamber_radius=0.005,
                  youngs_modulus=1e5, nodes=1)
    return Chain([seg], base="fixed", planar=planar)


def _kernel_args(name: str, m, wk, it) -> tuple:
    if name == "jacobian":
        return (m, wk, 0.0, it.y, it.Jq, it.Jv)
    return (m, wk, 0.0, it.y, it.f)


def _kernels(method: str, m) -> list[Kernel]:
    return [system.rhs(m)] + ([system.jacobian] if method in IMPLICIT else [])


def callbacks(method: str, m, wk, it) -> tuple:
    """The stepper's first argument: the compiled right-hand side (and Jacobian, for an
    implicit method), loaded from the cache or compiled here."""
    return tuple(k.compile(*_kernel_args(k.__name__, m, wk, it)) for k in _kernels(method, m))


def _advance_types(method: str, m, wk, it, out, c) -> tuple:
    import numba
    from numba.core import types

    with first_class_functions():  # (numba warns where it types a tuple of callbacks)
        fs = types.Tuple(tuple(k.function_type(*_kernel_args(k.__name__, m, wk, it)) for k in _kernels(method, m)))
    return (fs,) + tuple(numba.typeof(a) for a in (m, wk, it, out, c)) + (types.float64, types.int64, types.int64)


def is_cached(dispatcher) -> bool | None:
    """Whether numba's on-disk cache holds machine code for ``dispatcher`` built from its
    current source (None if that cannot be told)."""
    try:
        return cached_here(dispatcher, lambda key: True)
    except Exception:  # numba's cache layout is not public API: no answer, no notice
        return None


def parts(method: str, m, wk, it, energies: bool = True) -> dict[str, bool | None]:
    """The parts of ``method``'s engine for the model ``m`` (with the energies' pass if
    ``energies``): whether the on-disk cache holds each (None: cannot be told)."""
    out = {k.__name__: k.is_cached(*_kernel_args(k.__name__, m, wk, it)) for k in _kernels(method, m)}
    out["advance"] = is_cached(steppers.ADVANCE[method])
    if energies:
        out["energies"] = is_cached(system.energies_batch)
    return out


def loaded(method: str) -> bool:
    """Whether this process has ``method``'s stepper compiled or loaded."""
    return len(steppers.ADVANCE[method].overloads) > 0


_announced: set[str] = set()


def announce(method: str, cold: list[str], stream=sys.stderr) -> None:
    """One line on ``stream`` saying what is compiled and how long it takes (once a method)."""
    if stream is not None and cold and method not in _announced:
        _announced.add(method)
        print(f"qchain: compiling the {method} engine for this machine ({', '.join(cold)}): about "
              f"{EXPECTED_COMPILE_S[method]} s on 2 cores, once after install or an update (cached for later runs)",
              file=stream, flush=True)


# ------------------------------------------------------------------------------ the workers


def _groups(cold: list[str]) -> list[list[str]]:
    """The cold parts as two workers' shares of about equal cost (about 20 s each on one
    core for an implicit method): the Jacobian alone and the rest together, or for an
    explicit method the right-hand side and the rest."""
    first = [p for p in cold if p == "jacobian"] or [p for p in cold if p.startswith("rhs_")]
    rest = [p for p in cold if p not in first]
    return [g for g in (first, rest) if g]


def _spawn(parts_: list[str], method: str, planar_kernel: bool) -> None:
    """Start a worker compiling ``parts_`` into the cache, unless a live one has them."""
    busy = {q for group, p in _workers.items() if p.poll() is None for q in group}
    todo = tuple(q for q in parts_ if (method, q) not in busy and ("", q) not in busy)
    if not todo:
        return
    cmd = [sys.executable, "-c", "import sys; from qchain.sim.engine.warmup import _main; sys.exit(_main(sys.argv[1:]))",
           method, "planar" if planar_kernel else "spatial", *todo]
    key = tuple((method if q == "advance" else "", q) for q in todo)  # the stepper is the method's own
    try:
        _workers[key] = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                         stderr=subprocess.DEVNULL, env=os.environ.copy())
    except OSError:  # no process to be had: :func:`prepare` compiles it here
        pass


def _parallel() -> bool:
    return (os.cpu_count() or 1) > 1 and os.environ.get("QCHAIN_COMPILE_WORKERS", "1") != "0"


def start(method: str, planar_kernel: bool, energies: bool = False, stream=sys.stderr) -> None:
    """If the cache lacks parts of ``method``'s engine (the energies' pass too if
    ``energies``), say so on ``stream`` and start compiling them in worker processes; return
    at once (:func:`prepare` waits for them). ``planar_kernel``: the model will run on the
    planar kernel (the right-hand side differs)."""
    if method not in steppers.ADVANCE:
        return
    m, wk, it, _, _ = standin(method, planar_kernel)
    cold = [name for name, ok in parts(method, m, wk, it, energies).items() if ok is False]
    announce(method, cold, stream)
    if _parallel():
        for group in _groups(cold):
            _spawn(group, method, planar_kernel)


def _wait() -> None:
    """Wait for every worker (killed if this process is interrupted meanwhile)."""
    try:
        for p in _workers.values():
            p.wait()
    finally:
        _terminate_workers()


def prepare(method: str, m, wk, it, out, c, energies: bool = False, stream=sys.stderr) -> tuple:
    """Make ``method``'s engine ready for the model ``m`` (and the energies' pass if
    ``energies``) without taking a step: loaded from the cache, or compiled, the cold parts
    in worker processes. Returns ``(fs, advance)``: the stepper's callbacks and the compiled
    stepper, called ``advance(fs, m, wk, it, out, c, t_stop, max_out, max_steps)``."""
    key = (method, system.rhs(m).__name__, _fingerprint((m, wk, it, out, c)))
    ready = _ready.get(key)
    if ready is None:
        with _lock:  # runs on threads (qchain.batch.threads): one of them compiles or loads, the others wait
            ready = _ready.get(key) or _prepare(key, method, m, wk, it, out, c, energies, stream)
    if energies:
        prepare_energies(m, wk)
    return ready


def _prepare(key, method, m, wk, it, out, c, energies, stream) -> tuple:
    if loaded(method) and all(k.loaded(*_kernel_args(k.__name__, m, wk, it)) for k in _kernels(method, m)):
        fs = callbacks(method, m, wk, it)
    else:
        start(method, bool(m.planar_kernel == 1), energies, stream)
        _wait()
        fs = callbacks(method, m, wk, it)  # loaded from the cache, or compiled here if a worker failed
    advance = steppers.ADVANCE[method]
    # the compiled stepper's own entry point: numba's dispatcher types the callbacks argument in
    # Python at every call (a quarter of a millisecond), the entry point only unboxes it
    types = _advance_types(method, m, wk, it, out, c)
    if types not in advance.overloads:  # other argument types than the stand-in's (a read-only t_eval)
        with first_class_functions():
            advance.compile(types)
    entry = advance.overloads[types].entry_point
    _ready[key] = fs, entry
    return fs, entry


_ready: dict = {}  # (method, right-hand side, argument fingerprint) -> callbacks, this process
_lock = threading.RLock()  # held while a part is compiled or loaded


def _fingerprint(x) -> tuple:
    """What numba's types of the nested (named) tuple of arrays and ints ``x`` depend on (the
    tuple's class; dtype, dimensions, layout, writeable), at a fraction of the cost of
    ``numba.typeof``."""
    if isinstance(x, tuple):
        return (type(x),) + tuple(_fingerprint(a) for a in x)
    if not isinstance(x, np.ndarray):  # an int field of the model: int64 whatever its value
        return type(x)
    f = x.flags
    return x.dtype.num, x.ndim, f.c_contiguous, f.f_contiguous, f.writeable, f.aligned


def prepare_energies(m, wk, stream=sys.stderr) -> float:
    """Compile or load the samples' energies pass (needed at the first sample that reports
    energies, or where a trajectory's energies are first read); returns the seconds it took,
    0 if this process has it. Says so on ``stream`` first if it compiles."""
    if len(system.energies_batch.overloads):
        return 0.0
    with _lock:
        return _prepare_energies(m, wk, stream)


def _prepare_energies(m, wk, stream) -> float:
    if len(system.energies_batch.overloads):  # another thread has it now
        return 0.0
    if stream is not None and is_cached(system.energies_batch) is False:
        print(f"qchain: compiling the energies pass for this machine: about {EXPECTED_ENERGIES_S} s, once after "
              f"install or an update (cached for later runs)", file=stream, flush=True)
    t0 = time.perf_counter()
    e = np.zeros(0)
    system.energies_batch(m, wk, e, np.zeros((0, wk.q.size)), np.zeros((0, wk.v.size)), e, e.copy())
    return time.perf_counter() - t0


def _main(argv: list[str]) -> int:
    """A worker process: compile ``METHOD planar|spatial PART...`` into the cache."""
    method, variant, *names = argv
    m, wk, it, out, c = standin(method, variant == "planar")
    for name in names:
        if name == "advance":
            with first_class_functions():
                steppers.ADVANCE[method].compile(_advance_types(method, m, wk, it, out, c))
        elif name == "energies":
            prepare_energies(m, wk, stream=None)
        else:
            getattr(system, name).compile(*_kernel_args(name, m, wk, it))
    return 0

