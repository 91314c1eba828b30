"""Static equilibrium of a chain under constant pressures, gravity, a tip load and contact.

``equilibrium(chain, p)`` solves ``B(q) p + J_tip(q)^T w - dU_el/dq - g(q) = 0`` (the paper's
eq. (9) at rest; docs/model.md sections 5, 6 and 9) for the free (not locked) segment
coordinates of a fixed or prescribed-base chain by Newton's method. The Newton matrix is the
exact elastic stiffness ``d^2 U_el/dq^2`` minus the exact pressure stiffness ``d(B p)/dq``
(volume actuation); the gravity and tip-load stiffness are not available in closed form, so
Broyden updates learn them from the iterates, and a backtracking line search on the residual
keeps the iteration monotone. Segments in the
paper's coordinates are solved in curvature coordinates (the balance is the same, and
regular through the straight pose) and the result is mapped back.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..checks.bounds import FORCE, PRESSURE, TIME, Range
from .chain import Chain
from ..checks.convert import as_bool, as_vector
from ..errors import QchainError
from .tendons import check_tension

__all__ = ["equilibrium", "EquilibriumResult"]


@dataclass
class EquilibriumResult:
    """Result of :func:`equilibrium`.

    Attributes
    ----------
    q : (nq,)  the equilibrium configuration (the last iterate if not converged).
    success : bool
    message : str
    iterations : int
    residual : float  ``|F(q)|_inf`` in the generalised-force units of each coordinate (N, N m^2).
    nfev : int        residual evaluations.
    """

    q: np.ndarray
    success: bool
    message: str
    iterations: int
    residual: float
    nfev: int


def _stiffness(chain: Chain, q: np.ndarray, p: np.ndarray, env=None, t: float = 0.0, T=None) -> np.ndarray:
    """Newton matrix of ``-F``: elastic minus pressure stiffness, minus the tendons' and the
    environment's (all exact)."""
    K = chain.elastic_stiffness(q) - chain.pressure_stiffness(q, p)
    if T is not None:
        K = K - chain.tendon_stiffness(q, T)
    if env is not None:
        K = K - chain.environment_force_derivatives(q, np.zeros(chain.nv), env, t)[0]
    return K


def equilibrium(chain: Chain, p=None, q0=None, tip_wrench=None, *, t: float = 0.0, tol: float = 1e-10,
                max_iter: int = 200, continuation: bool = True, env=None, tension=None) -> EquilibriumResult:
    """Static shape of ``chain`` under pressures ``p`` (3 n,) Pa, tendon tensions and gravity.

    Parameters
    ----------
    chain : Chain
        Fixed or prescribed base (a prescribed base is held at its placement at ``t``).
    p : (3 n,) Pa, optional
        Within :data:`qchain.checks.bounds.PRESSURE`; ``tip_wrench`` within
        :data:`qchain.checks.bounds.FORCE`; ``q0`` inside the model's domain.
    q0 : (nq,), optional
        Starting guess (default ``chain.neutral()``).
    tip_wrench : (6,), optional
        ``[force (N); torque (N m)]`` on the tip, world axes, applied at the tip origin.
    t : float, s
        Time of a prescribed base's placement, within +-1e12 s.
    max_iter : int
        Newton iterations, 1 to 100000.
    tol : float
        In (0, 1). Converged when every residual entry is below ``tol`` times the scale of the
        generalised forces (the largest of the elastic, pressure and gravity terms at q0).
    continuation : bool
        If Newton fails from ``q0``, follow the solution from the unloaded shape as
        gravity, pressures and tip load grow from zero (steps halved on failure).
    env : qchain.contact.Environment, optional
        Obstacles and point loads: their generalised force at rest joins the balance, and
        its exact stiffness (:meth:`qchain.Chain.environment_force_derivatives`) the Newton
        matrix. At rest the regularised friction is zero (it needs sliding to act): a
        static shape holds by normal forces and loads alone.
    tension : (nt,) N, optional
        The tensions of the chain's tendons, each within :data:`qchain.checks.bounds.TENSION`
        (``>= 0``): ``B_T(q) T`` joins the balance and its exact stiffness
        (:meth:`qchain.Chain.tendon_stiffness`) the Newton matrix (docs/tendons.md).
    """
    if not isinstance(chain, Chain):
        raise TypeError(f"chain must be a qchain.Chain, got {type(chain).__name__}")
    if chain.floating:
        raise ValueError("equilibrium needs a fixed or prescribed base: a floating arm has no static shape")
    tol = Range(0.0, 1.0, low_open=True, high_open=True).check("tol", tol)
    max_iter = Range(1, 100_000, integer=True).check("max_iter", max_iter)
    t = TIME.check("t", t)
    continuation = as_bool("continuation", continuation)
    if p is not None:  # checked here, where they enter: real, finite, within their declared ranges
        p = PRESSURE.check_array("p", as_vector("p", p, chain.nu))
    if tension is not None:
        tension = check_tension(tension, chain.nt)
    if tip_wrench is not None:
        tip_wrench = FORCE.check_array("tip_wrench", as_vector("tip_wrench", tip_wrench, 6))
    if q0 is not None:
        q0 = as_vector("q0", chain._q(q0, "q0"), chain.nq)
        chain._state(q0, t=t)  # inside the model (DomainError naming the segment)
    if chain._any_paper and not chain._linear[chain._paper].any():
        # the balance is coordinate-free: solve it where it is regular and map the result back
        twin = _scaled(chain, 1.0, [dataclasses.replace(s, coords="curvature") for s in chain.segments])
        q0c = None
        if q0 is not None:
            q0c = chain._q(q0, "q0").copy()
            for j, s in enumerate(chain.segments):
                q0c[chain.q_slice(j)] = s.to_curvature(q0c[chain.q_slice(j)])
        res = equilibrium(twin, p, q0c, tip_wrench, t=t, tol=tol, max_iter=max_iter, continuation=continuation,
                          env=env, tension=tension)
        for j, s in enumerate(chain.segments):
            res.q[chain.q_slice(j)] = s.from_curvature(res.q[chain.q_slice(j)])
        return res
    res = _solve(chain, p, q0, tip_wrench, t, tol, max_iter, env, tension)
    if res.success or not continuation:
        return res
    p = np.zeros(chain.nu) if p is None else as_vector("p", p, chain.nu)
    w = np.zeros(6) if tip_wrench is None else as_vector("tip_wrench", tip_wrench, 6)
    lam, step, q, total = 0.0, 0.25, (chain.neutral() if q0 is None else q0), res.nfev
    while lam < 1.0:
        trial = min(1.0, lam + step)
        scaled = _scaled(chain, trial)
        r = _solve(scaled, trial * p, q, trial * w, t, tol, max_iter, env,
                   None if tension is None else trial * tension)
        total += r.nfev
        if r.success:
            lam, q = trial, r.q
            step = min(2 * step, 0.5)
        else:
            step /= 2
            if step < 1e-4:
                return EquilibriumResult(r.q, False, f"continuation stalled at load factor {lam:.4g}: {r.message}",
                                         r.iterations, r.residual, total)
    return EquilibriumResult(q, True, "converged (load continuation)", r.iterations, r.residual, total)


