"""Closed-form kinematics of a constant-strain (constant-curvature, extensible) slice.

This is the per-node kernel of the model (DESIGN.md section 1). A segment in
curvature coordinates ``q = (l, ux, uy)`` has the constant strain twist
``X = l * xi_u`` with the unit-length strain ``xi_u = (0, 0, 1, -uy, ux, 0)``
(Pinocchio's ``[linear; angular]``). The slice ``alpha`` in [0, 1] sits at
``g(alpha) = exp6(alpha X)``, i.e. arc length ``s = alpha l`` along the backbone.

Because ``xi_u`` has zero pitch, ``A = ad(xi_u)`` obeys ``A^3 = -kappa^2 A`` with
``kappa^2 = ux^2 + uy^2``, so every exponential is a quadratic polynomial in ``A``
whose coefficients are the entire functions

    f0(x) = sin(x)/x,   f1(x) = (1 - cos x)/x^2,   f2(x) = (x - sin x)/x^3,

of the bending angle ``x = s kappa``, and their derivatives ``g_n(x) = f_n'(x)/x``
(also entire). They are evaluated by their Taylor series for small ``x`` and in closed
form otherwise, so nothing divides by the curvature and the straight pose is a regular
point. With ``a1 = s f0, a2 = s^2 f1, a3 = s^3 f2``:

* ``R(s) = I + a1 [w] + a2 [w]^2`` with ``w = (-uy, ux, 0)``, ``p(s) = (a2 ux, a2 uy, a1)``;
* ``Ad(g)^-1`` from ``(R, p)``;
* the slice Jacobian ``S(alpha) = alpha Jexp6(alpha X) dX/dq`` (body frame of the slice),
  with columns ``alpha xi_u`` and ``F(s) eta_j`` where ``F(s) = s I - a2 A + a3 A^2``
  ``= int_0^s Ad(exp(-sigma xi_u)) dsigma`` and ``eta_j = d xi_u / d u_j``;
* the exact second derivatives ``dS/dq`` (needed by the Coriolis matrix).

``tests/test_arc.py`` holds ``g``, ``Ad(g)^-1`` and ``S`` equal to Pinocchio's
``exp6``, ``SE3.action`` and ``Jexp6`` to 1e-14, and ``dS/dq`` to finite differences.
"""

from __future__ import annotations

from dataclasses import dataclass
from math import factorial

import numpy as np

from .spatial import inv_adjoint, motion_cross

__all__ = ["ArcNodes", "arc_nodes", "bend_functions", "strain_twist"]

# Taylor series are used below this bending angle (rad). At x = 2 the truncated series
# (16 terms) is exact to 1e-25 and the closed forms have lost at most a few ulp.
_SERIES_BELOW = 2.0
_NTERMS = 16
_F_COEF = np.array([[(-1) ** k / factorial(2 * k + n + 1) for k in range(_NTERMS)] for n in range(3)])
_G_COEF = np.array(
    [[(-1) ** k * 2 * k / factorial(2 * k + n + 1) for k in range(1, _NTERMS + 1)] for n in range(3)]
)

# unit-length strain directions: eta_x = d xi_u / d ux, eta_y = d xi_u / d uy
ETA_X = np.array([0.0, 0.0, 0.0, 0.0, 1.0, 0.0])
ETA_Y = np.array([0.0, 0.0, 0.0, -1.0, 0.0, 0.0])


def _horner(coef: np.ndarray, t: np.ndarray) -> np.ndarray:
    out = np.full_like(t, coef[-1])
    for c in coef[-2::-1]:
        out = out * t + c
    return out


def bend_functions(x: np.ndarray, derivatives: bool = False):
    """Entire functions of the bending angle ``x`` (rad), shape ``(N,)``.

    Returns ``(f0, f1, f2)`` and, with ``derivatives``, also ``(g0, g1, g2)`` with
    ``g_n = f_n'(x) / x``; all of shape ``(N,)``. Values at ``x = 0``:
    ``f = (1, 1/2, 1/6)``, ``g = (-1/3, -1/12, -1/60)``.
    """
    x = np.asarray(x, dtype=float)
    t = x * x
    small = x < _SERIES_BELOW
    f = np.empty((3,) + x.shape)
    g = np.empty((3,) + x.shape) if derivatives else None
    if np.any(small):
        ts = t[small]
        for n in range(3):
            f[n][small] = _horner(_F_COEF[n], ts)
            if derivatives:
                g[n][small] = _horner(_G_COEF[n], ts)
    big = ~small
    if np.any(big):
        xb = x[big]
        s, c = np.sin(xb), np.cos(xb)
        f[0][big] = s / xb
        f[1][big] = (1.0 - c) / xb**2
        f[2][big] = (xb - s) / xb**3
        if derivatives:
            g[0][big] = (xb * c - s) / xb**3
            g[1][big] = (xb * s - 2.0 * (1.0 - c)) / xb**4
            g[2][big] = (xb * (1.0 - c) - 3.0 * (xb - s)) / xb**5
    return (f, g) if derivatives else f


