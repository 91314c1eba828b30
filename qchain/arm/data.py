"""Per-evaluation workspace of a chain, in the manner of Pinocchio's ``Data``.

A :class:`~qchain.Chain` is the model: its parameters are never changed by an algorithm.
Everything a pass writes lives in a :class:`Data`, made once by ``chain.create_data()`` and
handed to the passes, so a loop of calls (an integrator, a batch, a controller) allocates no
arrays. One ``Data`` serves one evaluation at a time (one per thread).

Arrays (``n`` segments, ``nv`` velocities, ``nu = 3 n`` pressures; frames: ``root j`` is the
root frame of segment ``j``, ``root 0`` the base; ``[linear; angular]``; SI units):

===================  =================  =================================================
``q_c, v_c, a_c``    (n, 3)             segment state in curvature coordinates ``(l, ux, uy)``
``p``                (n, 3)             chamber pressures (Pa)
``f``                (n, 3)             internal plus external generalised force on ``q_c``
``V, A``             (n + 1, 6)         root twists (m/s, rad/s) and apparent accelerations
                                        (gravity included) in their own frames
``R_0j, p_0j``       (n + 1, 3, 3/3)    root placements in root 0 (m)
``T``                (n, 6, 9)          tip maps ``Phi_j(1)``: next root's twist per ``xi_j``
``c``                (n, 6)             tip bias accelerations
``M_xi, Q``          (n, 9, 9), (n, 9)  segment blocks and slice Newton-Euler forces
``QqT, QxT``         (n, 3, 9), (n, 9, 9)  their derivatives by ``q_j`` and ``xi_j`` (first index)
``tipV, tipA``       (n, 6, 6)          variations of the next root's twist, acceleration
``dS1``              (n, 3, 6, 3)       ``dS_j(1)/dq``
``G, sig1, sig2``    (6, 2, 3n)         per-column wrench and twist variations (root 0;
                                        ``[:, 0]`` configuration, ``[:, 1]`` rate columns)
``Ms``               (6, 1, 3n)         composite columns of ``M`` (root 0)
``Ya, Yv, Jw``       (n, 3, 6)          subtree sensitivities, tip Jacobians (root 0)
``Lq, U, u``         (n, 3, 3), (n, 6, 3), (n, 3)  articulated-body factors
``scratch``          (SCRATCH,)         small temporaries of the passes (``qchain.model.arc.SCRATCH``)
``pT, pc, pb, pM``   (n, 3, 5), (n, 3), the planar kernel's tip maps, biases, segment forces
                     (n, 5), (n, 5, 5)  and blocks (:mod:`qchain.algorithms.planar`, planar chains)
``pDinv, pU, pu``    (n, 2, 2), (n, 3, 2), (n, 2)  its articulated factors; ``pscratch``
``tau``              (nv,)              inverse dynamics (N, N m)
``a``                (nv,)              forward dynamics (m/s^2, rad/s^2, ...)
``M, L``             (nv, nv)           mass matrix; the inverse of its Cholesky factor (free
                                        block), then the right-hand sides of ``da_dv``
``rhs``              (nv, nv)           right-hand sides of ``da_dq``
``dtau_dq, dtau_dv`` (nv, nv)           inverse-dynamics derivatives
``da_dq, da_dv``     (nv, nv)           forward-dynamics derivatives
``da_dtau``          (nv, nv)           ``M^-1``
``da_dp``            (nv, nu)           per pascal
``dfq, dfv, B``      (n, 3, 3)          internal-force derivatives and input matrices
===================  =================  =================================================
"""

from __future__ import annotations

import numpy as np

from ..algorithms import aba_derivatives, planar, recursive, rnea_derivatives
from ..algorithms.arrays import AbaDerivativesWorkspace, AbaWorkspace, PlanarWorkspace, RneaWorkspace

__all__ = ["Data"]


# (allocator, names): a group's arrays are made by one compiled allocator, which the
# compiled passes also call when no Data is given, so shapes are defined once; the names are
# the fields of the group's workspace (qchain.algorithms.arrays)
_GROUPS = {
    "aba": (recursive.aba_workspace, AbaWorkspace._fields),
    "rnea_derivatives": (rnea_derivatives.rnea_workspace, RneaWorkspace._fields),
    "aba_derivatives": (aba_derivatives.aba_derivatives_workspace, AbaDerivativesWorkspace._fields),
    "planar": (lambda n, nv: planar.planar_workspace(n), PlanarWorkspace._fields),
}


class Data:
    """Workspace of one chain of ``n`` segments and ``nv`` velocities (``chain.create_data()``);
    see the module docstring for every array. Arrays are allocated group by group on first
    use, so a workspace made for one call costs only what that call writes."""

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
        for make, names in _GROUPS.values():
            if name in names:
                for k, x in zip(names, make(self.n, self.nv)):
                    self.__dict__[k] = x
                return self.__dict__[name]
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
