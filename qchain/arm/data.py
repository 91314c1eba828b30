"""Per-evaluation workspace of a chain, in the manner of Pinocchio's ``Data``.

A :class:`~qchain.Chain` is the model: its parameters are never changed by an algorithm.
Everything a pass writes lives in a :class:`Data`, made once by ``chain.create_data()`` and
handed to the passes, so a loop of calls (an integrator, a batch, a controller) allocates no
arrays. One ``Data`` serves one evaluation at a time (one per thread).

Arrays (``n`` segments, ``nv`` velocities, ``nu = 3 n`` pressures; frames: ``root j`` is the
root frame of segment ``j``, ``root 0`` the base; ``[linear; angular]``; SI units):

===================  =================  =================================================
``a_c``              (n, 3)             segment accelerations in curvature coordinates ``(l, ux, uy)``
``f``                (n, 3)             internal plus external generalised force on ``q_c``
``V, A``             (n + 1, 6)         root twists (m/s, rad/s) and apparent accelerations
                                        (gravity included) in their own frames
``R_0j, p_0j``       (n + 1, 3, 3/3)    root placements in root 0 (m)
``T``                (n, 6, 9)          tip maps ``Phi_j(1)``: next root's twist per ``xi_j``
``c``                (n, 6)             tip bias accelerations
``M_xi, Q``          (n, 9, 9), (n, 9)  segment blocks and slice Newton-Euler forces
``QqT, QxT``         (n, 3, 9), (n, 9, 9)  their derivatives by ``q_j`` and ``xi_j`` (first index)
``rel1``             (n, 6)             each tip's twist relative to its root, ``S_j(1) qdot_j``
``tipV, tipA``       (n, 6, 6)          variations of the next root's twist, acceleration
``dS1``              (n, 3, 6, 3)       ``dS_j(1)/dq``
``G``                (6, 9n)            per-column wrench variations (root 0): blocks of 3n
                                        columns for ``q``, ``qd`` and ``qdd`` (the composite
                                        columns of ``M``)
``S``                (12, 6n)           per-column twist variations ``(sigma2, sigma1)`` (root
                                        0), blocks for ``q`` and ``qd``
``Y, Jw``            (3n, 12), (3n, 6)  subtree sensitivities ``(Ya, Yv)``, tip Jacobians (root 0)
``P1, P2``           (3n, 6n), (3n, 9n) the products ``Y S`` and ``Jw G`` the blocks between
                                        segments are taken from
``Lq, U, u``         (n, 3, 3), (n, 6, 3), (n, 3)  articulated-body factors
``scratch``          (SCRATCH,)         small temporaries of the passes (``qchain.model.arc.SCRATCH``)
``pT, pc, pb, pM``   (n, 3, 5), (n, 3), the planar kernel's tip maps, biases, segment forces
                     (n, 5), (n, 5, 5)  and blocks (:mod:`qchain.algorithms.planar`, planar chains)
``pDinv, pU, pu``    (n, 2, 2), (n, 3, 2), (n, 2)  its articulated factors
``pscratch``         (SCRATCH,)         its scratch
``tau_c, F0``        (n, 3), (6,)       inverse dynamics: segment forces and the base wrench
                                        (N, N m)
``A0``               (6,)               the base's apparent acceleration
``a``                (nv,)              forward dynamics (m/s^2, rad/s^2, ...)
``M, L``             (nv, nv)           mass matrix; the inverse of its Cholesky factor (free
                                        block), then ``da_dp`` transposed
``dtau_dq, dtau_dv`` (nv, nv)           inverse-dynamics derivatives (after the forward
                                        dynamics' derivatives ``dtau_dv`` holds the right-hand
                                        side ``df/dv - dID/dv``)
``da_dq, da_dv``     (nv, nv)           forward-dynamics derivatives
``da_dtau``          (nv, nv)           ``M^-1``
``da_dp``            (nv, nu)           per pascal
``dfq, dfv, B``      (n, 3, 3)          internal-force derivatives and input matrices
``kernel_buffer``    (size,)            the arrays of the compiled passes, one after another
``kernel_layout``    (K + 1, 5) int64   where each lies in it (:mod:`qchain.algorithms.layout`)
===================  =================  =================================================
"""

