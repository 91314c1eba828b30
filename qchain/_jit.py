"""qchain's numba decorators and array views, in one place: the engine's (:data:`ejit`,
:data:`ejit_inner`, :data:`inline`, :func:`kernel`) and the model's kernels' and passes'
(:data:`jit`, :data:`jit_helper`, :data:`jit_inline`, :data:`jit_pass`).

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

:func:`view2`, :func:`view3` and :func:`view4` give a 1-D buffer's entries as a C-ordered
matrix or array in compiled code (the scratch and workspace carvings of every pass), without
numba's ``reshape``, which calls a C helper of the runtime at every carving: dozens a
right-hand side, each costlier than the carving's own work (docs/benchmarks/README.md,
"Speed of a chain").
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import warnings
from pathlib import Path

import numba
from numba.core import cgutils, sigutils, types
from numba.core.caching import FunctionCache, IndexDataCacheFile
from numba.core.ccallback import CFunc
from numba.core.errors import NumbaExperimentalFeatureWarning
from numba.core.imputils import impl_ret_borrowed
from numba.extending import intrinsic, register_jitable
from numba.np.arrayobj import make_array, populate_array

__all__ = ["Address", "ejit", "ejit_inner", "inline", "kernel", "Kernel", "OPTIONS", "ENTRY_OPTIONS", "cached_here",
           "view2", "view3", "view4",
           "first_class_functions", "cached_njit", "COMPILED_SOURCES", "tree_stamp", "jit", "jit_helper",
           "jit_inline", "jit_pass", "jit_sums"]

#: the compiler options of every engine function
OPTIONS = dict(error_model="numpy", _nrt=False)
#: what an entry point's on-disk cache entries are marked with, beyond numba's own key
ENTRY_OPTIONS = dict(nogil=True)


#: The parts of qchain (relative to the package) whose source its compiled code is made of or
#: reads when it is compiled: every module with compiled functions and every qchain module
#: those import (constants, tuple types); ``tests/test_install_compile.py`` holds it to that closure.
COMPILED_SOURCES = ("_jit.py", "_blas.py", "errors.py", "algorithms", "arm", "checks", "contact", "model", "sim")


@functools.cache
def tree_stamp() -> str:
    """A digest of the modification times and sizes of every ``.py`` file of
    :data:`COMPILED_SOURCES`, once a process.

    numba keeps a cache entry while the source file of its function keeps its stamp, but a
    compiled function holds the code of every compiled function it calls, from other files
    too: a helper changed in ``model/arc.py`` would leave the cached passes of
    ``algorithms/recursive.py`` running the old helper, without a word. qchain's caches
    (:class:`_TreeCache`) are therefore stamped with the whole compiled tree as well: a change
    anywhere in it (an edit, a ``git pull`` on an editable install) compiles again what is used.
    """
    root = Path(__file__).resolve().parent
    h = hashlib.sha1()
    for part in COMPILED_SOURCES:
        path = root / part
        for f in sorted(path.rglob("*.py")) if path.is_dir() else [path]:
            st = f.stat()
            h.update(f"{f.relative_to(root).as_posix()}:{st.st_mtime_ns}:{st.st_size}\n".encode())
    return h.hexdigest()


class _TreeCache(FunctionCache):
    """numba's on-disk cache of a function, its index stamped with its source file (numba's
    stamp) and with :func:`tree_stamp`: an entry is taken only while no compiled source of
    qchain has changed since it was written."""

    def __init__(self, py_func):
        super().__init__(py_func)
        self._cache_file = IndexDataCacheFile(cache_path=self._cache_path, filename_base=self._impl.filename_base,
                                              source_stamp=(self._impl.locator.get_source_stamp(), tree_stamp()))


def cached_njit(cache_class=None, **options):
    """``numba.njit(cache=True, **options)`` with qchain's cache (``cache_class``, default
    :class:`_TreeCache`): the decorator of every cached compiled function of qchain."""
    def decorate(fn):
        disp = numba.njit(cache=True, **options)(fn)
        disp._cache = (cache_class or _TreeCache)(disp.py_func)
        return disp
    return decorate


class _MarkedCache(_TreeCache):
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
    return cached_njit(_MarkedCache, **ENTRY_OPTIONS, **OPTIONS)(fn)


#: called only from compiled code: the model and workspace tuples (dozens of arrays) get no
#: CPython wrapper to unbox them (calling one from Python crashes the process)
ejit_inner = cached_njit(no_cpython_wrapper=True, **OPTIONS)
#: inlined into the caller: a separately compiled function is linked into and optimised
#: again with every caller, and a call passing the tuples copies them
inline = cached_njit(inline="always", **OPTIONS)


#: The model's compiled kernels and passes (``qchain.model``, ``qchain.algorithms``,
#: ``qchain.contact``): numba's options for them, one place.
jit = cached_njit(fastmath=False, error_model="numpy")

#: The kernels' private helpers (what only compiled code calls). numba types a constant argument
#: (a size, an offset, a flag) as a literal and compiles a ``jit`` function once more for every
#: distinct one (``take2`` had ten specialisations, each a full compile); a ``register_jitable``
#: function is typed with the non-literal types first, so it is compiled once per argument types
#: (and per set of its callers' compiler flags: ``jit`` callers, helper callers, callers without
#: reference counting). It gets no CPython or C wrapper and no cache files of its own (it is
#: compiled into its callers, which are cached), which makes it cheaper to compile than a ``jit``
#: function. Called from Python it runs as plain Python.
jit_helper = register_jitable(fastmath=False, error_model="numpy", no_cfunc_wrapper=True)
#: A helper numba inlines into its caller's code before typing (:data:`jit`'s options): the
#: helpers take arrays, and a compiled call with array arguments costs atomic reference counts,
#: which numba prunes only within one function (the planar passes, ``_rnea_derivatives``' pieces).
jit_inline = cached_njit(fastmath=False, error_model="numpy", inline="always")
#: A pass called from Python that allocates nothing (it writes only into the arrays it is
#: given): compiled without numba's reference count, as the engine's code is (:data:`OPTIONS`).
#: With it every array view a pass makes (a segment's nodes, a workspace row, a scratch carving)
#: and every array handed to a compiled callee costs an atomic count and its release: a quarter
#: of a forward-dynamics call from Python at ten segments. Such a pass cannot allocate arrays
#: nor assign an array to a slice (loops do); the explicit flag holds for every caller.
jit_pass = cached_njit(fastmath=False, error_model="numpy", _nrt=False)
#: Dense loops whose sums may be reordered (the derivatives' Cholesky factor, inverse and
#: checks): LLVM vectorises a sum only where it may reassociate it (``reassoc``) and fuses a
#: product into its sum (``contract``, one rounding less). No other fast-math flag: NaN and
#: infinity keep their IEEE meaning (``x * 0`` is not folded to 0; the finiteness checks
#: rely on it). Rounding differs from the loops' order by a few units in the last place.
#: Called (not inlined) from the passes, as :data:`jit_pass` functions are compiled.
jit_sums = cached_njit(fastmath={"reassoc", "contract"}, error_model="numpy", _nrt=False)


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
        cf._cache = _TreeCache(cf._pyfunc)  # what enable_caching() sets, with qchain's stamp
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


# ------------------------------------------------------------------------- array views


def _view_codegen(context, builder, sig, args):
    """A C-ordered array of the shape ``args[1:]`` over the data of the 1-D array ``args[0]``;
    a size that differs raises ``ValueError`` where numba's ``reshape`` would (a carving that
    does not fit is a bug, and must stop rather than address memory past the buffer)."""
    ary = make_array(sig.args[0])(context, builder, args[0])
    out = make_array(sig.return_type)(context, builder)
    dims = [context.cast(builder, v, t, types.intp) for v, t in zip(args[1:], sig.args[1:])]
    size = dims[0]
    for d in dims[1:]:
        size = builder.mul(size, d)
    nitems = cgutils.unpack_tuple(builder, ary.shape, 1)[0]
    with builder.if_then(builder.icmp_signed("!=", size, nitems), likely=False):
        context.call_conv.return_user_exc(builder, ValueError, ("the buffer does not hold the view's entries",))
    strides = [ary.itemsize]
    for d in reversed(dims[1:]):
        strides.insert(0, builder.mul(strides[0], d))
    populate_array(out, data=ary.data, shape=cgutils.pack_array(builder, dims),
                   strides=cgutils.pack_array(builder, strides), itemsize=ary.itemsize, meminfo=ary.meminfo)
    return impl_ret_borrowed(context, builder, sig.return_type, out._getvalue())


def _flat(x) -> bool:
    return isinstance(x, types.Array) and x.ndim == 1 and x.layout == "C"


@intrinsic
def view2(typingctx, x, a, b):
    """``x.reshape((a, b))`` for a 1-D C-contiguous ``x`` of ``a * b`` entries (``ValueError``
    otherwise), in compiled code only: the same view, built inline."""
    if _flat(x):
        return types.Array(x.dtype, 2, "C")(x, a, b), _view_codegen


@intrinsic
def view3(typingctx, x, a, b, c):
    """``x.reshape((a, b, c))``, as :func:`view2`."""
    if _flat(x):
        return types.Array(x.dtype, 3, "C")(x, a, b, c), _view_codegen


@intrinsic
def view4(typingctx, x, a, b, c, d):
    """``x.reshape((a, b, c, d))``, as :func:`view2`."""
    if _flat(x):
        return types.Array(x.dtype, 4, "C")(x, a, b, c, d), _view_codegen
