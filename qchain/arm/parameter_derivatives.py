"""Exact derivatives of a chain's dynamics with respect to its parameters, checked.

:class:`Parameters` names a set ``theta`` of a chain's parameters (a column each, with its
unit); :func:`forward_dynamics_parameter_derivatives` returns ``da/dtheta`` (nv, n_theta) of
the whole equation of motion and :func:`inverse_dynamics_parameter_derivatives` ``dtau/dtheta``
of Pinocchio's inverse dynamics ``M a + C v + g``; :class:`ChainParameters` gives
:class:`~qchain.Chain` the same as methods. The compiled pass is
:mod:`qchain.algorithms.parameter_derivatives` (its docstring and docs/derivatives.md,
"Parameter derivatives", give the formulas); this module checks the input and maps the
curvature-coordinate results to the chain's coordinates (the paper's ``(l, psi, kappa)``:
``da_e = J^-1 da_c`` and ``dtau_e = J^T dtau_c`` segment by segment, as ``J`` does not depend on
any parameter).

Parameters, per segment ``j`` (``("kind", j)``) or for the whole arm (``("kind", None)``):

==================  ==========  =======================================================
``youngs_modulus``  Pa          ``E``: ``EI = E pi r^4/4`` and ``EA = E pi r^2`` together
``damping``         s           ``beta`` of the rest damping ``D = beta K(q0)``
``mass``            kg          the segment's mass (its density scaled: slice inertias
                                and weight linear in it)
``length``          m           the rest length ``l0`` (the elastic law and ``K(q0)``; an
                                inextensible segment's held length too)
``chamber_area``    m^2         ``A_ch``, the input gain (``B`` linear in it)
``gravity``         m/s^2       world gravity: ``("gravity", axis)`` one column,
                                ``("gravity", None)`` three (x, y, z)
``base_placement``  m, rad      a fixed base's ``X_WB exp6(delta)``, ``delta`` 6 columns:
                                translation x, y, z then rotation x, y, z, base frame
==================  ==========  =======================================================
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ..algorithms import aba_derivatives
from ..algorithms import parameter_derivatives as _pd
from ..model.segment import _paper_jacobian_dot as paper_jacobian_dot
from ..checks.convert import describe_value
from ..contact.forces import RECORD, contact_forces
from ..model.arc import SCRATCH
from .contact import _moved, _self_contact_work

if TYPE_CHECKING:
    from .chain import Chain
    from .data import Data

__all__ = ["Parameters", "ParameterDerivatives", "InverseParameterDerivatives", "PARAMETER_KINDS",
           "forward_dynamics_parameter_derivatives", "inverse_dynamics_parameter_derivatives", "ChainParameters"]

#: kind -> (compiled kind, unit, per segment)
PARAMETER_KINDS = {
    "youngs_modulus": (_pd.KIND_YOUNGS, "Pa", True),
    "damping": (_pd.KIND_DAMPING, "s", True),
    "mass": (_pd.KIND_MASS, "kg", True),
    "length": (_pd.KIND_LENGTH, "m", True),
    "chamber_area": (_pd.KIND_AREA, "m^2", True),
    "gravity": (_pd.KIND_GRAVITY, "m/s^2", False),
    "base_placement": (_pd.KIND_BASE, None, False),
}
_SEGMENT_ATTR = {"youngs_modulus": "youngs_modulus", "damping": "damping", "mass": "mass", "length": "length",
                 "chamber_area": "chamber_area"}
_BASE_COLUMNS = (("translation x", "m"), ("translation y", "m"), ("translation z", "m"),
                 ("rotation x", "rad"), ("rotation y", "rad"), ("rotation z", "rad"))


class Parameters:
    """A named, checked set of a chain's parameters ``theta``, a column each.

    Parameters
    ----------
    chain : Chain
    params : sequence of (kind, segment) pairs
        ``kind`` one of :data:`PARAMETER_KINDS`; ``segment`` an int in ``[0, n)`` for the
        per-segment kinds; for ``gravity`` its axis (0, 1, 2: world x, y, z; one column) or
        None (its three columns, x, y, z: the same as naming the axes in turn); None for
        ``base_placement`` (6 columns, a fixed base only). :func:`qchain.sim.sensitivities`
        takes the same pairs.

    Attributes
    ----------
    names : tuple of str     ``"segment 0 youngs_modulus [Pa]"``, ``"gravity z [m/s^2]"``, ...
    units : tuple of str     each column's SI unit.
    values : (n_theta,)      the chain's values (a base placement's perturbation is 0).
    kinds, index : (n_theta,) int64   the compiled pass's encoding (a ``KIND_*`` of
                             :mod:`qchain.algorithms.parameter_derivatives` and its segment or
                             component), to pass to its compiled entries; never write them.
    """

    def __init__(self, chain: Chain, params):
        if not isinstance(chain, ChainParameters):  # (a Chain; its module imports this one)
            raise TypeError(f"chain must be a qchain.Chain, got {describe_value(chain)}")
        if isinstance(params, (str, bytes)) or not isinstance(params, Sequence):
            raise TypeError(f"params must be a list of (kind, segment) pairs, e.g. [('mass', 0), ('gravity', None)], "
                            f"got {describe_value(params)}")
        if len(params) == 0:
            raise ValueError("params must name at least one parameter, got an empty list")
        if chain._literal.any():
            j = int(np.flatnonzero(chain._literal)[0])
            raise ValueError(f"parameter derivatives need the material law in every segment; segments[{j}] has the "
                             "paper's literal linear law (stiffness_matrix or damping_matrix)")
        names, units, kinds, index, values, seen = [], [], [], [], [], set()
        for i, item in enumerate(params):
            if not (isinstance(item, tuple) and len(item) == 2):
                raise TypeError(f"params[{i}] must be a (kind, segment) pair, got {describe_value(item)}")
            kind, seg = item
            if not isinstance(kind, str) or kind not in PARAMETER_KINDS:
                raise ValueError(f"params[{i}]: unknown parameter {kind!r}; the parameters are "
                                 f"{tuple(PARAMETER_KINDS)}")
            code, unit, per_segment = PARAMETER_KINDS[kind]
            if per_segment:
                if isinstance(seg, bool) or not isinstance(seg, (int, np.integer)) or not 0 <= seg < chain.n:
                    raise ValueError(f"params[{i}]: {kind!r} is per segment, its segment must be an int in "
                                     f"[0, {chain.n - 1}] (the chain has {chain.n} segments), got {seg!r}")
                seg = int(seg)
            elif kind == "gravity" and seg is not None:
                if isinstance(seg, bool) or not isinstance(seg, (int, np.integer)) or not 0 <= seg <= 2:
                    raise ValueError(f"params[{i}]: the axis of 'gravity' must be None (all three) or an int in "
                                     f"[0, 2] (x, y, z), got {seg!r}")
                seg = int(seg)
            elif seg is not None:
                raise ValueError(f"params[{i}]: {kind!r} is a whole-arm parameter, its segment must be None, "
                                 f"got {seg!r}")
            # one column a (kind, segment or axis): gravity's None stands for its three axes
            cols = [(kind, k) for k in range(3)] if (kind == "gravity" and seg is None) else [(kind, seg)]
            twice = [c for c in cols if c in seen]
            if twice:
                raise ValueError(f"params[{i}]: ({kind!r}, {twice[0][1]!r}) is named twice")
            seen.update(cols)
            if per_segment:
                names.append(f"segment {seg} {kind} [{unit}]")
                units.append(unit)
                kinds.append(code)
                index.append(seg)
                values.append(float(getattr(chain.segments[seg], _SEGMENT_ATTR[kind])))
                continue
            if kind == "gravity":
                for k, axis in enumerate("xyz"):
                    if seg is not None and k != seg:
                        continue
                    names.append(f"gravity {axis} [{unit}]")
                    units.append(unit)
                    kinds.append(code)
                    index.append(k)
                    values.append(float(chain.gravity[k]))
            else:
                if chain.base != "fixed":
                    raise ValueError(f"params[{i}]: 'base_placement' is a fixed base's placement; this chain has "
                                     f"base={chain.base!r}")
                for k, (what, u) in enumerate(_BASE_COLUMNS):
                    names.append(f"base_placement {what} [{u}]")
                    units.append(u)
                    kinds.append(code)
                    index.append(k)
                    values.append(0.0)
        self.n, self.nv, self.base = chain.n, chain.nv, chain.base
        self.names, self.units = tuple(names), tuple(units)
        self.kinds = np.array(kinds, dtype=np.int64)
        self.index = np.array(index, dtype=np.int64)
        self.values = np.array(values)
        # values read-only; kinds and index writable (never write them): numba compiles a kernel
        # apart for read-only arrays, and the compiled entries take these two as they are
        self.values.flags.writeable = False
        self._has_base = bool(np.any(self.kinds == _pd.KIND_BASE))

    def __len__(self) -> int:
        return len(self.names)

    def __repr__(self) -> str:
        return f"Parameters({list(self.names)})"

    def _check(self, chain: Chain) -> None:
        if (self.n, self.nv, self.base) != (chain.n, chain.nv, chain.base):
            raise ValueError(f"params were made for a chain of {self.n} segments, nv = {self.nv}, base={self.base!r}; "
                             f"this chain has {chain.n}, nv = {chain.nv}, base={chain.base!r}")


def _parameters(chain: Chain, params) -> Parameters:
    if isinstance(params, Parameters):
        params._check(chain)
        return params
    return Parameters(chain, params)


class ParameterDerivatives(NamedTuple):
    """:func:`forward_dynamics_parameter_derivatives`.

    Attributes
    ----------
    a : (nv,)                  ``forward_dynamics(q, v, p, tau)``.
    da_dtheta : (nv, n_theta)  column ``k`` per unit of ``names[k]`` (its ``units[k]``).
    names : tuple of str
    units : tuple of str
    """

    a: np.ndarray
    da_dtheta: np.ndarray
    names: tuple
    units: tuple


class InverseParameterDerivatives(NamedTuple):
    """:func:`inverse_dynamics_parameter_derivatives`.

    Attributes
    ----------
    tau : (nv,)                  ``inverse_dynamics(q, v, a)``.
    dtau_dtheta : (nv, n_theta)  column ``k`` per unit of ``names[k]``.
    names, units : tuple of str
    """

    tau: np.ndarray
    dtau_dtheta: np.ndarray
    names: tuple
    units: tuple


def _youngs(chain: Chain) -> np.ndarray:
    return np.array([s.youngs_modulus for s in chain.segments], dtype=float)


def _to_paper_rows(chain: Chain, st, X: np.ndarray) -> np.ndarray:
    """Rows of segment coordinates mapped from curvature to the chain's: ``J_j^-1`` (paper segments)."""
    if st.J is None:
        return X
    X = X.copy()
    for j in np.flatnonzero(chain._paper):
        sl = chain.v_slice(j)
        X[sl] = np.linalg.solve(st.J[j], X[sl])
    return X


