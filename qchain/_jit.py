"""The engine's numba decorators, in one place.

The engine runs without numba's reference counting (``_nrt=False``): with it every array
view (a row of a workspace, a slice of the state) costs an atomic count and its release,
which was half of a step's time. Such code cannot allocate arrays nor assign an array to a
slice (loops do); what it calls is compiled the same way.

The model's two big functions, the right-hand side and its exact Jacobian, are
:func:`kernel` s: C callbacks (``numba.cfunc``) that the steppers receive as arguments and
call through a pointer. numba otherwise links every compiled callee into its caller and
types, optimises and emits it again there, so each stepper paid again for the whole model;
a callback is compiled once, cached on its own, and can be compiled in another process at
the same time as the rest (:mod:`qchain.sim.engine.warmup`).

The entry points (:data:`ejit`) release Python's lock (``nogil``) for the whole call: a
stretch of steps runs in another thread while this one goes on, so a batch's rollouts run on
threads (:mod:`qchain.batch.threads`). Callbacks and inner functions never take the lock.
"""

from __future__ import annotations

import contextlib
import warnings

import numba
from numba.core import sigutils, types
from numba.core.caching import FunctionCache
from numba.core.ccallback import CFunc
from numba.core.errors import NumbaExperimentalFeatureWarning

__all__ = ["Address", "ejit", "ejit_inner", "inline", "kernel", "Kernel", "OPTIONS", "ENTRY_OPTIONS", "cached_here",
           "first_class_functions"]

#: the compiler options of every engine function
OPTIONS = dict(error_model="numpy", _nrt=False)
#: what an entry point's on-disk cache entries are marked with, beyond numba's own key
ENTRY_OPTIONS = dict(nogil=True)


class _MarkedCache(FunctionCache):
    """numba's on-disk cache with :data:`ENTRY_OPTIONS` in each entry's key.

    numba's key is the signature, the CPU and the bytecode, not the compiler options; an
    entry compiled before the entry points released the lock (from the same source file)
    would load and hold it. Marked entries are found only by dispatchers with these options.
    """

    def _index_key(self, sig, codegen):
        return super()._index_key(sig, codegen) + (tuple(sorted(ENTRY_OPTIONS.items())),)


def cached_here(dispatcher, key_matches) -> bool:
    """Whether ``dispatcher``'s on-disk index holds an entry whose key satisfies
    ``key_matches(key)`` and, for an entry point, carries :class:`_MarkedCache`'s mark
    (numba's cache layout is not public API: exceptions are the caller's to take)."""
    keys = dispatcher._cache._cache_file._load_index()
    mark = tuple(sorted(ENTRY_OPTIONS.items())) if isinstance(dispatcher._cache, _MarkedCache) else None
    return any(key_matches(k) and (mark is None or k[-1] == mark) for k in keys)


def ejit(fn):
    """An entry point, called from Python: compiled without a reference count, cached, and
    releasing Python's lock for the call (``nogil``)."""
    disp = numba.njit(cache=True, **ENTRY_OPTIONS, **OPTIONS)(fn)
    disp._cache = _MarkedCache(disp.py_func)
    return disp


#: called only from compiled code: the model and workspace tuples (dozens of arrays) get no
#: CPython wrapper to unbox them (calling one from Python crashes the process)
ejit_inner = numba.njit(cache=True, no_cpython_wrapper=True, **OPTIONS)
#: inlined into the caller: a separately compiled function is linked into and optimised
#: again with every caller, and a call passing the tuples copies them
inline = numba.njit(cache=True, inline="always", **OPTIONS)


@contextlib.contextmanager
def first_class_functions():
    """A context in which numba's warning that first-class function types are experimental
    is silenced: a stepper taking the callbacks is typed with them, and numba warns wherever
    a tuple of them is typed (compiling, or typing the arguments of a call). Not the user's
    concern, and a ``warnings.simplefilter("error")`` would stop every run on it; silenced
    where the engine types them, not by a filter set at import (importing qchain changes no
    global state)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
        yield


class Kernel:
    """A function of the model compiled to a C callback per argument types.

    ``kernel(*args)`` is not a call: :meth:`compile` gives the callback (a ``numba.cfunc``
    returning an int64 status) for the types of ``args``, loaded from numba's on-disk cache
    or compiled and cached, once per process. Pass the callback to compiled code, which
    calls it through its address (its numba type is ``FunctionType(signature)``).
    """

    def __init__(self, py_func):
        self.py_func = py_func
        self.__name__ = py_func.__name__
        self.__qualname__ = py_func.__qualname__
        self.__doc__ = py_func.__doc__
        self.__module__ = py_func.__module__
        self._compiled: dict = {}

    def __repr__(self) -> str:
        return f"<qchain kernel {self.__module__}.{self.__qualname__}>"

    @staticmethod
    def signature(*args):
        """The callback's numba signature for example arguments ``args``."""
        return types.int64(*(numba.typeof(a) for a in args))

    def function_type(self, *args):
        """The numba type of the callback for ``args`` (what a stepper is compiled for)."""
        return types.FunctionType(self.signature(*args))

    def _cfunc(self, sig) -> CFunc:
        cf = CFunc(self.py_func, sigutils.normalize_signature(sig), locals={}, options=dict(OPTIONS))
        cf.enable_caching()
        return cf

    def loaded(self, *args) -> bool:
        """Whether this process has the callback for ``args``."""
        return self.signature(*args) in self._compiled

    def is_cached(self, *args) -> bool | None:
        """Whether the on-disk cache holds the callback for ``args`` (None if that cannot be
        told), without loading or compiling it."""
        sig = self.signature(*args)
        if sig in self._compiled:
            return True
        try:
            return any(key[0] == sig for key in self._cfunc(sig)._cache._cache_file._load_index())
        except Exception:  # numba's cache layout is not public API: no answer
            return None

    def compile(self, *args) -> CFunc:
        """The callback for the types of ``args`` (loaded from the cache or compiled)."""
        sig = self.signature(*args)
        cf = self._compiled.get(sig)
        if cf is None:
            cf = self._cfunc(sig)
            cf.compile()
            self._compiled[sig] = cf
        return cf


class Address:
    """A compiled function as numba's first-class function arguments take it: its address
    (numba's wrapper address protocol). Passed to a compiled entry point in place of the
    callback itself, it is unboxed without typing the callback again at each call."""

    def __init__(self, address: int):
        self.address = address

    def __wrapper_address__(self) -> int:
        return self.address


def kernel(py_func) -> Kernel:
    """Decorate a model function ``f(m, wk, ...) -> status`` as a :class:`Kernel`."""
    return Kernel(py_func)
