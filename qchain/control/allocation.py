"""Pressure allocation, in one place: the chamber pressures that realise a wanted
generalised force ``tau`` within the chambers' bounds.

The paper's dynamics are affine in the pressures (eq. (9): ``... = B(q) p``), so a
controller that asks for ``tau`` on the free coordinates gets ``p`` from the bounded
least-squares problem

    min_p |B p - tau|^2 + w^2 |p|^2    subject to    p_min <= p <= p_max

(``scipy.optimize.lsq_linear``, bounded-variable least squares). The small penalty ``w``
picks the least pressure where ``B`` has a null space: equal pressure in a segment's three
chambers does not bend it, and for an inextensible segment (``l`` locked) ``B`` has two rows
and three columns. The penalty costs a relative residual of about ``(w / sigma_min(B))^2``,
far below the model's accuracy for the default ``w``; a larger residual means the bounds
bind: the force asked for is not one the chambers can make, and :class:`Allocation` says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import lsq_linear

__all__ = ["Allocation", "allocate", "PENALTY_SCALE", "SATURATION"]

#: Default penalty ``w`` as a fraction of the largest entry of ``B`` (N m^2/Pa per N m^2/Pa).
PENALTY_SCALE = 2.5e-4
#: Relative residual ``|B p - tau| / |tau|`` above which the allocation counts as saturated:
#: the penalty alone leaves ~1e-7 (see the module docstring).
SATURATION = 1e-3


@dataclass(frozen=True)
class Allocation:
    """The pressures for one wanted force and how well they realise it.

    Attributes
    ----------
    p : (m,) Pa
        The chamber pressures, within ``[p_min, p_max]``.
    realised : (k,)
        ``B p``: the generalised force the pressures make (units of ``tau``).
    residual : float
        ``|B p - tau|`` (Euclidean norm, units of ``tau``).
    at_lower, at_upper : int
        Chambers at the lower and upper bound.
    saturated : bool
        ``residual > SATURATION * |tau|``: the bounds bind and ``tau`` is not realised.
    """

    p: np.ndarray
    realised: np.ndarray
    residual: float
    at_lower: int
    at_upper: int
    saturated: bool


def allocate(B: np.ndarray, tau: np.ndarray, p_min: float, p_max: float, penalty: float) -> Allocation:
    """The pressures ``p`` (m,) Pa realising ``tau`` (k,) through ``B`` (k, m) within
    ``[p_min, p_max]`` Pa with the least-pressure penalty ``penalty`` (units of ``B``);
    see the module docstring. The arguments are the caller's checked arrays."""
    m = B.shape[1]
    # Solved in units where the pressures and B's entries are of order one: lsq_linear's
    # tolerances are absolute-ish, and B of ~1e-8 N m^2/Pa with p of ~1e4 Pa otherwise stops
    # it far from the optimum (same minimiser: the objective is scaled by bs^2).
    ps = max(abs(p_min), abs(p_max))
    bs = max(float(np.abs(B).max()) * ps, np.finfo(float).tiny)
    A = np.vstack([B * (ps / bs), (penalty * ps / bs) * np.eye(m)])
    b = np.concatenate([tau / bs, np.zeros(m)])
    res = lsq_linear(A, b, bounds=(p_min / ps, p_max / ps), method="bvls")
    p = np.clip(res.x * ps, p_min, p_max)  # bvls returns the bounds themselves; clip guards round-off
    realised = B @ p
    residual = float(np.linalg.norm(realised - tau))
    return Allocation(p=p, realised=realised, residual=residual, at_lower=int(np.count_nonzero(p <= p_min)),
                      at_upper=int(np.count_nonzero(p >= p_max)),
                      saturated=bool(residual > SATURATION * np.linalg.norm(tau)))
