"""The tendons of a :class:`qchain.Chain`: their lengths, input matrix and its derivative.

A tendon (:class:`qchain.model.tendon.Tendon`) passes the segments ``0 .. end`` and its
length is the sum of its lengths through them (:func:`qchain.model.tendon.tendon_length_c`).
A tension ``T >= 0`` (N) does the virtual work ``-T dL``, so its generalised force is

    tau_T = B_T(q) T,   B_T[:, k] = -dL_k/dq   (nv, m),

zero on the base rows (a tendon anchored in the base and ending on the arm is internal: it
pulls the base as much as the arm) and on the segments past the tendon's end. In paper
coordinates ``B_T^e = J^T B_T^c`` segment by segment (docs/model.md section 1), as for the
chambers. docs/tendons.md derives it and lists the checks.
"""

from __future__ import annotations

import numpy as np

from ..checks.bounds import TENSION
from ..checks.convert import as_vector
from ..errors import DomainError
from ..model.arc import arc_nodes
from ..model.segment import _paper_hessian_term
from ..model.tendon import Tendon, helix_nodes, tendon_length_c

__all__ = ["ChainTendons", "check_tension", "tendon_table"]


def tendon_table(tendons, segments) -> tuple:
    """The checked tendons of a chain of ``segments`` and their routing as one flat table:
    ``(tendons, rows, nodes, weights)`` with ``rows (R, 7)`` float, one row a (tendon,
    segment) pair it passes: ``k, j, r, phi, omega, node start, node stop`` and the helical
    rows' quadrature nodes and weights (:func:`qchain.model.tendon.helix_nodes`) in
    ``nodes[start:stop]``."""
    if isinstance(tendons, (Tendon, str, bytes)) or not hasattr(tendons, "__iter__"):
        raise TypeError(f"tendons must be a sequence of qchain.Tendon, got {type(tendons).__name__}")
    tendons = tuple(tendons)
    n = len(segments)
    rows, nodes, weights = [], [], []
    o = 0
    for k, td in enumerate(tendons):
        if not isinstance(td, Tendon):
            raise TypeError(f"tendons[{k}] must be a qchain.Tendon, got {type(td).__name__}")
        end = n - 1 if td.end is None else td.end
        if end >= n:
            raise ValueError(f"tendons[{k}].end must be a segment index < {n} (the chain's segments), got {td.end}")
        phi, omega = td.routing([s.length for s in segments[: end + 1]])
        for j in range(end + 1):
            x, w = helix_nodes(float(omega[j]))
            rows.append((k, j, td.radius, phi[j], omega[j], o, o + x.size))
            nodes.append(x)
            weights.append(w)
            o += x.size
    table = np.array(rows, dtype=float).reshape(-1, 7)
    nodes = np.concatenate(nodes) if nodes else np.zeros(0)
    weights = np.concatenate(weights) if weights else np.zeros(0)
    for a in (table, nodes, weights):
        a.flags.writeable = False
    return tendons, table, nodes, weights


def check_tension(T, m: int, name: str = "tension") -> np.ndarray:
    """Tensions ``T`` (m,) N as a new float array: finite and within
    :data:`qchain.checks.bounds.TENSION` (a tendon pulls; it cannot push: a negative tension is
    refused with its index and value)."""
    T = np.array(as_vector(name, T, m), dtype=float)
    return TENSION.check_array(name, T)


