"""The named structures the compiled passes take, each a ``typing.NamedTuple`` (numba compiles
them with attribute access, at no run-time cost).

:class:`ChainArrays`: the model's per-node and per-segment arrays, every pass's first argument.
Declared once: :class:`qchain.Chain` builds it, every pass of :mod:`qchain.algorithms` reads it,
and the engine's model (``qchain.sim.engine.system``) holds it.

The workspaces, made by the passes' allocators (``recursive.aba_workspace``,
``rnea_derivatives.rnea_workspace``, ``aba_derivatives.aba_derivatives_workspace``,
``planar.planar_workspace``), by :class:`qchain.arm.data.Data` (whose attributes bear the
fields' names) or carved from the engine's buffer: :class:`AbaWorkspace`,
:class:`RneaWorkspace`, :class:`AbaDerivativesWorkspace`, :class:`PlanarWorkspace`. The arrays'
shapes are in :mod:`qchain.arm.data`'s docstring and in the allocators.

A pass takes each structure either named or as the plain tuple of its fields, and names it on
entry (``arr = ChainArrays(*arr)``, free in compiled code). Python callers pass the plain
tuple: numba's dispatcher types a tuple of arrays in C but a NamedTuple field by field in
Python, about a microsecond a call for ``ChainArrays`` (``benchmarks/bench_chain.py`` is the
figure that would show it). Compiled callers (the engine) pass the named structures.

The four workspaces can also lie in one flat buffer, the arrays one after another in the
order of their fields (:data:`KERNEL_NDIM`; offsets and shapes in a layout table,
:func:`qchain.algorithms.layout.kernel_layout`). :func:`carve_aba` and its siblings give them
back as views in compiled code: one buffer and one table cross from Python instead of dozens
of arrays (each array a call unboxes costs about 70 ns). The engine's workspace and
:class:`qchain.arm.data.Data` hold them so."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .._jit import jit_inline, view2, view3, view4

__all__ = ["ChainArrays", "AbaWorkspace", "RneaWorkspace", "AbaDerivativesWorkspace", "PlanarWorkspace",
           "KERNEL_NDIM", "carve_aba", "carve_rnea", "carve_aba_derivatives", "carve_planar"]


class ChainArrays(NamedTuple):
    """A chain's model arrays (never written by a pass); ``N`` nodes over all segments, ``n``
    segments.

    Attributes
    ----------
    alpha : (N,) float
        The nodes' arc parameters in [0, 1].
    w : (N,) float
        Their quadrature weights (sum 1 a segment).
    offs : (n + 1,) int64
        Segment ``j``'s nodes are ``offs[j]:offs[j + 1]``.
    mass, radius, l0 : (n,) float
        Segment mass (kg), radius (m), rest length (m).
    EI, EA : (n,) float
        Bending (N m^2) and axial (N) stiffness.
    beta : (n,) float
        Stiffness-proportional damping (s).
    A_ch, r_ch : (n,) float
        Chamber area (m^2) and the chambers' distance from the axis (m).
    paper_act : (n,) bool
        The paper's actuation law.
    locked : (n, 3) bool
        Coordinates held still (``planar``, inextensible segments).
    payload : (6, 6) float
        Spatial inertia of a rigid payload fixed at the tip (root ``n``), in the tip frame,
        Pinocchio's ``[linear; angular]`` convention (``pinocchio.Inertia.matrix()``):
        ``[[m 1, -m [c]], [m [c], I_c - m [c][c]]]`` (kg, kg m, kg m^2). All zeros: no payload.
    D : (n, 3, 3) float
        Each segment's dissipation matrix in its curvature coordinates, constant (N s/m, N m s,
        N m^3 s: ``D qdot`` is a generalised force): the stiffness-proportional ``beta K(q0)``
        (:func:`qchain.model.slices.rest_damping_c`), ``beta K_e`` of the linear law, or the
        segment's ``damping_matrix`` (docs/model.md section 9).
    K : (n, 3, 3) float
        The linear law's stiffness ``K_e`` where ``linear_law``, zeros elsewhere.
    q_rest : (n, 3) float
        The linear law's rest configuration ``q_e0`` where ``linear_law`` (m, 1/m, 1/m).
    linear_law : (n,) bool
        The segment's elasticity is the linear law ``U_el = 1/2 (q - q_e0)^T K_e (q - q_e0)``
        (its ``stiffness_matrix``), not the material law of ``EI``, ``EA``.
    drag : (n, 2) float
        The drag of a still medium on the backbone, ``c_1`` (N s/m^2) and ``c_2`` (kg/m^2) of
        the force per unit length ``-(c_1 + c_2 |v|) v`` (:mod:`qchain.contact.drag`).
    """

    alpha: np.ndarray
    w: np.ndarray
    offs: np.ndarray
    mass: np.ndarray
    radius: np.ndarray
    l0: np.ndarray
    EI: np.ndarray
    EA: np.ndarray
    beta: np.ndarray
    A_ch: np.ndarray
    r_ch: np.ndarray
    paper_act: np.ndarray
    locked: np.ndarray
    payload: np.ndarray
    D: np.ndarray
    K: np.ndarray
    q_rest: np.ndarray
    linear_law: np.ndarray
    drag: np.ndarray


class AbaWorkspace(NamedTuple):
    """What :func:`~qchain.algorithms.recursive.aba`, ``rnea`` and ``crba`` write: root twists
    ``V``, tip maps ``T``, tip biases ``c``, segment forces ``Q``, segment blocks ``M_xi``, the
    articulated factors ``Lq`` (after ``aba``: the inverse of each segment's 3 x 3 articulated
    block), ``U, u`` and the ``scratch`` the passes carve small temporaries from."""

    V: np.ndarray
    T: np.ndarray
    c: np.ndarray
    Q: np.ndarray
    M_xi: np.ndarray
    Lq: np.ndarray
    U: np.ndarray
    u: np.ndarray
    scratch: np.ndarray


class RneaWorkspace(NamedTuple):
    """What :func:`~qchain.algorithms.rnea_derivatives.rnea_derivatives` writes: its
    intermediate arrays, then its outputs ``tau_c`` (n, 3), ``F0`` (6,), ``M``, ``dtau_dq``,
    ``dtau_dv`` (nv, nv)."""

    A: np.ndarray
    R_0j: np.ndarray
    p_0j: np.ndarray
    QqT: np.ndarray
    QxT: np.ndarray
    rel1: np.ndarray
    tipV: np.ndarray
    tipA: np.ndarray
    dS1: np.ndarray
    G: np.ndarray
    Y: np.ndarray
    Jw: np.ndarray
    S: np.ndarray
    P1: np.ndarray
    P2: np.ndarray
    tau_c: np.ndarray
    F0: np.ndarray
    M: np.ndarray
    dtau_dq: np.ndarray
    dtau_dv: np.ndarray


class AbaDerivativesWorkspace(NamedTuple):
    """What :func:`~qchain.algorithms.aba_derivatives.aba_derivatives` writes: the forces
    ``f``, the accelerations ``a_c`` (n, 3), ``A0`` (6,), ``a`` (nv,), the factor ``L``, the
    derivatives ``da_dq, da_dv, da_dtau, da_dp`` and the per-segment ``dfq, dfv, B``."""

    f: np.ndarray
    a_c: np.ndarray
    A0: np.ndarray
    a: np.ndarray
    L: np.ndarray
    da_dq: np.ndarray
    da_dv: np.ndarray
    da_dtau: np.ndarray
    da_dp: np.ndarray
    dfq: np.ndarray
    dfv: np.ndarray
    B: np.ndarray


class PlanarWorkspace(NamedTuple):
    """What :func:`~qchain.algorithms.planar.planar_aba` writes: tip maps ``pT``, tip biases
    ``pc``, segment forces ``pb``, segment blocks ``pM``, the articulated factors ``pDinv, pU,
    pu`` and the scratch ``pscratch``."""

    pT: np.ndarray
    pc: np.ndarray
    pb: np.ndarray
    pM: np.ndarray
    pDinv: np.ndarray
    pU: np.ndarray
    pu: np.ndarray
    pscratch: np.ndarray


#: The number of dimensions of each workspace array, in the order of the buffer: the aba,
#: rnea-derivative, aba-derivative and planar workspaces' fields (the carving code's types;
#: their shapes come from the allocators, ``tests/test_engine.py`` checks the two agree).
KERNEL_NDIM = ((2, 3, 2, 2, 3, 3, 3, 2, 1),
               (2, 3, 2, 3, 3, 2, 3, 3, 4, 2, 2, 2, 2, 2, 2, 2, 1, 2, 2, 2),
               (2, 2, 1, 1, 2, 2, 2, 2, 2, 3, 3, 3),
               (3, 2, 2, 3, 3, 3, 2, 1))


# where each workspace's first array is in the layout table (compile-time constants)
_RNEA = len(AbaWorkspace._fields)
_ABA_DERIVATIVES = _RNEA + len(RneaWorkspace._fields)
_PLANAR = _ABA_DERIVATIVES + len(AbaDerivativesWorkspace._fields)


@jit_inline
def _v1(buf, tb, i):
    """Array ``i`` of the layout table ``tb`` (``(K + 1, 5)``: offset, shape) as a view of ``buf``."""
    o = tb[i, 0]
    return buf[o : o + tb[i, 1]]


@jit_inline
def _v2(buf, tb, i):
    o = tb[i, 0]
    return view2(buf[o : o + tb[i, 1] * tb[i, 2]], tb[i, 1], tb[i, 2])


@jit_inline
def _v3(buf, tb, i):
    o = tb[i, 0]
    return view3(buf[o : o + tb[i, 1] * tb[i, 2] * tb[i, 3]], tb[i, 1], tb[i, 2], tb[i, 3])


@jit_inline
def _v4(buf, tb, i):
    o = tb[i, 0]
    return view4(buf[o : o + tb[i, 1] * tb[i, 2] * tb[i, 3] * tb[i, 4]], tb[i, 1], tb[i, 2], tb[i, 3], tb[i, 4])


@jit_inline
def carve_aba(buf, tb):
    """The :class:`AbaWorkspace` in the flat buffer ``buf`` by its layout table ``tb``."""
    return AbaWorkspace(_v2(buf, tb, 0), _v3(buf, tb, 1), _v2(buf, tb, 2), _v2(buf, tb, 3), _v3(buf, tb, 4),
                        _v3(buf, tb, 5), _v3(buf, tb, 6), _v2(buf, tb, 7), _v1(buf, tb, 8))


@jit_inline
def carve_rnea(buf, tb):
    """The :class:`RneaWorkspace` in ``buf``, as :func:`carve_aba`."""
    b, t, i = buf, tb, _RNEA
    return RneaWorkspace(_v2(b, t, i), _v3(b, t, i + 1), _v2(b, t, i + 2), _v3(b, t, i + 3), _v3(b, t, i + 4),
                         _v2(b, t, i + 5), _v3(b, t, i + 6), _v3(b, t, i + 7), _v4(b, t, i + 8), _v2(b, t, i + 9),
                         _v2(b, t, i + 10), _v2(b, t, i + 11), _v2(b, t, i + 12), _v2(b, t, i + 13), _v2(b, t, i + 14),
                         _v2(b, t, i + 15), _v1(b, t, i + 16), _v2(b, t, i + 17), _v2(b, t, i + 18), _v2(b, t, i + 19))


@jit_inline
def carve_aba_derivatives(buf, tb):
    """The :class:`AbaDerivativesWorkspace` in ``buf``, as :func:`carve_aba`."""
    b, t, i = buf, tb, _ABA_DERIVATIVES
    return AbaDerivativesWorkspace(_v2(b, t, i), _v2(b, t, i + 1), _v1(b, t, i + 2), _v1(b, t, i + 3), _v2(b, t, i + 4),
                                   _v2(b, t, i + 5), _v2(b, t, i + 6), _v2(b, t, i + 7), _v2(b, t, i + 8),
                                   _v3(b, t, i + 9), _v3(b, t, i + 10), _v3(b, t, i + 11))


@jit_inline
def carve_planar(buf, tb):
    """The :class:`PlanarWorkspace` in ``buf``, as :func:`carve_aba`."""
    b, t, i = buf, tb, _PLANAR
    return PlanarWorkspace(_v3(b, t, i), _v2(b, t, i + 1), _v2(b, t, i + 2), _v3(b, t, i + 3), _v3(b, t, i + 4),
                           _v3(b, t, i + 5), _v2(b, t, i + 6), _v1(b, t, i + 7))
