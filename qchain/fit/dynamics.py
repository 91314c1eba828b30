"""Dynamic calibration: a model fitted to measured motion under recorded pressures.

For parameters ``theta`` the model's motion is a run of the compiled engine from the
experiment's start, driven by the measured pressures (their piecewise-linear table), with its
exact forward sensitivities (:func:`qchain.sim.sensitivity.sensitivities`: the derivative of
the numbers the integrator returns, its steps held); the residuals are the model's points
at the measured times minus the measured points, their Jacobian ``J_point(q) dq/dtheta``.

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


def dynamic_residuals(chain, meas: Measurements, sens_params: list, static_params: list, T_sens: np.ndarray,
                      T_static: np.ndarray, *, start: str = "rest", q0=None, v0=None, rtol: float = 1e-7,
                      atol: float = 1e-9, jacobian: bool = True):
    """Residuals (K m 3,) m and their Jacobian (K m 3, p) of ``chain``'s run against ``meas``.

    Parameters
    ----------
    chain : Chain
    meas : Measurements
        Measured points (``meas.points``) at ``meas.where``, pressures ``meas.pressures``.
    sens_params, T_sens
        The sensitivities' ``(name, segment or axis)`` columns and the map from them to the
        fit's parameters (:func:`qchain.fit.parameters.column_map`).
    static_params, T_static
        The same for :meth:`~qchain.Chain.forward_dynamics_parameter_derivatives` (the rest
        pose's derivative; ``start="rest"`` only).
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

    if meas.points is None:
        raise ValueError(f"{meas.source}: the dynamic fit needs measured points (coordinates alone: not yet)")
    p0 = meas.pressures(0.0)
    if start == "rest":
        eq = equilibrium(chain, p0)
        if not eq.success:
            raise FloatingPointError(f"{meas.source}: the model has no rest pose under the first pressures "
                                     f"({eq.message})")
        q0, v0 = eq.q, np.zeros(chain.nv)
    elif start != "scene":
        raise ValueError(f"start must be 'rest' or 'scene', got {start!r}")
    if not jacobian:
        from ..sim.simulation import simulate

        run = simulate(chain, q0, v0, (0.0, float(meas.t[-1])), pressure=meas.pressures, method="dopri5",
                       rtol=rtol, atol=atol, t_eval=meas.t, energies=False)
        if not run.success:
            raise FloatingPointError(f"{meas.source}: the model's run failed: {run.message}")
        r = np.array([chain.points(q, meas.where) for q in run.q]) - meas.points  # one pass a sample
        return r.reshape(-1), None
    free = np.flatnonzero(chain.active)
    nf = free.size
    res = sensitivities(chain, q0, v0, (0.0, float(meas.t[-1])), params=list(sens_params), initial=True,
                        method="dopri5", rtol=rtol, atol=atol, t_eval=meas.t, pressure=meas.pressures)
    if not res.success:
        raise FloatingPointError(f"{meas.source}: the model's run failed: {res.message}")
    dx0 = None
    if start == "rest":
        dq0 = rest_derivative(chain, q0, p0, static_params) @ T_static  # (nv, p)
        dx0 = dq0[free]
    K, m = meas.points.shape[:2]
    r = np.empty((K, m, 3))
    J = np.empty((K, m, 3, T_sens.shape[1]))
    for j, (seg, alpha) in enumerate(meas.where):
        pts, dp = tip_sensitivities(chain, res, segment=int(seg) % chain.n, alpha=alpha)
        r[:, j] = pts - meas.points[:, j]
        Jj = dp[:, :, 2 * nf:] @ T_sens  # (K, 3, p)
        if dx0 is not None:
            Jj = Jj + dp[:, :, :nf] @ dx0
        J[:, j] = Jj
    return r.reshape(-1), J.reshape(K * m * 3, -1)


def input_noise_draws(chain, meas: Measurements, noise: np.ndarray, n_draws: int, *, cutoff: float | None = None,
                      start: str = "rest", q0=None, v0=None, rtol: float = 1e-7, atol: float = 1e-9,
                      seed: int = 0) -> np.ndarray:
    """(n_draws, K m 3) m: how the residuals change when the pressure sensor's noise is drawn
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
    base, _ = dynamic_residuals(chain, meas, [], [], None, None, start=start, q0=q0, v0=v0, rtol=rtol, atol=atol,
                                jacobian=False)
    rng = np.random.default_rng(seed)
    out = np.empty((int(n_draws), base.size))
    for k in range(int(n_draws)):
        e = rng.normal(size=tab.values.shape) * np.asarray(noise, dtype=float)
        if cutoff is not None:
            e = filter_pressures(Table(tab.times, e), cutoff).values
        m = replace(meas, pressures=Table(tab.times, tab.values + e))
        r, _ = dynamic_residuals(chain, m, [], [], None, None, start=start, q0=q0, v0=v0, rtol=rtol, atol=atol,
                                 jacobian=False)
        out[k] = r - base
    return out
