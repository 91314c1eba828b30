"""Dynamic calibration: a model fitted to measured motion under recorded pressures.

For parameters ``theta`` the model's motion is a run of the compiled engine from the
experiment's start, driven by the measured pressures (their piecewise-linear table), with its
exact forward sensitivities (:func:`qchain.sim.sensitivity.sensitivities`: the derivative of
the numbers the integrator returns, its steps held); the residuals are the model's points
at the measured times minus the measured points, their Jacobian ``J_point(q) dq/dtheta``, and
for measured coordinates the model's less the measured, each scaled to a length
(:func:`qchain.fit.measurements.coordinate_scale`), their Jacobian the sensitivities' own
configuration rows.

The start: a real arm's experiment starts at rest under its first pressures (``start="rest"``,
the default): ``q0 = equilibrium(chain, p(0))``, ``v0 = 0``, and since that rest pose moves
with the parameters too, its exact derivative (the implicit function theorem, as in
:mod:`qchain.fit.statics`) is carried through the initial-state columns of the sensitivities:
``dq/dtheta = S_theta + S_q0 dq0/dtheta``. ``start="scene"`` takes the scene's own initial
state, which does not depend on the parameters.

:func:`input_noise_draws` samples how the residuals move when the pressure sensor's noise is
drawn anew (plain runs under the measured pressures plus fresh noise): the fit's
``covariance="inputs"`` standard errors.
"""

from __future__ import annotations

import numpy as np

from .measurements import Measurements
from .statics import rest_derivative

__all__ = ["dynamic_residuals", "input_noise_draws"]


def dynamic_residuals(chain, meas: Measurements, params: list, T: np.ndarray, *, start: str = "rest", q0=None,
                      v0=None, rtol: float = 1e-7, atol: float = 1e-9, jacobian: bool = True):
    """Residuals (K rows,) m and their Jacobian (K rows, p) of ``chain``'s run against ``meas``.

    Each sample's ``rows = meas.rows`` residuals (:attr:`Measurements.rows`): the model's
    points minus the measured ones (m, x y z a point), then the used coordinates'
    ``w_i (q_i - q_meas_i)`` (``w = meas.coordinate_scale``, m per unit; default and the
    coordinates the model holds left out: :func:`~qchain.fit.measurements.coordinate_scale`).
    The Jacobian: ``J_point dq/dtheta`` for a point, ``w_i dq_i/dtheta`` for a coordinate
    (the configuration rows of the sensitivities ``S``).

    Parameters
    ----------
    chain : Chain
    meas : Measurements
        Measured points (``meas.points``) at ``meas.where`` and/or coordinates
        (``meas.coordinates``, (K, nq)), pressures ``meas.pressures``.
    params, T
        The model's ``(name, segment or axis)`` columns (:func:`qchain.sim.sensitivities`'s
        and :meth:`~qchain.Chain.forward_dynamics_parameter_derivatives`' pairs, gravity
        ``("gravity", axis)``) and the map from them to the fit's parameters
        (:func:`qchain.fit.parameters.column_map`).
    start : {"rest", "scene"}
    q0, v0
        The start for ``start="scene"``.
    rtol, atol
        dopri5's tolerances (its steps are then held for the sensitivities).
    jacobian : bool
        False: the residuals of a plain run (the same numbers: the sensitivities' run is
        ``simulate``'s bit for bit), the Jacobian None.
    """
    from ..arm.statics import equilibrium
    from ..sim.sensitivity import sensitivities, tip_sensitivities
    from .measurements import coordinate_scale

    w = ci = None
    if meas.coordinates is not None:
        w, _ = coordinate_scale(chain, meas)
        ci = np.flatnonzero(w > 0)
        if meas.coordinate_scale is not None and ci.size != meas.coordinate_index.size:
            raise ValueError(f"{meas.source}: coordinate_scale weights coordinates the model holds still")
    p0 = meas.pressures(0.0)
    if start == "rest":
        eq = equilibrium(chain, p0)
        if not eq.success:
            raise FloatingPointError(f"{meas.source}: the model has no rest pose under the first pressures "
                                     f"({eq.message})")
        q0, v0 = eq.q, np.zeros(chain.nv)
    elif start != "scene":
        raise ValueError(f"start must be 'rest' or 'scene', got {start!r}")
    K = meas.t.size
    m = 0 if meas.points is None else meas.points.shape[1]
    if not jacobian:
        from ..sim.simulation import simulate

        run = simulate(chain, q0, v0, (0.0, float(meas.t[-1])), pressure=meas.pressures, method="dopri5",
                       rtol=rtol, atol=atol, t_eval=meas.t, energies=False)
        if not run.success:
            raise FloatingPointError(f"{meas.source}: the model's run failed: {run.message}")
        parts = []
        if m:
            parts.append((np.array([chain.points(q, meas.where) for q in run.q]) - meas.points).reshape(K, -1))
        if ci is not None:
            parts.append(w[ci] * (run.q[:, ci] - meas.coordinates[:, ci]))
        return np.concatenate(parts, axis=1).reshape(-1), None
    free = np.flatnonzero(chain.active)
    nf = free.size
    res = sensitivities(chain, q0, v0, (0.0, float(meas.t[-1])), params=list(params), initial=True,
                        method="dopri5", rtol=rtol, atol=atol, t_eval=meas.t, pressure=meas.pressures)
    if not res.success:
        raise FloatingPointError(f"{meas.source}: the model's run failed: {res.message}")
    dx0 = None
    if start == "rest":
        dx0 = (rest_derivative(chain, q0, p0, params) @ T)[free]  # (nf, p)
    p = T.shape[1]
    rs, Js = [], []
    for seg, alpha in (meas.where if m else ()):
        pts, dp = tip_sensitivities(chain, res, segment=int(seg) % chain.n, alpha=alpha)
        Jj = dp[:, :, 2 * nf:] @ T  # (K, 3, p)
        if dx0 is not None:
            Jj = Jj + dp[:, :, :nf] @ dx0
        rs.append(pts - meas.points[:, len(rs)])
        Js.append(Jj)
    if ci is not None:  # the configuration rows of S (tangent space: dq for curvature coordinates, nq = nv)
        Sq = res.S[:, ci, :]  # (K, nc, ncol)
        Jc = Sq[:, :, 2 * nf:] @ T
        if dx0 is not None:
            Jc = Jc + Sq[:, :, :nf] @ dx0
        rs.append(w[ci] * (res.q[:, ci] - meas.coordinates[:, ci]))
        Js.append(w[ci][None, :, None] * Jc)
    r = np.concatenate([a.reshape(K, -1) for a in rs], axis=1)
    J = np.concatenate([a.reshape(K, -1, p) for a in Js], axis=1)
    return r.reshape(-1), J.reshape(-1, p)


