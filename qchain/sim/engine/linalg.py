"""Small dense LU factorisation for the implicit steppers (compiled, in place, no allocation).

numba has ``np.linalg.solve`` but no factorisation to keep: the implicit methods factor
their Newton matrix once and reuse it over many solves and steps, real and complex.
Partial pivoting; the same code serves float64 and complex128 matrices.

Unchecked by design: compiled kernels whose arguments the checked API has validated
(``docs/engine.md``, "Unchecked kernels"); call the checked API unless you guarantee them.
"""

from __future__ import annotations

import numpy as np

from ..._jit import ejit

__all__ = ["lu_factor", "lu_solve"]


@ejit
def lu_factor(A, piv):
    """``A`` (k, k) overwritten by its LU factors (unit lower, upper) with row pivots ``piv``
    (k,) int64. Returns False if a pivot is zero or not finite (a singular matrix)."""
    k = A.shape[0]
    for j in range(k):
        p = j
        best = abs(A[j, j])
        for i in range(j + 1, k):
            a = abs(A[i, j])
            if a > best:
                best = a
                p = i
        piv[j] = p
        if not (best > 0.0 and np.isfinite(best)):
            return False
        if p != j:
            for c in range(k):
                tmp = A[j, c]
                A[j, c] = A[p, c]
                A[p, c] = tmp
        inv = 1.0 / A[j, j]
        for i in range(j + 1, k):
            A[i, j] *= inv
            lij = A[i, j]
            if lij != 0.0:
                for c in range(j + 1, k):
                    A[i, c] -= lij * A[j, c]
    return True


@ejit
def lu_solve(LU, piv, b):
    """Solve ``A x = b`` in place (``b`` (k,)) with the factors of :func:`lu_factor`."""
    k = LU.shape[0]
    for j in range(k):
        p = piv[j]
        if p != j:
            tmp = b[j]
            b[j] = b[p]
            b[p] = tmp
    for i in range(k):
        acc = b[i]
        for s in range(i):
            acc -= LU[i, s] * b[s]
        b[i] = acc
    for i in range(k - 1, -1, -1):
        acc = b[i]
        for s in range(i + 1, k):
            acc -= LU[i, s] * b[s]
        b[i] = acc / LU[i, i]
