"""Independent brute-force references for the tests: material particles, written from the
paper's closed-form kinematics and density field, sharing no code with ``qchain``.

A particle of a segment is labelled ``(alpha, r, phi)``: slice ``alpha`` in [0, 1], radius
``r`` in [0, r_s], angle ``phi``. The paper places it at
``x = d(s) + R(s) (r cos phi, r sin phi, 0)``, ``s = alpha l``, with
``R(s) = Rz(psi) Ry(kappa s) Rz(psi)^T`` and ``d(s) = Rz(psi) ((1 - cos kappa s)/kappa, 0,
sin(kappa s)/kappa)``, and gives it the mass ``rho dV`` with the density field
``rho = rho0 l0 / (l (1 - kappa r cos(psi - phi)))`` and the volume element
``dV = r l (1 - kappa r cos(psi - phi)) dalpha dr dphi``.

Time derivatives are taken exactly with second-order Taylor jets (``Jet``): evaluating
the closed form along ``q(t) = q + t qdot`` gives ``x``, ``xdot`` and ``xddot`` (for
``qddot = 0``) to rounding error.
"""

from __future__ import annotations

import numpy as np


class Jet:
    """Truncated Taylor polynomial ``c0 + c1 t + c2 t^2`` with array coefficients."""

    def __init__(self, c0, c1=0.0, c2=0.0):
        self.c = [np.asarray(c0, float), np.asarray(c1, float), np.asarray(c2, float)]

    @staticmethod
    def lift(x):
        return x if isinstance(x, Jet) else Jet(x)

    def __add__(self, o):
        o = Jet.lift(o)
        return Jet(*(a + b for a, b in zip(self.c, o.c)))

    __radd__ = __add__

    def __neg__(self):
        return Jet(*(-a for a in self.c))

    def __sub__(self, o):
        return self + (-Jet.lift(o))

    def __rsub__(self, o):
        return Jet.lift(o) - self

    def __mul__(self, o):
        o = Jet.lift(o)
        a, b = self.c, o.c
        return Jet(a[0] * b[0], a[0] * b[1] + a[1] * b[0], a[0] * b[2] + a[1] * b[1] + a[2] * b[0])

    __rmul__ = __mul__

    def recip(self):
        a0, a1, a2 = self.c
        return Jet(1 / a0, -a1 / a0**2, a1**2 / a0**3 - a2 / a0**2)

    def __truediv__(self, o):
        return self * Jet.lift(o).recip()

    def __rtruediv__(self, o):
        return Jet.lift(o) * self.recip()

    def sin(self):
        a0, a1, a2 = self.c
        s, c = np.sin(a0), np.cos(a0)
        return Jet(s, c * a1, c * a2 - 0.5 * s * a1**2)

    def cos(self):
        a0, a1, a2 = self.c
        s, c = np.sin(a0), np.cos(a0)
        return Jet(c, -s * a1, -s * a2 - 0.5 * c * a1**2)

    def sqrt(self):
        a0, a1, a2 = self.c
        r0 = np.sqrt(a0)
        r1 = a1 / (2 * r0)
        return Jet(r0, r1, (a2 - r1**2) / (2 * r0))

    @property
    def val(self):
        return self.c[0]

    @property
    def d1(self):
        return self.c[1]

    @property
    def dd(self):
        """Second time derivative (2 c2)."""
        return 2 * self.c[2]


def paper_params(q, coords):
    """``(l, cos psi, sin psi, kappa)`` as jets from a jet configuration in either coordinates."""
    if coords == "paper":
        l, psi, kappa = q
        return l, psi.cos(), psi.sin(), kappa
    l, ux, uy = q
    kappa = (ux * ux + uy * uy).sqrt()
    return l, ux / kappa, uy / kappa, kappa


def _matmul(A, B):
    return [[sum(A[i][k] * B[k][j] for k in range(3)) for j in range(3)] for i in range(3)]


def _matvec(A, x):
    return [sum(A[i][k] * x[k] for k in range(3)) for i in range(3)]


def _transpose(A):
    return [[A[j][i] for j in range(3)] for i in range(3)]


def slice_frame(q, coords, alpha):
    """``(R, d)`` of slice ``alpha`` in the segment's root frame from the paper's closed form:
    ``R = Rz(psi) Ry(kappa s) Rz(psi)^T``, ``d = Rz(psi) ((1 - cos kappa s)/kappa, 0, sin(kappa s)/kappa)``;
    R as 3x3 nested lists and d as a list of jets."""
    l, cp, sp, kappa = paper_params(q, coords)
    ks = kappa * (l * alpha)
    C, S = ks.cos(), ks.sin()
    Rz = [[cp, -sp, 0.0], [sp, cp, 0.0], [0.0, 0.0, 1.0]]
    Ry = [[C, 0.0, S], [0.0, 1.0, 0.0], [-S, 0.0, C]]
    R = _matmul(_matmul(Rz, Ry), _transpose(Rz))
    d = _matvec(Rz, [(1 - C) / kappa, 0.0, S / kappa])
    return R, d


