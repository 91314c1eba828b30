"""Static calibration: a model fitted to equilibrium poses measured at held pressures.

A :class:`StaticPoses` is K pressure vectors, each held until the arm settled, and the
points measured on the arm there. For parameters ``theta`` the model's poses are the
equilibria ``q_k(theta)`` (:func:`qchain.equilibrium`), the residuals the model's points minus
the measured ones, and their Jacobian exact by the implicit function theorem: at an
equilibrium the accelerations ``a(q, 0, p; theta)`` vanish, so

    dq_k/dtheta = -(da/dq)^-1 da/dtheta,      d point/dtheta = J_point(q_k) dq_k/dtheta,

with ``da/dq`` of :meth:`~qchain.Chain.forward_dynamics_derivatives`, ``da/dtheta`` of
:meth:`~qchain.Chain.forward_dynamics_parameter_derivatives` (on the free coordinates where
the model holds some still) and ``J_point`` of :meth:`~qchain.Chain.point_jacobian`.

What statics cannot tell: the masses and moduli enter a static pose only as the ratio of
weight to stiffness (and the chamber area as pressure gain to stiffness), so fitting mass
and modulus of one segment from statics alone is refused by the fit's identifiability check
(:mod:`qchain.fit.solve`), which names them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .measurements import MeasurementError, beyond_reach, csv_columns

__all__ = ["StaticPoses", "static_residuals", "rest_derivative", "read_static_csv", "static_input_draws"]


@dataclass(frozen=True)
class StaticPoses:
    """Equilibrium poses of one experiment.

    Attributes
    ----------
    pressures : (K, 3 n) float, Pa
        The held pressures.
    points : (K, m, 3) float, m, world frame
        The measured points at each.
    where : tuple of (int, float)
        Each point's ``(segment, alpha)`` (default the tip).
    source : str
    """

    pressures: np.ndarray
    points: np.ndarray
    where: tuple = ((-1, 1.0),)
    source: str = "static poses"

    def __post_init__(self):
        p = np.asarray(self.pressures, dtype=float)
        x = np.asarray(self.points, dtype=float)
        if p.ndim != 2 or p.shape[0] == 0:
            raise MeasurementError(f"{self.source}: pressures must be (K, 3 n) with K >= 1, got shape {p.shape}")
        if x.shape != (p.shape[0], len(self.where), 3):
            raise MeasurementError(f"{self.source}: points must have shape ({p.shape[0]}, {len(self.where)}, 3) "
                                   f"(poses, points at where, xyz), got {x.shape}")
        for name, a in (("pressures", p), ("points", x)):
            if not np.all(np.isfinite(a)):
                k = int(np.flatnonzero(~np.all(np.isfinite(a.reshape(a.shape[0], -1)), axis=1))[0])
                raise MeasurementError(f"{self.source}: {name} of pose {k} are not finite (a lost marker? leave "
                                       "that pose out)")
        object.__setattr__(self, "pressures", p)
        object.__setattr__(self, "points", x)

    @property
    def n_values(self) -> int:
        return int(self.points.size)

    def check_model(self, chain) -> None:
        """Refuse poses the arm ``chain`` cannot mean: pressures for another number of
        chambers, a point farther from the base than 1.5 times the arm's length (units)."""
        if self.pressures.shape[1] != chain.nu:
            raise MeasurementError(f"{self.source}: {self.pressures.shape[1]} pressures a pose, the model has "
                                   f"{chain.nu} chambers ({chain.n} segments x 3)")
        far = beyond_reach(chain, self.points)
        if far is not None:
            k, _, d, reach = far
            raise MeasurementError(f"{self.source}: the point measured in pose {k} is {d:.4g} m from the base, and "
                                   f"the arm is {reach:.4g} m long: units that do not match (mm for m?) or another "
                                   "frame than the base's world frame")


def rest_derivative(chain, q, p, params) -> np.ndarray:
    """``dq/dtheta`` (nv, n_theta) of the equilibrium ``q`` under pressures ``p``, by the
    implicit function theorem (``a(q, 0, p; theta) = 0``), on the free coordinates (zero rows
    where the model holds a coordinate still)."""
    free = np.flatnonzero(chain.active)
    zero = np.zeros(chain.nv)
    d = chain.forward_dynamics_derivatives(q, zero, p)
    pd = chain.forward_dynamics_parameter_derivatives(q, zero, p, params)
    out = np.zeros((chain.nv, pd.da_dtheta.shape[1]))
    out[free] = -np.linalg.solve(d.da_dq[np.ix_(free, free)], pd.da_dtheta[free])
    return out