def input_noise_draws(chain, meas: Measurements, noise: np.ndarray, n_draws: int, *, cutoff: float | None = None,
                      start: str = "rest", q0=None, v0=None, rtol: float = 1e-7, atol: float = 1e-9,
                      seed: int = 0) -> np.ndarray:
    """(n_draws, K rows) m: how the residuals change when the pressure sensor's noise is drawn
    anew: the model's run under the measured pressures plus white noise of ``noise`` (Pa a
    chamber, each sample; low-passed at ``cutoff`` Hz as the measured ones were), less its run
    under the measured pressures (a plain run each, :func:`dynamic_residuals` with
    ``jacobian=False``).

    The measured pressures are the true ones plus the sensor's noise, so the residuals hold the
    model's response to that noise; a fresh draw of it has the same distribution (to first
    order in the noise, the model near the truth), so the draws sample the residuals'
    covariance from the inputs (errors in the variables, propagated through the model's
    nonlinear dynamics rather than through a linearisation). Reproducible: draws from ``seed``.
    """
    from dataclasses import replace

    from ..sim.inputs import Table
    from .measurements import filter_pressures

    tab = meas.pressures
    base, _ = dynamic_residuals(chain, meas, [], None, start=start, q0=q0, v0=v0, rtol=rtol, atol=atol,
                                jacobian=False)
    rng = np.random.default_rng(seed)
    out = np.empty((int(n_draws), base.size))
    for k in range(int(n_draws)):
        e = rng.normal(size=tab.values.shape) * np.asarray(noise, dtype=float)
        if cutoff is not None:
            e = filter_pressures(Table(tab.times, e), cutoff).values
        m = replace(meas, pressures=Table(tab.times, tab.values + e))
        r, _ = dynamic_residuals(chain, m, [], None, start=start, q0=q0, v0=v0, rtol=rtol, atol=atol,
                                 jacobian=False)
        out[k] = r - base
    return out