def particle_position(q, coords, alpha, r, phi, frame=None):
    """Position of particles ``(alpha, r, phi)`` as three jets, in the segment's root frame, or in
    the frame where the root sits at ``frame = (R0, p0)`` (jets)."""
    R, d = slice_frame(q, coords, alpha)
    x = [d[i] + R[i][0] * (r * np.cos(phi)) + R[i][1] * (r * np.sin(phi)) for i in range(3)]
    if frame is None:
        return x
    R0, p0 = frame
    return [p0[i] + sum(R0[i][k] * x[k] for k in range(3)) for i in range(3)]


def particle_grid(seg, n_alpha=24, n_r=6, n_phi=24):
    """Particle labels and the quadrature weights of ``dalpha dr dphi``."""
    xa, wa = np.polynomial.legendre.leggauss(n_alpha)
    xa, wa = 0.5 * (xa + 1), 0.5 * wa
    xr, wr = np.polynomial.legendre.leggauss(n_r)
    xr, wr = 0.5 * seg.radius * (xr + 1), 0.5 * seg.radius * wr
    ph = 2 * np.pi * np.arange(n_phi) / n_phi
    wp = np.full(n_phi, 2 * np.pi / n_phi)
    A, Rr, P = np.meshgrid(xa, xr, ph, indexing="ij")
    W = np.einsum("i,j,k->ijk", wa, wr, wp)
    return A.ravel(), Rr.ravel(), P.ravel(), W.ravel()


def particle_masses(seg, q, coords, alpha, r, phi, w):
    """``rho dV`` per particle, with the paper's density field and volume element as written."""
    if coords == "paper":
        l, psi, kappa = q
    else:
        l, ux, uy = q
        psi, kappa = np.arctan2(uy, ux), np.hypot(ux, uy)
    rho0 = seg.mass / (seg.length * np.pi * seg.radius**2)
    stretch = 1 - kappa * r * np.cos(psi - phi)
    rho = rho0 * seg.length / (l * stretch)
    dV = r * l * stretch
    return rho * dV * w


def _jets(q, direction):
    return [Jet(q[i], direction[i]) for i in range(3)]


def brute_segment(seg, q, xi, gravity=np.zeros(3), grid=None):
    """Brute-force ``M_xi`` (9, 9), velocity-product force ``C_xi xi`` (9,) and ``G`` (9,).

    Uses d'Alembert's principle over the particles: with ``u = v + w x x + xdot`` (root
    coordinates) and ``J = du/dxi = [I, -[x], dx/dq]``,
    ``M = sum dm J^T J``, ``C xi = sum dm J^T (w x (v + w x x) + 2 w x xdot + xddot)``,
    ``G = -sum dm J^T g``.
    """
    coords = seg.coords
    alpha, r, phi, w = grid if grid is not None else particle_grid(seg)
    dm = particle_masses(seg, q, coords, alpha, r, phi, w)
    q = np.asarray(q, float)
    xi = np.asarray(xi, float)
    # positions and dx/dq_j
    cols = []
    for j in range(3):
        e = np.zeros(3)
        e[j] = 1.0
        X = particle_position(_jets(q, e), coords, alpha, r, phi)
        cols.append(np.stack([c.d1 for c in X], axis=-1))
        x = np.stack([c.val for c in X], axis=-1)
    dxdq = np.stack(cols, axis=-1)  # (P, 3, 3)
    P = x.shape[0]
    J = np.zeros((P, 3, 9))
    J[:, :, :3] = np.eye(3)
    J[:, 0, 4], J[:, 0, 5] = x[:, 2], -x[:, 1]  # -[x] w = w x x ... (-[x])
    J[:, 1, 3], J[:, 1, 5] = -x[:, 2], x[:, 0]
    J[:, 2, 3], J[:, 2, 4] = x[:, 1], -x[:, 0]
    J[:, :, 6:] = dxdq
    M = np.einsum("p,pai,paj->ij", dm, J, J)
    v, om, qd = xi[:3], xi[3:6], xi[6:]
    X = particle_position(_jets(q, qd), coords, alpha, r, phi)
    xdot = np.stack([c.d1 for c in X], axis=-1)
    xdd = np.stack([c.dd for c in X], axis=-1)
    acc = np.cross(om, v + np.cross(om, x)) + 2 * np.cross(om, xdot) + xdd
    Cxi = np.einsum("p,pai,pa->i", dm, J, acc)
    G = -np.einsum("p,pai,a->i", dm, J, gravity)
    return M, Cxi, G