def _contact_rest_length_column(chain: Chain, st, env, t: float, j: int) -> np.ndarray:
    """``d tau_env/d l0_j`` (nv,) at fixed ``q``: a contact point stands for ``l0 / K`` of tube
    (:mod:`qchain.contact.forces`), so the contact forces are linear in the rest lengths
    (self-contact through ``(l0_i + l0_j) / 2``) and their derivative is the contact pass itself
    with ``l0 = e_j`` (an evaluation, not a difference); point loads do not depend on it."""
    out = np.zeros(chain.nv)
    pk = env.packed()
    if not (pk.kind.size or pk.law[7]):
        return out
    n = chain.n
    unit = np.zeros(n)
    unit[j] = 1.0
    arrays = tuple(chain._named_arrays._replace(l0=unit))
    tau_c, F0, W = np.zeros((n, 3)), np.zeros(6), np.zeros((n + 1, 6))
    prm, vel = _moved(pk, t)
    roots, Pw = _self_contact_work(n, pk)
    contact_forces(arrays, pk.kind, prm, vel, pk.law, pk.calpha, st.q_c, np.ascontiguousarray(st.v_c),
                   np.ascontiguousarray(st.X_WB.rotation), np.ascontiguousarray(st.X_WB.translation),
                   np.ascontiguousarray(st.V0), tau_c, F0, W, roots, Pw, np.zeros((0, RECORD)), np.empty(SCRATCH))
    out[chain._voff :] = tau_c.ravel()
    if chain.floating:
        out[:6] = F0
    return out


