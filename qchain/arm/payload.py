"""A rigid tip payload: the check of :class:`qchain.Chain`'s ``payload=`` argument and the
spatial inertia the compiled passes read (``ChainArrays.payload``).

The payload is a rigid body fixed at the arm's tip frame (root ``n``): a
``pinocchio.Inertia(mass, lever, inertia)`` with ``mass`` (kg), ``lever`` its centre of mass
(3,) m in the tip frame, ``inertia`` (3, 3) kg m^2 about the centre of mass, tip-frame axes.
Its spatial inertia at the tip origin is ``Inertia.matrix()`` (Pinocchio's ``[linear;
angular]``). Every pass (``rnea``, ``crba``, ``aba``, the planar passes, the derivatives)
starts its backward sweep from it; all zeros is no payload.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..checks.bounds import Range
from ..checks.text import show_matrix, show_vector

__all__ = ["PAYLOAD_MASS", "PAYLOAD_LEVER", "PAYLOAD_INERTIA", "payload_matrix", "planar_consistent",
           "inertia_problem"]

#: the payload's mass (0: none; up to the heaviest segment's bound, qchain.checks.bounds.MASS)
PAYLOAD_MASS = Range(0.0, 1e6, "kg")
#: each component of the payload's centre of mass in the tip frame (a segment's length bound)
PAYLOAD_LEVER = Range(-1e2, 1e2, "m")
#: each entry of the payload's rotational inertia about its centre of mass
PAYLOAD_INERTIA = Range(-1e10, 1e10, "kg m^2")
#: relative tolerance of the symmetry and positive semi-definiteness of the rotational inertia
_PSD_TOL = 1e-12


def payload_matrix(payload, planar: bool) -> tuple[pin.Inertia | None, np.ndarray]:
    """``payload`` (a ``pinocchio.Inertia`` or None), checked: a copy of it (None for None or
    a zero mass) and its spatial inertia (6, 6) at the tip origin (zeros for none).

    Raises
    ------
    TypeError
        ``payload`` is neither None nor a ``pinocchio.Inertia``.
    ValueError
        A mass, lever or inertia entry is not finite or outside its range
        (:data:`PAYLOAD_MASS`, :data:`PAYLOAD_LEVER`, :data:`PAYLOAD_INERTIA`), the rotational
        inertia is not symmetric or not positive semi-definite, a zero mass carries a
        rotational inertia, or (``planar``) the payload is not symmetric about the x-z plane.
    """
    if payload is None:
        return None, np.zeros((6, 6))
    if not isinstance(payload, pin.Inertia):
        raise TypeError(f"payload must be a pinocchio.Inertia(mass, lever, inertia) or None, got "
                        f"{type(payload).__name__}")
    m = PAYLOAD_MASS.check("payload.mass", float(payload.mass))
    c = PAYLOAD_LEVER.check_array("payload.lever", np.array(payload.lever, dtype=float))
    I = np.array(payload.inertia, dtype=float)
    PAYLOAD_INERTIA.check_array("payload.inertia", I)
    why = inertia_problem(I)
    if why is not None:
        raise ValueError(f"payload.inertia must be symmetric and positive semi-definite (a rigid body's rotational "
                         f"inertia), got {why}")
    if m == 0.0 and np.abs(I).max() > 0.0:
        raise ValueError("payload.mass is 0 but payload.inertia is not: a body without mass has no rotational "
                         "inertia (use payload=None for no payload)")
    inertia = pin.Inertia(m, c, 0.5 * (I + I.T))
    P = inertia.matrix()
    if planar and not planar_consistent(P):
        raise ValueError("planar=True needs a payload symmetric about the base's x-z plane (lever[1] = 0, y a "
                         f"principal axis of payload.inertia: inertia[0, 1] = inertia[1, 2] = 0), got lever "
                         f"{show_vector(c)} m and inertia {show_matrix(I)} kg m^2")
    return (inertia if m > 0.0 else None), P


def planar_consistent(P: np.ndarray) -> bool:
    """Whether the spatial inertia ``P`` (6, 6) couples no in-plane component (0, 2, 4) to an
    out-of-plane one (1, 3, 5): the condition of :mod:`qchain.algorithms.planar`'s reduction."""
    even, odd = [0, 2, 4], [1, 3, 5]
    return not np.any(P[np.ix_(even, odd)])


def inertia_problem(I: np.ndarray) -> str | None:
    """Why the (3, 3) matrix ``I`` (kg m^2) is not a rigid body's rotational inertia
    (symmetric and positive semi-definite, to a relative 1e-12 of its largest entry), or None."""
    I = np.asarray(I, dtype=float)
    scale = max(float(np.abs(I).max()), np.finfo(float).tiny)
    if np.abs(I - I.T).max() > _PSD_TOL * scale:
        return f"a matrix that is not symmetric, {show_matrix(I)} kg m^2"
    eig = np.linalg.eigvalsh(0.5 * (I + I.T))
    if eig.min() < -_PSD_TOL * scale:
        return f"a matrix that is not positive semi-definite, eigenvalues {show_vector(eig)} kg m^2"
    return None
