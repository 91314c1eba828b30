"""Tendons: the fibre length of a tendon through one segment and its exact derivatives.

A tendon runs at the offset ``r`` from the backbone, at the angle ``phi(alpha)`` about the
segment's root ``z`` axis (the chamber angles' convention, docs/model.md section 1): straight
(``phi`` constant) or helical (``phi(alpha) = phi_0 + omega alpha``, ``omega = 2 pi l0 /
pitch``), fixed to the material of the cross-sections it crosses and free to slide along
its path. Its length through a segment in curvature coordinates ``q = (l, ux, uy)`` is

    L(q) = int_0^1 sqrt(a^2 + z(alpha)^2) dalpha,   z = l (1 - r (ux cos phi + uy sin phi)),
    a = r omega,

the arc length of the material fibre on the deformed segment (docs/tendons.md derives it).
A straight tendon (``omega = 0``) has the closed form ``L = z``, the chamber fibre of
:func:`qchain.model.slices.input_matrix_c`; a helical one is an elliptic-type integral,
evaluated by composite Gauss-Legendre quadrature (:func:`helix_nodes`) whose gradient and
Hessian are the exact derivatives of the quadrature. A tension ``T`` does the virtual work
``-T dL``: its generalised force is ``-T dL/dq`` (the tendon's column of the input matrix).

Unchecked by design (``docs/engine.md``, "Unchecked kernels"): :class:`Tendon` checks a
tendon's description, :class:`qchain.Chain` the configurations.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..checks import bounds as B
from ..checks.convert import as_real, describe_value
from .._jit import jit

__all__ = ["Tendon", "tendon_length_c", "helix_nodes", "HELIX_PANEL", "HELIX_PANEL_NODES"]

#: The largest turn (rad) of a helical tendon one quadrature panel covers.
HELIX_PANEL = math.pi / 4.0
#: Gauss-Legendre nodes a panel.
HELIX_PANEL_NODES = 12


@dataclass(frozen=True, kw_only=True, eq=False)
class Tendon:
    """A tendon routed at an offset from the backbone of a :class:`qchain.Chain`.

    Parameters
    ----------
    radius : float
        Offset ``r`` from the backbone (m), ``0 < r <= 10``
        (:data:`qchain.checks.bounds.TENDON_RADIUS`). Every configuration must keep
        ``kappa r < 1`` in the segments it passes (the fibre's length stays positive).
    angle : float
        Angle ``phi`` of the tendon about the base segment's root ``z`` axis at the base
        (rad), within +-1e3 rad (:data:`qchain.checks.bounds.ANGLE`); ``phi = 0`` is the root
        ``+x`` axis, where chamber 1 lies.
    pitch : float or None
        None: a straight tendon, parallel to the backbone. A number: a helix that turns once
        (``2 pi`` about the backbone) in ``|pitch|`` metres of rest length, ``1e-4 <= |pitch|
        <= 1e6`` (:data:`qchain.checks.bounds.TENDON_PITCH`); ``pitch > 0`` turns positively
        about the backbone's ``z`` axis (right-handed), ``pitch < 0`` the other way.
    end : int or None
        The segment at whose tip the tendon ends (0 is the base segment); None: the last
        segment (the arm's tip). Checked against the chain it is put on.
    """

    radius: float
    angle: float = 0.0
    pitch: float | None = None
    end: int | None = None

    def __post_init__(self):
        s = object.__setattr__
        s(self, "radius", B.TENDON_RADIUS.check("radius", self.radius))
        s(self, "angle", B.ANGLE.check("angle", self.angle))
        if self.pitch is not None:
            p = as_real("pitch", self.pitch)
            if not math.isfinite(p) or not B.TENDON_PITCH.low <= abs(p) <= B.TENDON_PITCH.high:
                raise ValueError(f"pitch must be None (a straight tendon) or a number with |pitch| "
                                 f"{B.TENDON_PITCH.text()} (qchain.checks.bounds.TENDON_PITCH), got {p!r} m")
            s(self, "pitch", p)
        end = self.end
        if end is not None and (isinstance(end, (bool, np.bool_)) or not isinstance(end, (int, np.integer)) or end < 0):
            raise ValueError(f"end must be None (the arm's tip) or a segment index >= 0, got {describe_value(end)}")
        if self.end is not None:
            s(self, "end", int(self.end))

    @property
    def helical(self) -> bool:
        """Whether the tendon turns about the backbone."""
        return self.pitch is not None

    def routing(self, lengths) -> tuple[np.ndarray, np.ndarray]:
        """``(phi, omega)``, each ``(k,)``, of the ``k = len(lengths)`` segments the tendon
        passes: its angle at each segment's root (rad) and its turn along it (rad), from the
        segments' rest lengths ``lengths`` (m). A helix turns with the material: its angle at
        a segment's root is ``angle + 2 pi (rest length before it) / pitch``."""
        l0 = np.asarray(lengths, dtype=float)
        if self.pitch is None:
            return np.full(l0.size, self.angle), np.zeros(l0.size)
        before = np.concatenate([[0.0], np.cumsum(l0)[:-1]])
        return self.angle + 2.0 * np.pi * before / self.pitch, 2.0 * np.pi * l0 / self.pitch


def helix_nodes(omega: float) -> tuple[np.ndarray, np.ndarray]:
    """Quadrature nodes ``alpha`` in [0, 1] and weights (summing to 1) for a tendon that turns
    by ``omega`` (rad) along a segment: :data:`HELIX_PANEL_NODES` Gauss-Legendre nodes on each
    of ``ceil(|omega| / HELIX_PANEL)`` equal panels. A straight tendon (``omega = 0``) needs
    none (its length is closed-form): empty arrays. docs/tendons.md gives the accuracy."""
    if omega == 0.0:
        return np.zeros(0), np.zeros(0)
    panels = max(1, math.ceil(abs(omega) / HELIX_PANEL))
    x, w = np.polynomial.legendre.leggauss(HELIX_PANEL_NODES)
    x = 0.5 * (x + 1.0) / panels
    w = 0.5 * w / panels
    starts = np.arange(panels) / panels
    return (starts[:, None] + x[None, :]).ravel(), np.tile(w, panels)


@jit
def tendon_length_c(q, r, phi, omega, alpha, w, hessian, g, H):
    """The length ``L`` (m) of a tendon through one segment, returned, with ``g[:] = dL/dq``
    (3,) and, if ``hessian``, ``H[:] = d^2 L/dq^2`` (3, 3), curvature coordinates
    ``q = (l, ux, uy)``, exact.

    ``r`` offset (m), ``phi`` angle at the segment's root (rad), ``omega`` turn along the
    segment (rad): 0 for a straight tendon (closed form, ``alpha`` and ``w`` unused), else the
    quadrature nodes and weights of :func:`helix_nodes` (the derivatives are those of the
    quadrature, so exact for the ``L`` returned). Needs ``kappa r < 1`` (unchecked).
    """
    l, ux, uy = q[0], q[1], q[2]
    for i in range(3):
        g[i] = 0.0
        if hessian:
            for k in range(3):
                H[i, k] = 0.0
    if omega == 0.0:
        c = math.cos(phi)
        s = math.sin(phi)
        h = 1.0 - r * (ux * c + uy * s)
        g[0] = h
        g[1] = -l * r * c
        g[2] = -l * r * s
        if hessian:
            H[0, 1] = H[1, 0] = -r * c
            H[0, 2] = H[2, 0] = -r * s
        return l * h
    a = r * omega
    a2 = a * a
    L = 0.0
    for k in range(alpha.shape[0]):
        ph = phi + omega * alpha[k]
        c = math.cos(ph)
        s = math.sin(ph)
        h = 1.0 - r * (ux * c + uy * s)
        z = l * h
        f = math.sqrt(a2 + z * z)
        wk = w[k]
        L += wk * f
        # dz/dq
        d0 = h
        d1 = -l * r * c
        d2 = -l * r * s
        zf = wk * z / f
        g[0] += zf * d0
        g[1] += zf * d1
        g[2] += zf * d2
        if hessian:
            # d2 f = a^2 dz dz^T / f^3 + z d2z / f, d2z nonzero only in (l, ux), (l, uy)
            e = wk * a2 / (f * f * f)
            H[0, 0] += e * d0 * d0
            H[0, 1] += e * d0 * d1 - zf * r * c
            H[0, 2] += e * d0 * d2 - zf * r * s
            H[1, 1] += e * d1 * d1
            H[1, 2] += e * d1 * d2
            H[2, 2] += e * d2 * d2
    if hessian:
        H[1, 0] = H[0, 1]
        H[2, 0] = H[0, 2]
        H[2, 1] = H[1, 2]
    return L