def static_residuals(chain, poses: StaticPoses, params, q_guess: list | None = None, jacobian: bool = True):
    """Residuals (K m 3,) m and their Jacobian (K m 3, n_theta) of the model ``chain``'s
    equilibria against ``poses``, for the model parameters ``params`` (a
    :class:`~qchain.arm.parameter_derivatives.Parameters` or its ``(kind, segment)`` list).

    ``q_guess`` (K configurations, updated in place) starts each equilibrium where the last
    evaluation ended, so a fit's Newton solves take a step or two. ``jacobian=False``: the
    residuals alone (the Jacobian None).
    """
    from ..arm.statics import equilibrium

    P = chain.parameters(params) if not hasattr(params, "names") else params
    K, m = poses.points.shape[:2]
    r = np.empty((K, m, 3))
    J = np.empty((K, m, 3, len(P)))
    for k in range(K):
        p = poses.pressures[k]
        q0 = None if q_guess is None or q_guess[k] is None else q_guess[k]
        eq = equilibrium(chain, p, q0=q0)
        if not eq.success:
            raise FloatingPointError(f"{poses.source}: pose {k}: the model has no equilibrium at these pressures and "
                                     f"parameters ({eq.message})")
        if q_guess is not None:
            q_guess[k] = eq.q
        q = eq.q
        r[k] = chain.points(q, poses.where) - poses.points[k]
        if not jacobian:
            continue
        dq = rest_derivative(chain, q, p, P)
        for j, (seg, alpha) in enumerate(poses.where):
            J[k, j] = chain.point_jacobian(q, seg, alpha) @ dq
    return r.reshape(-1), (J.reshape(K * m * 3, len(P)) if jacobian else None)


def static_input_draws(chain, poses: StaticPoses, noise, n_draws: int, *, seed: int = 0) -> np.ndarray:
    """(n_draws, K m 3) m: how the static residuals change when the held pressures' sensor noise
    (``noise``, Pa a chamber, standard deviation) is drawn anew: ``J_point(q_k) dq_k/dp e``, with
    ``dq/dp = -(da/dq)^-1 da/dp`` the exact derivative of the equilibrium by the implicit
    function theorem (on the free coordinates) and ``e`` white noise, one draw a pose.

    Linearised rather than re-solved: the equilibrium map ``p -> q`` is smooth, the noise small,
    and the dynamic draws (:func:`qchain.fit.dynamics.input_noise_draws`) hold to first order in
    the noise too; the derivative costs one linear solve a pose where re-solving costs a Newton
    solve a pose and draw. Reproducible: draws from ``seed``."""
    from ..arm.statics import equilibrium

    free = np.flatnonzero(chain.active)
    K, m = poses.points.shape[:2]
    G = np.empty((K, m * 3, chain.nu))
    zero = np.zeros(chain.nv)
    for k in range(K):
        p = poses.pressures[k]
        eq = equilibrium(chain, p)
        if not eq.success:
            raise FloatingPointError(f"{poses.source}: pose {k}: the model has no equilibrium ({eq.message})")
        d = chain.forward_dynamics_derivatives(eq.q, zero, p)
        dq = np.zeros((chain.nv, chain.nu))
        dq[free] = -np.linalg.solve(d.da_dq[np.ix_(free, free)], d.da_dp[free])
        G[k] = np.concatenate([chain.point_jacobian(eq.q, seg, alpha) @ dq for seg, alpha in poses.where])
    rng = np.random.default_rng(seed)
    e = rng.normal(size=(int(n_draws), K, chain.nu)) * np.asarray(noise, dtype=float)
    return np.einsum("krp,nkp->nkr", G, e).reshape(int(n_draws), -1)


def read_static_csv(path, *, points: list, pressures: list[str], where=((-1, 1.0),), scale: float = 1.0) -> StaticPoses:
    """Static poses from a CSV file with a header row, one pose a row: the held pressures'
    columns (``pressures``, Pa) and the measured points' x, y, z columns (``points``: one
    triple of column names a point, in ``where``'s order; ``scale`` multiplies them, 1e-3 for
    mm). A row with an empty or non-finite cell is refused, naming it (leave that pose out)."""
    from pathlib import Path

    path = Path(path)
    cols = list(pressures) + [c for triple in points for c in triple]
    data = csv_columns(path, cols)
    n_p = len(pressures)
    pts = data[:, n_p:].reshape(len(data), len(points), 3) * float(scale)
    return StaticPoses(data[:, :n_p], pts, where=tuple((int(s), float(a)) for s, a in where), source=str(path))