def chamber_fibre_length(seg, q, i, n=40):
    """Length (m) of chamber ``i``'s centre fibre, integrated along the paper's kinematics."""
    xa, wa = np.polynomial.legendre.leggauss(n)
    xa, wa = 0.5 * (xa + 1), 0.5 * wa
    phi = 2 * np.pi / 3 * np.array([0, 1, -1])[i]
    qj = [Jet(v) for v in q]
    # derivative along alpha: jets in alpha
    X = particle_position(qj, seg.coords, Jet(xa, 1.0), seg.chamber_radius, phi)
    speed = np.sqrt(sum(c.d1**2 for c in X))
    return float(wa @ speed)


def tip_plate_force_matrix(seg, q):
    """The paper's ``B = A_ch [J_ci^T R k]`` from the closed form (3, 3)."""
    B = np.zeros((3, 3))
    for i in range(3):
        phi = 2 * np.pi / 3 * np.array([0, 1, -1])[i]
        for j in range(3):
            e = np.zeros(3)
            e[j] = 1.0
            X = particle_position(_jets(q, e), seg.coords, 1.0, seg.chamber_radius, phi)
            dx = np.array([c.d1 for c in X]).ravel()
            # tip normal: derivative of the backbone point along alpha, normalised
            T = particle_position([Jet(v) for v in q], seg.coords, Jet(1.0, 1.0), 0.0, 0.0)
            n = np.array([c.d1 for c in T]).ravel()
            n = n / np.linalg.norm(n)
            B[j, i] = seg.chamber_area * dx @ n
    return B


def _rows_J(x, dxdq, floating):
    """Particle velocity Jacobians ``du/dv`` (P, 3, nv): ``[I, -[x], dx/dq]`` or ``dx/dq``."""
    P = x.shape[0]
    if not floating:
        return dxdq
    J = np.zeros((P, 3, 6 + dxdq.shape[2]))
    J[:, :, :3] = np.eye(3)
    J[:, 0, 4], J[:, 0, 5] = x[:, 2], -x[:, 1]
    J[:, 1, 3], J[:, 1, 5] = -x[:, 2], x[:, 0]
    J[:, 2, 3], J[:, 2, 4] = x[:, 1], -x[:, 0]
    J[:, :, 6:] = dxdq
    return J


def _chain_positions(segments, q_e, direction):
    """All particles of a chain in the base frame, as jets along ``q_e + t direction``."""
    xs = []
    R0 = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    p0 = [0.0, 0.0, 0.0]
    for j, seg in enumerate(segments):
        qj = [Jet(q_e[j, i], direction[j, i]) for i in range(3)]
        alpha, r, phi, _ = particle_grid(seg)
        xs.append(particle_position(qj, seg.coords, alpha, r, phi, frame=(R0, p0)))
        Rt, dt = slice_frame(qj, seg.coords, 1.0)
        p0 = [p0[i] + sum(R0[i][k] * dt[k] for k in range(3)) for i in range(3)]
        R0 = _matmul(R0, Rt)
    return xs


def brute_chain(segments, q_e, v, floating, g_B):
    """Brute-force ``M`` (nv, nv) and ``C v + g`` (nv,) of a chain over material particles.

    ``q_e`` (n, 3) segment coordinates; ``v`` (nv,) with the base twist first if ``floating``;
    ``g_B`` (3,) gravity in the base frame. Particle velocities in base coordinates are
    ``u = v_B + w_B x x + xdot`` (floating) or ``xdot`` (fixed base).
    """
    n = len(segments)
    q_e = np.asarray(q_e, float)
    off = 6 if floating else 0
    v = np.asarray(v, float)
    dm = np.concatenate([
        particle_masses(seg, q_e[j], seg.coords, *particle_grid(seg)) for j, seg in enumerate(segments)
    ])
    cols = []
    for k in range(3 * n):
        d = np.zeros((n, 3))
        d.flat[k] = 1.0
        X = _chain_positions(segments, q_e, d)
        cols.append(np.concatenate([np.stack([c.d1 * np.ones_like(c.val) for c in xj], -1) for xj in X]))
        x = np.concatenate([np.stack([c.val for c in xj], -1) for xj in X])
    dxdq = np.stack(cols, axis=-1)
    J = _rows_J(x, dxdq, floating)
    M = np.einsum("p,pai,paj->ij", dm, J, J)
    X = _chain_positions(segments, q_e, v[off:].reshape(n, 3))
    xdot = np.concatenate([np.stack([c.d1 * np.ones_like(c.val) for c in xj], -1) for xj in X])
    xdd = np.concatenate([np.stack([c.dd * np.ones_like(c.val) for c in xj], -1) for xj in X])
    acc = xdd.copy()
    if floating:
        vb, wb = v[:3], v[3:6]
        acc += np.cross(wb, vb + np.cross(wb, x)) + 2 * np.cross(wb, xdot)
    nle = np.einsum("p,pai,pa->i", dm, J, acc - g_B)
    return M, nle
