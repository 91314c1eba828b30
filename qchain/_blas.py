"""BLAS's matrix product (``dgemm``) called from compiled code.

The exact derivatives multiply ``M^-1`` (nv, nv) into two (nv, nv) right-hand sides
(:mod:`qchain.algorithms.aba_derivatives`). scipy's OpenBLAS does that several times faster
than the loops numba compiles (figures in docs/benchmarks/README.md, "Cost of the
derivatives"), so it is called here, through scipy's public ``scipy.linalg.cython_blas``
table, without numba's reference counting and without Python's lock.

The library's function is registered with LLVM by name when this module is imported
(``llvmlite.binding.add_symbol``) and compiled code calls it by that name: numba's on-disk
cache then holds the name, not an address, and a later process links it to that process's
library (a ctypes pointer would be written into the cached machine code as a number).
Everything that calls :func:`gemm` imports this module first, so the name is known before any
cached code is loaded.

LAPACK's Cholesky factorisation and inverse (``dpotrf``, ``dpotri``) were measured as well:
at these sizes they are slower than the hand-written ones of
:mod:`qchain.algorithms.recursive` and :mod:`qchain.algorithms.aba_derivatives`, which stay.
"""

from __future__ import annotations

import llvmlite.binding as llvm
import numpy as np
from numba import types
from numba.core import cgutils
from numba.core.errors import TypingError
from numba.extending import get_cython_function_address, intrinsic, register_jitable

__all__ = ["gemm", "SINGLE_THREAD_MNK"]

_SYMBOL = "qchain_cython_blas_dgemm"
llvm.add_symbol(_SYMBOL, get_cython_function_address("scipy.linalg.cython_blas", "dgemm"))
#: ``dgemm(transa, transb, m, n, k, alpha, a, lda, b, ldb, beta, c, ldc)``, every argument by
#: pointer (Fortran's convention; scipy's table adds the hidden lengths of the two characters)
_dgemm = types.ExternalFunction(_SYMBOL, types.void(*([types.voidptr] * 13)))

_NO_TRANSPOSE = np.uint8(ord("N"))


@intrinsic
def _on_stack(typingctx, x):
    """A pointer to a copy of the scalar ``x`` in the calling function's stack frame."""

    def codegen(context, builder, signature, args):
        return builder.bitcast(cgutils.alloca_once_value(builder, args[0]), cgutils.voidptr_t)

    return types.voidptr(x), codegen


@intrinsic
def _at(typingctx, a, i):
    """The address of entry ``i`` (a flat index) of a C-ordered float64 array."""
    if not (isinstance(a, types.Array) and a.dtype == types.float64 and a.layout == "C"):
        raise TypingError(f"qchain._blas needs C-ordered float64 arrays, got {a}")

    def codegen(context, builder, signature, args):
        ary = cgutils.create_struct_proxy(signature.args[0])(context, builder, value=args[0])
        return builder.bitcast(builder.gep(ary.data, [args[1]]), cgutils.voidptr_t)

    return types.voidptr(a, types.intp), codegen


#: OpenBLAS runs one product on threads of its own where ``m n k`` exceeds this
#: (``SMP_THRESHOLD_MIN * GEMM_MULTITHREAD_THRESHOLD``): :func:`gemm` calls it on blocks below
#: it, so the library never starts its threads from qchain's (a product on two busy cores was
#: several times slower than on one, and a batch already runs a thread a core)
SINGLE_THREAD_MNK = 65536 * 4


@register_jitable
def gemm(A, B, C):
    """``C = A B`` (compiled code only) for C-ordered float64 ``A`` (m, k), ``B`` (k, n),
    ``C`` (m, n); ``C`` must not overlap ``A`` or ``B``. The sizes are not checked: the callers
    pass workspace arrays of matching shapes.

    BLAS stores matrices by columns, where a C-ordered ``X`` reads as ``X^T``: it is asked for
    ``C^T = B^T A^T``, on square blocks of ``C`` each within :data:`SINGLE_THREAD_MNK`.
    """
    m, k = A.shape
    n = B.shape[1]
    side = max(1, int(np.sqrt(SINGLE_THREAD_MNK / max(k, 1))))
    ki, ldk, ldn = np.int32(k), np.int32(max(k, 1)), np.int32(max(n, 1))
    for r0 in range(0, m, side):
        mb = np.int32(min(side, m - r0))
        for c0 in range(0, n, side):
            nb = np.int32(min(side, n - c0))
            _dgemm(_on_stack(_NO_TRANSPOSE), _on_stack(_NO_TRANSPOSE), _on_stack(nb), _on_stack(mb), _on_stack(ki),
                   _on_stack(1.0), _at(B, c0), _on_stack(ldn), _at(A, r0 * k), _on_stack(ldk), _on_stack(0.0),
                   _at(C, r0 * n + c0), _on_stack(ldn))