def strain_twist(q: np.ndarray) -> np.ndarray:
    """Unit-length strain twist ``xi_u = (0, 0, 1, -uy, ux, 0)``, ``(..., 3)`` -> ``(..., 6)``."""
    q = np.asarray(q, dtype=float)
    xi = np.zeros(q.shape[:-1] + (6,))
    xi[..., 2] = 1.0
    xi[..., 3] = -q[..., 2]
    xi[..., 4] = q[..., 1]
    return xi


@dataclass(frozen=True)
class ArcNodes:
    """Slice kinematics at N nodes, all in curvature coordinates ``q = (l, ux, uy)``.

    Attributes
    ----------
    R : (N, 3, 3)  rotation of slice frame in root frame.
    p : (N, 3)     position of the slice centre in the root frame (m).
    Ad_inv : (N, 6, 6)  ``Ad(g)^-1``: root-frame twist -> slice-frame twist.
    S : (N, 6, 3)  slice Jacobian: slice body twist per unit ``qdot`` (columns l, ux, uy).
    dS : (N, 6, 3, 3) or None  ``dS[n, :, i, j] = d S[n, :, i] / d q_j``.
    """

    R: np.ndarray
    p: np.ndarray
    Ad_inv: np.ndarray
    S: np.ndarray
    dS: np.ndarray | None


def arc_nodes(alpha: np.ndarray, q: np.ndarray, second: bool = False) -> ArcNodes:
    """Evaluate the slice kinematics at nodes ``alpha`` (N,) for configurations ``q`` (N, 3).

    Each node carries its own segment configuration, so the nodes of all segments of
    a chain are evaluated in one call. ``second`` adds the exact ``dS/dq``.
    """
    alpha = np.asarray(alpha, dtype=float)
    q = np.asarray(q, dtype=float)
    N = alpha.shape[0]
    l, ux, uy = q[:, 0], q[:, 1], q[:, 2]
    s = alpha * l
    x = s * np.hypot(ux, uy)
    if second:
        (f0, f1, f2), (_, g1, g2) = bend_functions(x, derivatives=True)
    else:
        f0, f1, f2 = bend_functions(x)
    a1 = s * f0
    a2 = s * s * f1
    a3 = s**3 * f2

    xi = strain_twist(q)  # (N, 6)
    W = np.zeros((N, 3, 3))
    W[:, 0, 2] = ux  # [w] with w = (-uy, ux, 0)
    W[:, 1, 2] = uy
    W[:, 2, 0] = -ux
    W[:, 2, 1] = -uy
    R = np.eye(3) + a1[:, None, None] * W + a2[:, None, None] * (W @ W)
    p = np.stack([a2 * ux, a2 * uy, a1], axis=-1)
    Ad_inv = inv_adjoint(R, p)

    etas = (np.broadcast_to(ETA_X, (N, 6)), np.broadcast_to(ETA_Y, (N, 6)))
    S = np.empty((N, 6, 3))
    S[:, :, 0] = alpha[:, None] * xi
    A_eta = []
    AA_eta = []
    for i, eta in enumerate(etas):
        Ae = motion_cross(xi, eta)
        AAe = motion_cross(xi, Ae)
        A_eta.append(Ae)
        AA_eta.append(AAe)
        S[:, :, 1 + i] = s[:, None] * eta - a2[:, None] * Ae + a3[:, None] * AAe

    dS = None
    if second:
        dS = np.zeros((N, 6, 3, 3))
        u = (ux, uy)
        s4g1 = s**4 * g1
        s5g2 = s**5 * g2
        for j, eta_j in enumerate(etas):
            dS[:, :, 0, 1 + j] = alpha[:, None] * eta_j
        for i, eta_i in enumerate(etas):
            dS[:, :, 1 + i, 0] = alpha[:, None] * np.einsum("nab,nb->na", Ad_inv, eta_i)
            for j, eta_j in enumerate(etas):
                eji = motion_cross(eta_j, eta_i)
                dS[:, :, 1 + i, 1 + j] = (
                    -(s4g1 * u[j])[:, None] * A_eta[i]
                    - a2[:, None] * eji
                    + (s5g2 * u[j])[:, None] * AA_eta[i]
                    + a3[:, None] * (motion_cross(eta_j, A_eta[i]) + motion_cross(xi, eji))
                )
    return ArcNodes(R=R, p=p, Ad_inv=Ad_inv, S=S, dS=dS)