from __future__ import annotations

import numpy as np

from ..algorithms.arrays import AbaDerivativesWorkspace, AbaWorkspace, PlanarWorkspace, RneaWorkspace
from ..algorithms.layout import kernel_layout, kernel_views

__all__ = ["Data"]


# the compiled passes' workspace arrays, in the order they lie in one buffer
# (qchain.algorithms.layout): one name each
_KERNEL_FIELDS = (AbaWorkspace._fields + RneaWorkspace._fields + AbaDerivativesWorkspace._fields
                  + PlanarWorkspace._fields)
_KERNEL_NAMES = frozenset(_KERNEL_FIELDS) | {"kernel_buffer", "kernel_layout"}


class Data:
    """Workspace of one chain of ``n`` segments and ``nv`` velocities (``chain.create_data()``);
    see the module docstring for every array. The arrays are views of one zeroed buffer
    (``kernel_buffer`` (size,), laid out by ``kernel_layout`` (K + 1, 5) int64,
    :func:`qchain.algorithms.layout.kernel_layout`), allocated on the first use of any of
    them (``np.zeros``: a large buffer's pages that no call writes are not touched)."""

    def __init__(self, n: int, nv: int):
        from ..checks.bounds import SEGMENT_COUNT

        n = SEGMENT_COUNT.check("n", n)
        if isinstance(nv, (bool, np.bool_)) or not isinstance(nv, (int, np.integer)) or int(nv) not in (3 * n, 3 * n + 6):
            raise ValueError(f"nv must be 3 n = {3 * n} (a fixed or prescribed base) or 3 n + 6 = {3 * n + 6} (a "
                             f"floating base), got {nv!r}")
        object.__setattr__(self, "n", n)
        object.__setattr__(self, "nv", int(nv))

    def __setattr__(self, name: str, value) -> None:
        # the compiled passes write into the arrays at the sizes checked against n and nv:
        # a size changed or an array replaced would let them write outside it
        raise AttributeError(f"Data.{name} cannot be set: a workspace's sizes and arrays are made by "
                             "chain.create_data() (make a new one)")

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        if name in _KERNEL_NAMES:
            # every workspace array at once, in one zeroed buffer (np.zeros: a large buffer's
            # pages no pass writes are not touched), so that a compiled call can take the
            # buffer and its table and carve them (qchain.algorithms.arrays) instead of
            # unboxing each array
            table = kernel_layout(self.n, self.nv)
            buf = np.zeros(table[-1, 0])
            d = self.__dict__
            d["kernel_buffer"], d["kernel_layout"] = buf, table
            for k, x in zip(_KERNEL_FIELDS, kernel_views(buf, table)):
                d[k] = x
            return d[name]
        raise AttributeError(f"Data has no array {name!r}")

    def aba_workspace(self) -> AbaWorkspace:
        """The arrays :func:`qchain.algorithms.recursive.aba`, ``rnea`` and ``crba`` work in, by name."""
        return self._tuple("_ws", AbaWorkspace)

    def rnea_workspace(self) -> RneaWorkspace:
        """The arrays :func:`qchain.algorithms.rnea_derivatives.rnea_derivatives` works in, by name."""
        return self._tuple("_wd", RneaWorkspace)

    def aba_derivatives_workspace(self) -> AbaDerivativesWorkspace:
        """The arrays :func:`qchain.algorithms.aba_derivatives.aba_derivatives` writes, by name."""
        return self._tuple("_wa", AbaDerivativesWorkspace)

    def planar_workspace(self) -> PlanarWorkspace:
        """The arrays :func:`qchain.algorithms.planar.planar_aba` works in, by name."""
        return self._tuple("_wp", PlanarWorkspace)

    def _tuple(self, key: str, kind: type):
        t = self.__dict__.get(key)
        if t is None:
            t = self.__dict__[key] = kind(*(getattr(self, k) for k in kind._fields))
        return t

    def __repr__(self) -> str:
        return f"Data(n={self.n}, nv={self.nv})"
