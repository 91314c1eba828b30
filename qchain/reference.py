"""Independent reference solutions (no qchain model code inside).

* :func:`elastica_cantilever`: the planar Euler elastica (inextensible, unshearable
  Kirchhoff rod -- a Cosserat rod without shear and extension) clamped horizontally and
  loaded by its own weight, solved as a boundary-value problem with ``scipy.integrate.solve_bvp``.
  A chain of ``n`` inextensible constant-curvature segments is a Ritz approximation of it
  with piecewise-constant curvature, so it converges to this solution as ``n`` grows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_bvp

from .checks.bounds import Range
from .errors import QchainError

__all__ = ["ElasticaSolution", "elastica_cantilever"]


@dataclass
class ElasticaSolution:
    """``s`` (K,) arc length (m); ``theta`` (K,) tangent angle from the horizontal, positive up
    (rad); ``x``, ``z`` (K,) centreline (m), clamp at the origin, ``x`` along the clamp
    direction, ``z`` up; ``tip`` (2,) = (x, z) at s = L."""

    s: np.ndarray
    theta: np.ndarray
    x: np.ndarray
    z: np.ndarray
    tip: np.ndarray


def elastica_cantilever(length: float, EI: float, weight_per_length: float, tol: float = 1e-10) -> ElasticaSolution:
    """Self-weight cantilever: ``EI theta'' = w (L - s) cos(theta)``, ``theta(0) = 0``,
    ``theta'(L) = 0``, ``x' = cos(theta)``, ``z' = sin(theta)``.

    Parameters
    ----------
    length : m;  EI : N m^2;  weight_per_length : w = rho A g (N/m), acting downwards.
        Real numbers (``TypeError`` otherwise): ``0 < length <= 1e3`` m, ``0 < EI <= 1e12``
        N m^2, ``|weight_per_length| <= 1e9`` N/m, ``0 < tol < 1``. A boundary-value problem
        that does not converge (loads far beyond the elastica's regime) raises
        :class:`qchain.QchainError` naming them.
    """
    L = Range(0.0, 1e3, "m", low_open=True).check("length", length)
    EI = Range(0.0, 1e12, "N m^2", low_open=True).check("EI", EI)
    w = Range(-1e9, 1e9, "N/m").check("weight_per_length", weight_per_length)
    tol = Range(0.0, 1.0, low_open=True, high_open=True).check("tol", tol)

    def f(s, y):
        th, k, x, z = y
        return np.vstack([k, w * (L - s) * np.cos(th) / EI, np.cos(th), np.sin(th)])

    def bc(ya, yb):
        return np.array([ya[0], yb[1], ya[2], ya[3]])

    s = np.linspace(0.0, L, 201)
    guess = np.zeros((4, s.size))
    guess[2] = s
    sol = solve_bvp(f, bc, s, guess, tol=tol, max_nodes=200000)
    if not sol.success:
        raise QchainError(f"elastica_cantilever: the boundary-value problem did not converge for length = {L:g} m, "
                          f"EI = {EI:g} N m^2, weight_per_length = {w:g} N/m: {sol.message}")
    ss = np.linspace(0.0, L, 2001)
    th, _, x, z = sol.sol(ss)
    return ElasticaSolution(s=ss, theta=th, x=x, z=z, tip=np.array([x[-1], z[-1]]))