def _scaled(chain: Chain, lam: float, segments=None) -> Chain:
    """The same chain with gravity scaled by ``lam`` (and other ``segments``, if given)."""
    return Chain(chain.segments if segments is None else segments, base=chain.base, gravity=lam * chain.gravity,
                 base_placement=chain.base_placement if chain.base == "fixed" else None,
                 base_motion=chain.base_motion, planar=chain.planar, tendons=chain.tendons)


def _solve(chain, p, q0, tip_wrench, t, tol, max_iter, env=None, T=None) -> EquilibriumResult:
    p = np.zeros(chain.nu) if p is None else as_vector("p", p, chain.nu)
    q = chain.neutral() if q0 is None else chain._q(q0, "q0").copy()
    w = None if tip_wrench is None else as_vector("tip_wrench", tip_wrench, 6)
    idx = np.flatnonzero(chain.active)
    zero_v = np.zeros(chain.nv)
    nfev = 0

    def F(q):
        nonlocal nfev
        nfev += 1
        f = chain.internal_forces(q, zero_v, p) - chain.generalized_gravity(q, t=t)
        if w is not None:
            f += chain.tip_jacobian(q, "local_world_aligned", t=t).T @ w
        if env is not None:
            f += chain.environment_force(q, zero_v, env, t)
        if T is not None:
            f += chain.tendon_force(q, T)
        return f[idx]

    def with_step(q, dx):
        d = np.zeros(chain.nv)
        d[idx] = dx
        return chain.integrate(q, d)

    try:
        r = F(q)
    except QchainError as err:
        raise QchainError(f"equilibrium: the starting guess is not a valid configuration: {err}") from None
    scale = max(np.max(np.abs(r)), np.max(np.abs(chain.elastic_force(q)[idx])), 1e-12)
    scale = max(scale, np.max(np.abs(chain.input_matrix(q)[idx] @ p)) if p.any() else 0.0)
    scale = max(scale, np.max(np.abs(chain.tendon_force(q, T)[idx])) if T is not None and T.any() else 0.0)
    W = _stiffness(chain, q, p, env, t, T)[np.ix_(idx, idx)]  # of -F
    col = np.sqrt(np.abs(np.diag(W))) + 1e-300  # residual scaling: N vs N m^2 per coordinate
    fresh = True
    it = 0
    for it in range(1, max_iter + 1):
        if np.max(np.abs(r)) <= tol * scale:
            return EquilibriumResult(q, True, "converged", it - 1, float(np.max(np.abs(r))), nfev)
        try:
            dx = np.linalg.solve(W, r)
        except np.linalg.LinAlgError:
            W = _stiffness(chain, q, p, env, t, T)[np.ix_(idx, idx)]
            dx = np.linalg.lstsq(W, r, rcond=None)[0]
        step = 1.0
        while True:
            try:
                q_new = with_step(q, step * dx)
                r_new = F(q_new)
                if np.linalg.norm(r_new / col) < np.linalg.norm(r / col):
                    break
            except QchainError:
                pass
            step *= 0.5
            if step < 1e-4:
                break
        if step < 1e-4:
            if fresh:
                return EquilibriumResult(q, False, "line search failed: no decrease along the Newton step",
                                         it, float(np.max(np.abs(r))), nfev)
            W = _stiffness(chain, q, p, env, t, T)[np.ix_(idx, idx)]  # drop the Broyden history and retry
            fresh = True
            continue
        fresh = False
        s_ = step * dx
        y_ = -(r_new - r)  # change of -F
        W = W + np.outer(y_ - W @ s_, s_) / (s_ @ s_)  # good Broyden update
        if it % 10 == 0:  # refresh the exact part now and then
            W = _stiffness(chain, q_new, p, env, t, T)[np.ix_(idx, idx)]
        q, r = q_new, r_new
    return EquilibriumResult(q, False, f"no convergence in {max_iter} iterations", it,
                             float(np.max(np.abs(r))), nfev)