class ChainTendons:
    """Tendon methods of :class:`qchain.Chain` (its ``tendons``, ``nt`` and routing table)."""

    def _tendon_pass(self, q, hessian: bool):
        """``(st, L (m,), G (n, m, 3), H (n, m, 3, 3) or None)``: the tendons' lengths and, per
        segment, the gradient (and Hessian) of each tendon's length through it in curvature
        coordinates; the domain ``kappa r < 1`` checked."""
        st = self._state(q)
        m = self.nt
        L = np.zeros(m)
        G = np.zeros((self.n, m, 3))
        H = np.zeros((self.n, m, 3, 3)) if hessian else None
        g = np.empty(3)
        h = np.empty((3, 3))
        x, w = self._tendon_nodes, self._tendon_weights
        for k, j, r, phi, omega, a, b in self._tendon_rows:
            k, j, a, b = int(k), int(j), int(a), int(b)
            qc = st.q_c[j]
            kr = np.hypot(qc[1], qc[2]) * r
            if not kr < 1.0:
                sl = self.q_slice(j)
                raise DomainError(f"segment {j} (q[{sl.start}:{sl.stop}]): kappa r = {kr:.6g} for tendons[{k}] "
                                  f"(radius {r:g} m) must be < 1: the tendon's fibre would have no length")
            L[k] += tendon_length_c(qc, r, phi, omega, x[a:b], w[a:b], hessian, g, h)
            G[j, k] = g
            if hessian:
                H[j, k] = h
        return st, L, G, H

    def tendon_lengths(self, q) -> np.ndarray:
        """The tendons' lengths ``L`` (m,) m from the base to their ends at ``q``
        (docs/tendons.md)."""
        return self._tendon_pass(q, False)[1]

    def tendon_matrix(self, q) -> np.ndarray:
        """The tendons' input matrix ``B_T(q)`` (nv, m): column ``k = -dL_k/dq``, the
        generalised force of a unit tension (N, N m) of tendon ``k``, exact; zero on the base
        and on the segments past the tendon's end (docs/tendons.md)."""
        st, _, G, _ = self._tendon_pass(q, False)
        Bt = np.zeros((self.nv, self.nt))
        for j in range(self.n):
            Ge = G[j] if st.J is None else G[j] @ st.J[j]  # (m, 3): dL/dq_e = J^T dL/dq_c
            Bt[self.v_slice(j)] = -Ge.T
        return Bt

    def tendon_force(self, q, tension) -> np.ndarray:
        """``B_T(q) T`` (nv,): the generalised force of the tensions ``T`` (m,) N, each within
        :data:`qchain.checks.bounds.TENSION` (``>= 0``: a tendon cannot push)."""
        T = check_tension(tension, self.nt)
        return self.tendon_matrix(q) @ T

    def _with_tendons(self, q, tau, tension):
        """``tau + B_T(q) T`` (nv,) (``tau`` None: zeros), the tensions checked."""
        tt = self.tendon_force(q, tension)
        return tt if tau is None else self._vec("tau", tau, self.nv) + tt

    def tendon_stiffness(self, q, tension) -> np.ndarray:
        """``d(B_T(q) T)/dq`` (nv, nv), exact: ``-sum_k T_k d^2 L_k/dq^2``, block-diagonal, zero
        on the base; in paper coordinates with the chain rule's second-order term, as
        :meth:`qchain.Segment.pressure_stiffness`."""
        T = check_tension(tension, self.nt)
        st, _, G, H = self._tendon_pass(q, True)
        K = np.zeros((self.nv, self.nv))
        for j in range(self.n):
            Kc = -np.einsum("k,kab->ab", T, H[j])
            if st.J is not None and self._paper[j]:
                gc = -T @ G[j]  # the generalised force in curvature coordinates
                Kc = st.J[j].T @ Kc @ st.J[j] + _paper_hessian_term(st.q_e[j], gc)
            K[self.v_slice(j), self.v_slice(j)] = Kc
        return K

    def tendon_paths(self, q, points_per_segment: int = 20, t: float = 0.0) -> list[np.ndarray]:
        """World points along each tendon (m): a list of ``nt`` arrays ``(P, 3)``, from the base
        to the tendon's end, ``points_per_segment`` (>= 2) evenly in ``alpha`` on each segment
        it passes (for drawing; the helix's angle from :meth:`qchain.Tendon.routing`)."""
        if isinstance(points_per_segment, bool) or not isinstance(points_per_segment, (int, np.integer)) \
                or not 2 <= points_per_segment <= 10_000:
            raise ValueError(f"points_per_segment must be an integer from 2 to 10000, got {points_per_segment!r}")
        st = self._state(q, t=t)
        roots = self.placements(q, t)
        alpha = np.linspace(0.0, 1.0, int(points_per_segment))
        paths = [[] for _ in self.tendons]
        for k, j, r, phi, omega, _, _ in self._tendon_rows:
            k, j = int(k), int(j)
            nodes = arc_nodes(alpha, st.q_c[j])
            ang = phi + omega * alpha
            rho = r * np.stack([np.cos(ang), np.sin(ang), np.zeros_like(ang)], axis=1)
            local = nodes.p + np.einsum("nab,nb->na", nodes.R, rho)
            X = roots[j]
            paths[k].append(local @ X.rotation.T + X.translation)
        return [np.concatenate(pk) for pk in paths]
