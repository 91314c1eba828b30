"""Bounded nonlinear least squares with exact Jacobians, and what the fit says: standard
errors, correlations, parameters the data cannot tell apart.

:func:`least_squares_fit` minimises ``1/2 sum rho(r_i(theta)^2)`` over ``theta`` within bounds
with scipy's ``least_squares`` (trust-region reflective), the residuals ``r`` and their
Jacobian ``J = dr/dtheta`` from one callable (the model computes both in one pass). The
parameters are scaled by their start values' size (or the given scales), so a modulus of 1e5
Pa and a length of 0.1 m are of one size to the solver.

The statistics (:class:`FitResult`) are those of a least-squares estimate with independent
residuals of one standard deviation: ``sigma^2 = 2 cost / (m - p)`` and the covariance
``sigma^2 (J^T J)^-1`` at the solution, computed from the singular value decomposition of the
column-scaled ``J`` (its small singular values are the directions the data do not fix). With a
robust loss every row is weighted as scipy weights it (``sqrt(rho')``, :func:`robust_weights`):
the Jacobian, the residuals the HAC scores are made of and the input-noise draws alike, the
usual approximation that leaves out ``rho''``. ``covariance="hac"`` (Newey-West) and ``"inputs"`` (the
inputs' noise propagated by draws, the effective-variance sandwich) replace the independent
residuals by residuals correlated in time (docs/fit.md, "Noisy pressures").

A parameter set the data cannot tell apart shows as a scaled ``J`` whose smallest singular
value is below ``identifiable_tol`` times its largest: the warning names the parameters that
make up that direction (mass and stiffness from statics alone, two segments' moduli from the
tip alone), and their standard errors are infinite. A pair with a correlation above 0.99 is
named too.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

__all__ = ["FitResult", "FitWarning", "least_squares_fit"]


class FitWarning(UserWarning):
    """Something a fit's result should be read with (parameters not identifiable, correlated,
    at a bound, a fit that did not converge)."""


@dataclass
class FitResult:
    """The outcome of a fit.

    Attributes
    ----------
    names : list of str
        The parameters, in order.
    x : (p,) float
        The fitted values (SI units).
    x0 : (p,) float
        The start values.
    stderr : (p,) float
        Standard errors (inf for a parameter the data do not fix).
    correlation : (p, p) float
        Correlation matrix of the estimates (NaN rows for parameters the data do not fix).
    covariance : (p, p) float
    residuals : (m,) float
        Residuals at the solution (model minus measurement, in the measurements' units).
    sigma : float
        The residuals' standard deviation estimate, ``sqrt(2 cost / (m - p))`` (with
        ``covariance="inputs"``: the measurement noise's, less the inputs' noise's part).
    cost : float
        ``1/2 sum rho(r^2)``.
    success : bool
    message : str
    nfev, njev : int
        Residual and Jacobian evaluations.
    unidentifiable : list of list of str
        Groups of parameters the data cannot tell apart.
    correlated : list of (str, str, float)
        Pairs with a correlation above 0.99 in magnitude.
    at_bound : list of str
        Parameters that ended at a bound (their standard errors assume they did not).
    """

    names: list
    x: np.ndarray
    x0: np.ndarray
    stderr: np.ndarray
    correlation: np.ndarray
    covariance: np.ndarray
    residuals: np.ndarray
    sigma: float
    cost: float
    success: bool
    message: str
    nfev: int
    njev: int
    unidentifiable: list = field(default_factory=list)
    correlated: list = field(default_factory=list)
    at_bound: list = field(default_factory=list)

    def table(self) -> list[str]:
        """One line a parameter: name, start, fitted value, standard error."""
        w = max(len(n) for n in self.names)
        out = [f"{'parameter':<{w}}  {'start':>12}  {'fitted':>12}  {'std error':>10}"]
        for n, a, b, s in zip(self.names, self.x0, self.x, self.stderr):
            out.append(f"{n:<{w}}  {a:12.6g}  {b:12.6g}  {s:10.3g}")
        return out


COVARIANCES = ("iid", "hac", "inputs")


def newey_west_lags(n: int) -> int:
    """Newey and West's (1994) bandwidth rule ``floor(4 (n / 100)^(2/9))`` for ``n`` samples."""
    return int(np.floor(4.0 * (n / 100.0) ** (2.0 / 9.0)))


def _hac_meat(Js: np.ndarray, r: np.ndarray, blocks) -> np.ndarray:
    """Newey-West estimate of ``Js^T Cov(r) Js`` (p, p): the scores ``g_k = sum Js r`` over each
    sample's rows, their autocovariances to the lag :func:`newey_west_lags` with Bartlett
    weights, per experiment (experiments independent), scaled by ``K / (K - p)``."""
    m, p = Js.shape
    meat = np.zeros((p, p))
    K_all = 0
    for start, K, rows in blocks:
        g = (Js[start:start + K * rows] * r[start:start + K * rows, None]).reshape(K, rows, p).sum(axis=1)
        S = g.T @ g
        L = newey_west_lags(K)
        for lag in range(1, min(L, K - 1) + 1):
            G = g[lag:].T @ g[:-lag]
            S += (1.0 - lag / (L + 1.0)) * (G + G.T)
        meat += S
        K_all += K
    return meat * K_all / max(K_all - p, 1)


def _statistics(J: np.ndarray, r: np.ndarray, cost: float, scale: np.ndarray, names: list[str],
                identifiable_tol: float, covariance: str = "iid", blocks=None, draws=None):
    """Covariance, standard errors, correlation and the unidentifiable groups from the
    Jacobian ``J`` (m, p) in physical units, via the SVD of ``J * scale``; ``covariance`` as
    :func:`least_squares_fit` says (``blocks`` for ``"hac"``, ``draws`` (N, m) for ``"inputs"``)."""
    m, p = J.shape
    Js = J * scale
    U, s, Vt = np.linalg.svd(Js, full_matrices=False)
    dof = max(m - p, 1)
    sigma2 = 2.0 * cost / dof
    ok = s > identifiable_tol * (s[0] if s.size else 0.0)
    groups = []
    for k in np.flatnonzero(~ok):
        v = Vt[k]
        big = np.flatnonzero(np.abs(v) > 0.2 * np.abs(v).max())
        groups.append([names[i] for i in big])
    inv = (Vt[ok].T / s[ok] ** 2) @ Vt[ok]  # pseudo-inverse of Js^T Js on the fixed directions
    if covariance == "hac":
        cov_s = inv @ _hac_meat(Js, r, blocks if blocks is not None else [(0, m, 1)]) @ inv
    elif covariance == "inputs" and draws is not None and len(draws):
        # r = e_meas + d (white measurement noise plus the input noise's propagated part d):
        # Cov(theta) = inv Js^T (s_m^2 I + Cov d) Js inv, Cov d from the draws; s_m^2 from the
        # residuals less what the draws put in them off the fitted directions
        D = np.asarray(draws, dtype=float)
        G = D @ Js  # (N, p)
        Dperp = D - (D @ U[:, ok]) @ U[:, ok].T
        sm2 = max(2.0 * cost - float(np.mean(np.sum(Dperp ** 2, axis=1))), 0.0) / dof
        cov_s = sm2 * inv + inv @ (G.T @ G / D.shape[0]) @ inv
        sigma2 = sm2
    else:
        cov_s = sigma2 * inv
    cov = cov_s * np.outer(scale, scale)
    free = np.zeros(p, bool)
    for k in np.flatnonzero(~ok):
        free |= np.abs(Vt[k]) > 1e-8 * np.abs(Vt[k]).max()
    stderr = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    stderr[free] = np.inf
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.sqrt(np.diag(cov))
        corr = cov / np.outer(d, d)
    corr[free, :] = np.nan
    corr[:, free] = np.nan
    np.fill_diagonal(corr, np.where(free, np.nan, 1.0))
    pairs = [(names[i], names[j], float(corr[i, j])) for i in range(p) for j in range(i + 1, p)
             if np.isfinite(corr[i, j]) and abs(corr[i, j]) > 0.99]
    return cov, stderr, corr, float(np.sqrt(sigma2)), groups, pairs


def robust_weights(r: np.ndarray, loss: str, f_scale: float) -> np.ndarray:
    """``rho'(z)`` (m,) of scipy's robust ``loss`` at ``z = (r / f_scale)^2``: the factor a row's
    squared residual is weighted by at the solution (1 for ``"linear"``)."""
    z = (np.asarray(r, dtype=float) / f_scale) ** 2
    if loss == "linear":
        return np.ones_like(z)
    return {"soft_l1": lambda z: (1 + z) ** -0.5, "huber": lambda z: np.where(z <= 1, 1.0, z ** -0.5),
            "cauchy": lambda z: 1 / (1 + z), "arctan": lambda z: 1 / (1 + z ** 2)}[loss](z)


def least_squares_fit(fun: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]], x0, names: list[str], *,
                      lower=None, upper=None, scale=None, loss: str = "linear", f_scale: float = 1.0,
                      identifiable_tol: float = 1e-7, max_nfev: int | None = None,
                      xtol: float = 1e-10, ftol: float = 1e-10, gtol: float = 1e-10,
                      residuals: Callable[[np.ndarray], np.ndarray] | None = None, covariance: str = "iid",
                      blocks=None, input_draws: Callable[[np.ndarray], np.ndarray] | None = None) -> FitResult:
    """Fit ``theta`` to make ``r(theta)`` small.

    Parameters
    ----------
    fun : callable
        ``fun(theta) -> (r, J)``: residuals (m,) and their exact Jacobian (m, p).
    x0 : (p,) float
        Start values (SI units).
    names : list of str
        The parameters' names (p).
    lower, upper : (p,) float, optional
        Bounds (default unbounded); ``x0`` must lie inside them.
    scale : (p,) float, optional
        Typical sizes (default ``|x0|``, 1 where it is 0).
    loss : str
        scipy's ``least_squares`` loss: ``"linear"`` (least squares), ``"soft_l1"``,
        ``"huber"``, ``"cauchy"``, ``"arctan"`` (robust to outliers).
    f_scale : float
        The residual size where a robust loss starts to down-weight (measurement units).
    identifiable_tol : float
        Singular values of the scaled Jacobian below this fraction of the largest mark
        directions the data do not fix.
    residuals : callable, optional
        ``residuals(theta) -> r``, the same residuals without their Jacobian, for the trial
        points the solver rejects (a plain rollout instead of one with sensitivities); the
        Jacobian is asked of ``fun`` only where the solver needs it.
    covariance : {"iid", "hac", "inputs"}
        How the standard errors read the residuals. ``"iid"``: independent, of one standard
        deviation (``sigma^2 (J^T J)^-1``). ``"hac"``: the sandwich ``(J^T J)^-1 J^T Omega J
        (J^T J)^-1`` with Newey and West's estimate of ``Omega`` from the residuals, correlated
        within ``blocks`` (residuals correlated in time, their correlation unknown).
        ``"inputs"``: the same sandwich with ``Omega = s_m^2 I + Cov(d)``, ``d`` the residuals'
        change from the inputs' noise, sampled by ``input_draws`` (errors in the inputs
        propagated through the model); without ``input_draws`` as ``"iid"``.
    blocks : list of (start, K, rows), optional
        For ``"hac"``: the residual rows ``start .. start + K rows`` are ``K`` samples in time
        of ``rows`` residuals each, one experiment (default: all rows one experiment, one row a
        sample).
    input_draws : callable, optional
        For ``"inputs"``: ``input_draws(theta) -> (N, m)``, ``N`` draws of the residuals'
        change when the inputs' noise is drawn anew (at the solution).
    """
    from scipy.optimize import least_squares

    x0 = np.asarray(x0, dtype=float)
    p = x0.size
    if len(names) != p:
        raise ValueError(f"names has {len(names)} entries for {p} parameters")
    lo = np.full(p, -np.inf) if lower is None else np.asarray(lower, dtype=float)
    hi = np.full(p, np.inf) if upper is None else np.asarray(upper, dtype=float)
    for i in range(p):
        if not lo[i] < hi[i]:
            raise ValueError(f"{names[i]}: lower bound {lo[i]:g} must be below the upper bound {hi[i]:g}")
        if not lo[i] <= x0[i] <= hi[i]:
            raise ValueError(f"{names[i]}: start value {x0[i]:g} is outside its bounds [{lo[i]:g}, {hi[i]:g}]")
    sc = np.where(np.abs(x0) > 0, np.abs(x0), 1.0) if scale is None else np.asarray(scale, dtype=float)
    if covariance not in COVARIANCES:
        raise ValueError(f"covariance must be 'iid', 'hac' or 'inputs', got {covariance!r}")
    if loss not in ("linear", "soft_l1", "huber", "cauchy", "arctan"):
        raise ValueError(f"loss must be 'linear', 'soft_l1', 'huber', 'cauchy' or 'arctan', got {loss!r}")
    cache: dict = {}  # the last point's r, and its J once asked

    def check(z, r, J=None):
        if not (np.all(np.isfinite(r)) and (J is None or np.all(np.isfinite(J)))):
            raise FloatingPointError(f"the residuals or their Jacobian are not finite at {dict(zip(names, z * sc))}")

    def value(z):
        key = z.tobytes()
        if cache.get("key") != key:
            if residuals is None:
                r, J = fun(z * sc)
                r, J = np.asarray(r, dtype=float), np.asarray(J, dtype=float)
                check(z, r, J)
                cache.update(key=key, r=r, J=J * sc)
            else:
                r = np.asarray(residuals(z * sc), dtype=float)
                check(z, r)
                cache.update(key=key, r=r, J=None)
        return cache["r"]

    njev = [0]

    def jac(z):
        njev[0] += 1
        value(z)
        if cache["J"] is None:
            r, J = fun(z * sc)
            r, J = np.asarray(r, dtype=float), np.asarray(J, dtype=float)
            check(z, r, J)
            cache.update(r=r, J=J * sc)
        return cache["J"]

    lo_s, hi_s = lo / sc, hi / sc
    z0 = np.clip(x0 / sc, lo_s, hi_s)
    sol = least_squares(value, z0, jac=jac, bounds=(lo_s, hi_s), method="trf", loss=loss,
                        f_scale=f_scale, x_scale=1.0, max_nfev=max_nfev, xtol=xtol, ftol=ftol, gtol=gtol)
    x = sol.x * sc
    Js = jac(sol.x)
    njev[0] -= 1  # (the statistics' own)
    r = cache["r"]
    J = Js / sc
    draws = input_draws(x) if covariance == "inputs" and input_draws is not None else None
    r_w = r
    if loss != "linear":
        # every residual row as the robust loss weights it (scipy's scaling by sqrt(rho')): the
        # Jacobian, the residuals of the HAC scores and the input draws alike, so that a row the
        # loss down-weights (an outlier) counts as little in the covariance as in the fit
        w = np.sqrt(robust_weights(r, loss, f_scale))
        J = J * w[:, None]
        r_w = r * w
        if draws is not None:
            draws = np.asarray(draws, dtype=float) * w
    cov, stderr, corr, sigma, groups, pairs = _statistics(J, r_w, float(sol.cost), sc, list(names),
                                                          identifiable_tol, covariance, blocks, draws)
    at_bound = [names[i] for i in range(p) if sol.active_mask[i] != 0]
    res = FitResult(names=list(names), x=x, x0=x0, stderr=stderr, correlation=corr, covariance=cov, residuals=r,
                    sigma=sigma, cost=float(sol.cost), success=bool(sol.success), message=str(sol.message),
                    nfev=int(sol.nfev), njev=njev[0], unidentifiable=groups, correlated=pairs, at_bound=at_bound)
    for g in groups:
        warnings.warn(f"the data cannot tell apart {', '.join(g)}: one combination of them is not fixed by the "
                      "measurements (their standard errors are infinite); fix one of them or measure what "
                      "separates them", FitWarning, stacklevel=2)
    for a, b, c in pairs:
        warnings.warn(f"{a} and {b} are correlated {c:+.4f}: the data barely tell them apart", FitWarning,
                      stacklevel=2)
    if at_bound:
        warnings.warn(f"{', '.join(at_bound)} ended at a bound: the fit would go further; their standard errors "
                      "assume it did not", FitWarning, stacklevel=2)
    if not sol.success:
        warnings.warn(f"the fit did not converge: {sol.message}", FitWarning, stacklevel=2)
    return res