def forward_dynamics_parameter_derivatives(chain: Chain, q, v, p=None, params=(), tau=None, t: float = 0.0,
                                           env=None, data: Data | None = None) -> ParameterDerivatives:
    """Exact ``da/dtheta`` (nv, n_theta) of :meth:`Chain.forward_dynamics` at ``(q, v, p, tau, t)``.

    ``da/dtheta = M^-1 (df/dtheta - dID/dtheta)`` (:mod:`qchain.algorithms.parameter_derivatives`),
    compiled, after the forward dynamics and their state derivatives. ``params``: a
    :class:`Parameters` or the list it takes. ``env`` (a :class:`qchain.contact.Environment`,
    curvature coordinates) adds its forces, which depend on no parameter here (its
    ``d/dq`` enters an inextensible segment's rest length; a base placement with ``env`` is
    refused: the obstacles sit in the world). Locked coordinates have zero rows. ``data``:
    :meth:`Chain.create_data`, the workspace of the state pass.
    """
    P = _parameters(chain, params)
    data = chain._data(data)
    dq_env = None
    if env is not None:
        if P._has_base:
            raise ValueError("base_placement derivatives with env are not supported: the obstacles are placed in the "
                             "world, so moving the base moves the arm against them")
        te, dq_env, _ = chain.environment_terms(q, v, env, t)
        tau = te if tau is None else chain._vec("tau", tau, chain.nv) + te
    st, p3, tau = chain._dynamics_inputs(q, v, p, tau, t)
    dq_drag = None
    if chain._has_drag:  # the medium's drag depends on no parameter, but on an inextensible segment's held length
        tau, dq_drag, _ = chain._with_drag(tau, st.q_c, st.v_c, st.V0, True)
    n, nv = chain.n, chain.nv
    tau_c = np.zeros(nv) if tau is None else np.array(tau, dtype=float)
    if st.J is not None:
        for j in np.flatnonzero(chain._paper):  # tau_c = J^-T tau_e
            sl = chain.v_slice(j)
            tau_c[sl] = np.linalg.solve(st.J[j].T, tau_c[sl])
    if data is None:
        data = chain.create_data()
    da = np.empty((nv, len(P)))
    dID = np.empty((nv, len(P)))
    wq = _pd.parameter_workspace(n, nv, len(P))
    A_B = np.zeros(6) if st.A_B is None else np.ascontiguousarray(st.A_B)
    q_c, v_c, V0, g_B = (np.ascontiguousarray(x) for x in (st.q_c, st.v_c, st.V0, st.g_B))
    ws, wd, wa = tuple(data.aba_workspace()), tuple(data.rnea_workspace()), tuple(data.aba_derivatives_workspace())
    # two calls, not the one compiled entry: the state derivatives' pass is the one
    # forward_dynamics_derivatives compiled already (the entry, without reference counting, is
    # compiled apart, a minute and a half on first use)
    status = aba_derivatives.aba_derivatives(chain._arrays, chain.floating, q_c, v_c, p3, tau_c, V0, A_B, g_B, ws, wd,
                                             wa, data.scratch)
    if status == 0:
        status = _pd.parameter_derivatives_at(chain._arrays, chain.floating, q_c, v_c, p3, data.a_c, data.A0, V0, g_B,
                                              np.ascontiguousarray(st.X_WB.rotation), _youngs(chain), P.kinds,
                                              P.index, ws, wd, wa, tuple(wq), data.scratch, da, dID)
    if status in (1, 2):
        raise chain.indefinite_error("forward_dynamics_parameter_derivatives", st.q_e, t)
    if status:
        raise chain.nonfinite_error("forward_dynamics_parameter_derivatives", "accelerations or their parameter "
                                    "derivatives", np.concatenate([np.zeros(chain._qoff), st.q_e.ravel()]),
                                    np.concatenate([np.zeros(chain._voff), st.v_e.ravel()]), t)
    if dq_env is not None:
        for k in np.flatnonzero(P.kinds == _pd.KIND_LENGTH):
            j = int(P.index[k])
            extra = _contact_rest_length_column(chain, st, env, t, j)
            if chain._locked[j, 0]:  # an inextensible segment's held length moves the arm against the obstacles
                extra += dq_env[:, chain._voff + 3 * j]
            da[:, k] += data.da_dtau @ extra
    if dq_drag is not None:
        for k in np.flatnonzero(P.kinds == _pd.KIND_LENGTH):
            j = int(P.index[k])
            if chain._locked[j, 0]:
                da[:, k] += data.da_dtau @ dq_drag[:, chain._voff + 3 * j]
    a = data.a.copy()
    if st.J is not None:
        for j in np.flatnonzero(chain._paper):
            sl = chain.v_slice(j)
            a[sl] = np.linalg.solve(st.J[j], a[sl] - paper_jacobian_dot(st.q_e[j], st.v_e[j]) @ st.v_e[j])
    return ParameterDerivatives(a, _to_paper_rows(chain, st, da), P.names, P.units)


def inverse_dynamics_parameter_derivatives(chain: Chain, q, v, a, params=(), t: float = 0.0, env=None
                                           ) -> InverseParameterDerivatives:
    """Exact ``dtau/dtheta`` (nv, n_theta) of :meth:`Chain.inverse_dynamics` ``M a + C v + g`` at
    ``(q, v, a, t)``: the mass, gravity and base-placement columns (and an inextensible
    segment's rest length, which moves its held length); Young's modulus, damping, a free
    rest length and the chamber area do not enter it (zero columns). With ``env`` the
    inverse dynamics less the environment's forces, as :meth:`Chain.inverse_dynamics` (the
    contact forces' share of the rest lengths enters; a base placement is refused)."""
    P = _parameters(chain, params)
    te = dq_env = None
    if env is not None:
        if P._has_base:
            raise ValueError("base_placement derivatives with env are not supported: the obstacles are placed in the "
                             "world, so moving the base moves the arm against them")
        te, dq_env, _ = chain.environment_terms(q, v, env, t)
    a = chain._vec("a", a, chain.nv)
    st = chain._state(q, v, t=t, nonsingular=True, extra=(("a", a),))
    if chain._any_locked:
        chain._check_locks(st.q_e, st.v_e)
    n, nv = chain.n, chain.nv
    a_c = chain._acc_c(st, a[chain._voff :].reshape(n, 3))
    A0 = chain._A0(st, a[:6] if chain.floating else None)
    data = chain.create_data()
    wq = _pd.parameter_workspace(n, nv, len(P))
    dID = np.empty((nv, len(P)))
    _pd.inverse_parameter_derivatives(
        chain._arrays, chain.floating, np.ascontiguousarray(st.q_c), np.ascontiguousarray(st.v_c),
        np.ascontiguousarray(a_c), np.ascontiguousarray(st.V0), A0, np.ascontiguousarray(st.g_B),
        np.ascontiguousarray(st.X_WB.rotation), P.kinds, P.index, tuple(data.aba_workspace()),
        tuple(data.rnea_workspace()), tuple(wq), data.scratch, dID)
    tau_c = data.tau_c.ravel()
    tau = np.concatenate([data.F0, tau_c]) if chain.floating else tau_c.copy()
    if env is not None:  # (curvature coordinates: environment_terms refuses the paper's)
        tau -= te
        for k in np.flatnonzero(P.kinds == _pd.KIND_LENGTH):
            j = int(P.index[k])
            dID[:, k] -= _contact_rest_length_column(chain, st, env, t, j)
            if chain._locked[j, 0]:
                dID[:, k] -= dq_env[:, chain._voff + 3 * j]
    if st.J is not None:  # tau_e = J^T tau_c, row blocks
        for j in np.flatnonzero(chain._paper):
            sl = chain.v_slice(j)
            tau[sl] = st.J[j].T @ tau[sl]
            dID[sl] = st.J[j].T @ dID[sl]
    if not (np.all(np.isfinite(tau)) and np.all(np.isfinite(dID))):
        raise chain.nonfinite_error("inverse_dynamics_parameter_derivatives", "inverse dynamics or its parameter "
                                    "derivatives", np.concatenate([np.zeros(chain._qoff), st.q_e.ravel()]),
                                    np.concatenate([np.zeros(chain._voff), st.v_e.ravel()]), t)
    return InverseParameterDerivatives(tau, dID, P.names, P.units)


class ChainParameters:
    """The parameter derivatives as :class:`~qchain.Chain` methods (a base class of it)."""

    def parameters(self, params) -> Parameters:
        """A :class:`Parameters` of this chain from a list of ``(kind, segment)`` pairs."""
        return Parameters(self, params)

    def forward_dynamics_parameter_derivatives(self, q, v, p=None, params=(), tau=None, t: float = 0.0, env=None,
                                               data: Data | None = None) -> ParameterDerivatives:
        """:func:`qchain.arm.parameter_derivatives.forward_dynamics_parameter_derivatives` of this chain."""
        return forward_dynamics_parameter_derivatives(self, q, v, p, params, tau, t, env, data)

    def inverse_dynamics_parameter_derivatives(self, q, v, a, params=(), t: float = 0.0, env=None
                                               ) -> InverseParameterDerivatives:
        """:func:`qchain.arm.parameter_derivatives.inverse_dynamics_parameter_derivatives` of this chain."""
        return inverse_dynamics_parameter_derivatives(self, q, v, a, params, t, env)
