"""Tendons (qchain.model.tendon, qchain.arm.tendons; docs/tendons.md): the input matrix
against finite differences and a brute-force fibre length from the arm's kinematics, the
quadrature against scipy, a straight tip tendon against its equivalent chamber pressures,
the statics of a tendon-bent segment against its closed form, and bad input."""

from __future__ import annotations

import numba
import numpy as np
import pytest
from scipy.integrate import quad

import qchain as qc
from qchain.arm.tendons import check_tension
from qchain.errors import DomainError
from qchain.model.slices import CHAMBER_ANGLES
from qchain.model.tendon import helix_nodes, tendon_length_c


def _segment(**kw):
    base = dict(length=0.2, radius=0.02, mass=0.1, chamber_area=1e-4, chamber_radius=0.01, youngs_modulus=1e5)
    base.update(kw)
    return qc.Segment(**base)


#: a mid-arm straight tendon, a helical one to the tip, a left-handed helix ending at segment 0
TENDONS = (qc.Tendon(radius=0.015, angle=0.3, end=1), qc.Tendon(radius=0.012, angle=1.0, pitch=0.25),
           qc.Tendon(radius=0.018, angle=-2.0, pitch=-0.07, end=0))


def _chain(coords=("curvature",) * 3, tendons=TENDONS, **kw):
    segs = [_segment(length=0.2 - 0.02 * j, coords=c) for j, c in enumerate(coords)]
    return qc.Chain(segs, tendons=tendons, **kw)


def _config(chain, rng, bend=8.0):
    """A random bent configuration (curvatures up to ``bend`` 1/m, lengths +-10 %)."""
    q = chain.neutral()
    for j, s in enumerate(chain.segments):
        l = s.length * rng.uniform(0.9, 1.1)
        k, psi = rng.uniform(0.5, 1.0) * bend, rng.uniform(-np.pi, np.pi)
        q[chain.q_slice(j)] = (l, psi, k) if s.coords == "paper" else (l, k * np.cos(psi), k * np.sin(psi))
    return q


def _fd(f, x, eps=1e-6):
    cols = []
    for i in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp[i] += eps
        xm[i] -= eps
        cols.append((f(xp) - f(xm)) / (2 * eps))
    return np.array(cols)  # (n, ...): derivative along x[i] in row i


@pytest.mark.parametrize("coords", [("curvature",) * 3, ("paper", "curvature", "paper")])
def test_tendon_matrix_is_minus_the_length_gradient(coords):
    chain = _chain(coords)
    rng = np.random.default_rng(3)
    for _ in range(3):
        q = _config(chain, rng)
        Bt = chain.tendon_matrix(q)
        fd = -_fd(chain.tendon_lengths, q)  # (nv, m)
        assert np.abs(Bt - fd).max() <= 1e-8 * np.abs(Bt).max()
        # zero past each tendon's end
        assert np.all(Bt[chain.v_slice(2), 0] == 0.0) and np.all(Bt[3:, 2] == 0.0)
    # the straight pose is a regular point in curvature coordinates
    if coords[0] == "curvature":
        q = chain.neutral()
        assert np.abs(chain.tendon_matrix(q) + _fd(chain.tendon_lengths, q)).max() <= 1e-8


@pytest.mark.parametrize("coords", [("curvature",) * 3, ("paper", "curvature", "paper")])
def test_tendon_stiffness_is_the_derivative_of_the_tendon_force(coords):
    chain = _chain(coords)
    q = _config(chain, np.random.default_rng(5))
    T = np.array([2.0, 3.0, 1.5])
    K = chain.tendon_stiffness(q, T)
    fd = _fd(lambda x: chain.tendon_force(x, T), q).T  # K[:, i] = d tau / dq_i
    assert np.abs(K - fd).max() <= 1e-7 * np.abs(K).max()


def _fibre_polyline(chain, q, k, points=4001):
    """Tendon ``k``'s length as the polyline through ``points`` material points a segment,
    placed on the deformed arm by the chain's own kinematics (root frames) and each segment's
    slice placements; the helix's angle from the rest arc length from the base, computed
    here independently of the model's routing."""
    td = chain.tendons[k]
    roots = chain.placements(q)  # world placements of the roots 0..n
    end = chain.n - 1 if td.end is None else td.end
    s0 = 0.0
    pts = []
    alphas = np.linspace(0.0, 1.0, points)
    for j in range(end + 1):
        seg = chain.segments[j]
        qe = q[chain.q_slice(j)]
        for a in alphas:
            s = s0 + a * seg.length
            phi = td.angle + (0.0 if td.pitch is None else 2 * np.pi * s / td.pitch)
            X = roots[j] * seg.slice_placement(qe, a)
            pts.append(X.translation + X.rotation @ (td.radius * np.array([np.cos(phi), np.sin(phi), 0.0])))
        s0 += seg.length
    pts = np.array(pts)
    return np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()


def test_tendon_length_matches_the_fibre_on_the_deformed_arm():
    chain = _chain(("paper", "curvature", "curvature"))
    q = _config(chain, np.random.default_rng(7))
    L = chain.tendon_lengths(q)
    for k in range(chain.nt):
        coarse = _fibre_polyline(chain, q, k, 801)
        fine = _fibre_polyline(chain, q, k, 1601)
        # the polyline converges from below at O(h^2): the model's length lies past both, and
        # Richardson's extrapolation of the two (error O(h^4)) meets it
        assert coarse < fine < L[k]
        assert abs(L[k] - (4 * fine - coarse) / 3) < 1e-9 * L[k] < abs(L[k] - fine)


@pytest.mark.parametrize("kr", [0.0, 0.3, 0.6, 0.9])
@pytest.mark.parametrize("omega", [0.4, 2 * np.pi, -9.0, 40.0])
def test_helix_quadrature_against_adaptive_quadrature(kr, omega):
    r, l, psi, phi = 0.01, 0.18, 0.7, -0.4
    kappa = kr / r
    q = np.array([l, kappa * np.cos(psi), kappa * np.sin(psi)])
    x, w = helix_nodes(omega)
    L = tendon_length_c(q, r, phi, omega, x, w, False, np.empty(3), np.empty((3, 3)))

    def f(a):
        return np.hypot(r * omega, l * (1 - kr * np.cos(phi + omega * a - psi)))

    ref = quad(f, 0.0, 1.0, epsabs=0.0, epsrel=1e-13, limit=500)[0]
    assert abs(L - ref) <= 1e-12 * ref


def test_straight_tip_tendon_equals_its_equivalent_chamber_pressures():
    """A straight tendon at the chambers' radius ending at the tip does the virtual work of the
    pressures ``p`` with ``A_ch (sum p_i, sum p_i cos phi_i, sum p_i sin phi_i) = -T (1, cos phi,
    sin phi)`` (the volume model; docs/tendons.md): the same generalised force, to round-off."""
    segs = [_segment(), _segment(length=0.15)]
    rng = np.random.default_rng(11)
    A = np.vstack([np.ones(3), np.cos(CHAMBER_ANGLES), np.sin(CHAMBER_ANGLES)])
    for phi in (0.0, 0.4, np.pi, -2.2):
        chain = qc.Chain(segs, tendons=[qc.Tendon(radius=segs[0].chamber_radius, angle=phi)])
        q = _config(chain, rng)
        T = 7.5
        p_seg = np.linalg.solve(segs[0].chamber_area * A, -T * np.array([1.0, np.cos(phi), np.sin(phi)]))
        p = np.tile(p_seg, 2)
        tau_p = chain.input_matrix(q) @ p
        tau_t = chain.tendon_force(q, [T])
        assert np.abs(tau_t - tau_p).max() <= 1e-13 * np.abs(tau_p).max()
    # the equivalent pressures of a tendon on chamber 1 are -T/A_ch there: below vacuum for
    # T > 101325 Pa * A_ch = 10.1 N, where the equivalence cannot be run with pressures
    assert np.allclose(np.linalg.solve(segs[0].chamber_area * A, -T * np.array([1.0, 1.0, 0.0])),
                       [-T / segs[0].chamber_area, 0.0, 0.0], atol=1e-9)


def test_tendon_matrix_rank():
    """Three straight tendons at distinct angles ending at the tip of one segment: ``B_T`` is
    invertible at every configuration, the straight pose included (``det = -l^2 r^2 D``, ``D``
    twice the area of the triangle of the angles on the unit circle), as the chambers' ``B``;
    helical ones likewise here. A tendon that ends at segment 0 spans nothing past it."""
    angles = CHAMBER_ANGLES + 0.2
    for pitch in (None, 0.3):
        tendons = [qc.Tendon(radius=0.01, angle=a, pitch=pitch) for a in angles]
        chain = qc.Chain([_segment()], tendons=tendons)
        rng = np.random.default_rng(2)
        for q in (chain.neutral(), _config(chain, rng), _config(chain, rng, bend=40.0)):
            Bt = chain.tendon_matrix(q)
            assert np.linalg.matrix_rank(Bt) == 3
            if pitch is None:
                D = np.linalg.det(np.vstack([np.ones(3), np.cos(angles), np.sin(angles)]))
                assert np.linalg.det(Bt) == pytest.approx(-(q[0] * 0.01) ** 2 * D, rel=1e-12)
    chain = _chain()
    q = _config(chain, np.random.default_rng(4))
    assert np.linalg.matrix_rank(chain.tendon_matrix(q)[3:, [0, 2]]) == 1  # only tendon 0 reaches segment 1


def test_tendon_bent_segment_statics_closed_form():
    """One segment, no gravity, a straight tendon at angle phi ending at the tip, tension T:
    the balance ``dU_el/dq = B_T T`` of the material law has the closed form
    ``l = l0 (1 - T/EA)`` and ``EI kappa l / l0 = T r`` (the moment ``T r`` balanced by the
    bending moment), curvature towards the tendon."""
    s = _segment()
    r, phi, T = 0.015, 0.8, 4.0
    chain = qc.Chain([s], gravity=(0.0, 0.0, 0.0), tendons=[qc.Tendon(radius=r, angle=phi)])
    res = qc.equilibrium(chain, tension=[T], tol=1e-13)
    assert res.success
    l = s.length * (1 - T / s.axial_stiffness)
    kappa = T * r * s.length / (s.bending_stiffness * l)
    assert res.q == pytest.approx([l, kappa * np.cos(phi), kappa * np.sin(phi)], rel=1e-10, abs=1e-12)
    assert kappa * l > 0.5  # a real bend, not a linearisation


def test_forward_dynamics_takes_tensions_beside_pressures():
    chain = _chain()
    q = _config(chain, np.random.default_rng(8))
    v = np.zeros(chain.nv)
    p = np.full(chain.nu, 1e3)
    T = np.array([1.0, 0.5, 2.0])
    a = chain.forward_dynamics(q, v, p, tension=T)
    assert np.allclose(a, chain.forward_dynamics(q, v, p, tau=chain.tendon_matrix(q) @ T), rtol=1e-12, atol=0.0)
    assert not np.allclose(a, chain.forward_dynamics(q, v, p))


def test_negative_tension_is_refused_by_name():
    chain = _chain()
    q = chain.neutral()
    with pytest.raises(ValueError, match=r"tension\[1\] must be >= 0 .* got -0.5 N"):
        chain.tendon_force(q, [1.0, -0.5, 0.0])
    with pytest.raises(ValueError, match=r"tension\[1\] must be >= 0"):
        chain.forward_dynamics(q, np.zeros(chain.nv), tension=[1.0, -0.5, 0.0])
    with pytest.raises(ValueError, match=r"tension\[0\] must be >= 0"):
        qc.equilibrium(chain, tension=[-1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match=r"tension must have shape \(3,\)"):
        check_tension([1.0], 3)


@pytest.mark.parametrize("kw, match", [
    (dict(radius=0.0), r"radius must be > 0"),
    (dict(radius=-1e-3), r"radius must be > 0"),
    (dict(radius=0.01, pitch=0.0), r"pitch must be None .* got 0.0"),
    (dict(radius=0.01, pitch=float("nan")), r"pitch must be finite, got nan"),
    (dict(radius=0.01, pitch=-2e6), r"pitch must be None .* \|pitch\| >= 0.0001 and <= 1e\+06 .* got -2000000.0 m"),
    (dict(radius=0.01, end=-1), r"end must be None .* segment index >= 0"),
    (dict(radius=0.01, end=1.5), r"end must be None"),
    (dict(radius=0.01, angle=1e4), r"angle must be"),
])
def test_tendon_bad_input(kw, match):
    with pytest.raises((ValueError, TypeError), match=match):
        qc.Tendon(**kw)


def test_chain_refuses_a_tendon_past_its_segments_and_a_fibre_without_length():
    with pytest.raises(ValueError, match=r"tendons\[0\]\.end must be a segment index < 3"):
        _chain(tendons=[qc.Tendon(radius=0.01, end=3)])
    with pytest.raises(TypeError, match=r"tendons\[1\] must be a qchain.Tendon"):
        _chain(tendons=[qc.Tendon(radius=0.01), "x"])
    chain = qc.Chain([_segment()], tendons=[qc.Tendon(radius=0.04)])  # on spacer disks, outside the 20 mm body
    q = np.array([0.2, 26.0, 0.0])  # kappa r = 1.04 for the tendon, inside the segment's own domain (0.52)
    with pytest.raises(DomainError, match=r"kappa r = 1.04 for tendons\[0\]"):
        chain.tendon_matrix(q)


def _tendon_arm(damping=0.02, **kw):
    segs = [_segment(damping=damping), _segment(length=0.18, damping=damping)]
    return qc.Chain(segs, tendons=[qc.Tendon(radius=0.015, angle=0.0, end=0),
                                   qc.Tendon(radius=0.012, angle=1.0, pitch=0.3)], **kw)


def test_simulate_tensions_on_the_compiled_engine_match_the_python_steppers():
    """Constant tensions run on the compiled engine; the same tensions from a controller run
    on the Python steppers (the same rk4 steps): the two agree to round-off, beside
    pressures."""
    chain = _tendon_arm()
    T = np.array([1.5, 0.8])
    p = np.array([2e3, 0.0, 0.0, 0.0, 1e3, 0.0])
    kw = dict(pressure=p, method="rk4", dt=2e-4, t_eval=np.linspace(0.0, 0.05, 6))
    c = qc.simulate(chain, chain.neutral(), np.zeros(chain.nv), (0.0, 0.05), tension=T, **kw)
    py = qc.simulate(chain, chain.neutral(), np.zeros(chain.nv), (0.0, 0.05), tension=lambda t, q, v: T, **kw)
    assert c.meta["engine"] == "compiled" and py.meta["engine"] != "compiled"
    assert np.abs(c.q - py.q).max() < 1e-10
    assert c.tension.shape == (6, 2) and np.all(c.tension == T) and np.all(py.tension == T)
    free = qc.simulate(chain, chain.neutral(), np.zeros(chain.nv), (0.0, 0.05), **kw)
    assert np.abs(c.q[-1] - free.q[-1]).max() > 1e-3  # the tendons did something


def test_simulate_settles_on_the_tendon_equilibrium():
    """radau5 (the compiled engine with the tendons' exact stiffness in its Jacobian) on a
    damped arm under constant tensions and pressures settles on :func:`qchain.equilibrium`'s shape."""
    chain = _tendon_arm(damping=0.3, gravity=(0.0, 0.0, 0.0))
    T = np.array([1.0, 0.6])
    p = np.array([1e3, 0.0, 0.0, 0.0, 0.0, 5e2])
    eq = qc.equilibrium(chain, p, tension=T, tol=1e-12)
    assert eq.success
    tr = qc.simulate(chain, chain.neutral(), np.zeros(chain.nv), (0.0, 8.0), pressure=p, tension=T, method="radau5",
                     rtol=1e-8, atol=1e-10, t_eval=[8.0])
    assert tr.success and tr.meta["engine"] == "compiled"
    assert np.abs(tr.v[-1]).max() < 1e-5  # at rest
    assert np.abs(tr.q[-1] - eq.q).max() < 1e-6
    assert np.abs(eq.q - chain.neutral()).max() > 0.5  # bent: curvatures of order 1/m


def test_simulate_refuses_negative_tensions_where_they_enter():
    chain = _tendon_arm()
    q0, v0 = chain.neutral(), np.zeros(chain.nv)
    with pytest.raises(ValueError, match=r"tension\[1\] must be >= 0 .* got -2 N"):
        qc.simulate(chain, q0, v0, (0.0, 0.01), tension=[1.0, -2.0], method="rk4", dt=1e-3)
    from qchain.sim.inputs import Step
    with pytest.raises(ValueError, match=r"tension\[0\] must stay >= 0"):
        qc.simulate(chain, q0, v0, (0.0, 0.01), tension=Step(0.005, [0.0, 1.0], [-1.0, 1.0]), method="rk4", dt=1e-3)
    with pytest.raises(ValueError, match=r"tension\(t, q, v\)\[0\] must be >= 0 .* got -0.25 N"):
        qc.simulate(chain, q0, v0, (0.0, 0.01), tension=lambda t, q, v: np.array([-0.25, 0.0]), method="rk4",
                    dt=1e-3)
    with pytest.raises(ValueError, match=r"tension is given but the chain has no tendons"):
        ch = qc.Chain([_segment()])
        qc.simulate(ch, ch.neutral(), np.zeros(3), (0.0, 0.01), tension=[1.0], method="rk4", dt=1e-3)


@numba.njit(cache=True)
def _call_rhs(f, m, wk, t, y, out):
    return f(m, wk, t, y, out)


@numba.njit(cache=True)
def _call_jacobian(f, m, wk, t, y, Jq, Jv):
    return f(m, wk, t, y, Jq, Jv)


def test_engine_rhs_and_jacobian_carry_the_tendons():
    """The compiled engine's right-hand side equals ``forward_dynamics(..., tension=T)``, and
    its exact Jacobian ``da/dq`` (the tendons' stiffness included) equals central finite
    differences of that right-hand side; the tendons' part of it is far above the error."""
    from qchain.sim.engine import packing, steppers, system, warmup

    chain = _tendon_arm()
    q = _config(chain, np.random.default_rng(1))
    v = 0.1 * np.random.default_rng(2).normal(size=chain.nv)
    p = np.full(chain.nu, 1e3)

    def engine(T):
        m = packing.pack(chain, p, None, None, T)
        wk = system.workspace(chain, m)
        rhs, jac = warmup.callbacks("radau5", m, wk, steppers.integrator(m.idx.size, chain.nq))
        nA = m.idx.size
        wk.q_chart[:] = q
        y = np.concatenate([np.zeros(nA), v[m.idx]])
        out, Jq, Jv = np.zeros(2 * nA), np.zeros((nA, nA)), np.zeros((nA, nA))
        assert _call_rhs(rhs, m, wk, 0.0, y, out) == system.OK
        a = out[nA:].copy()
        assert _call_jacobian(jac, m, wk, 0.0, y, Jq, Jv) == system.OK

        def acc(x):
            yy = y.copy()
            yy[:nA] = x
            _call_rhs(rhs, m, wk, 0.0, yy, out)
            return out[nA:].copy()

        return a, Jq, _fd(acc, y[:nA]).T

    T = np.array([1.5, 2.0])
    a, Jq, fd = engine(T)
    assert np.abs(a - chain.forward_dynamics(q, v, p, tension=T)).max() <= 1e-12 * np.abs(a).max()
    err = np.abs(Jq - fd).max()
    assert err <= 1e-8 * np.abs(Jq).max()
    _, Jq0, _ = engine(np.zeros(2))
    assert np.abs(Jq - Jq0).max() > 1e4 * err


def _kirchhoff_tendon_arm(tendons, T, EI, s_stops):
    """An independent reference: the inextensible, torsion-rigid Kirchhoff rod (no gravity)
    clamped along +z with frictionless tendons ``(r, phi0, pitch or None, s_end)``. Cut at
    arclength ``s``, the part beyond it holds the tendons that pass ``s`` and nothing else, so
    the rod's bending moment balances theirs there: with the tendon's tangent
    ``(a (-sin phi, cos phi), z) / f`` in the section frame, ``a = 2 pi r / pitch``,
    ``z = 1 - r (u . e)``, ``f = sqrt(a^2 + z^2)``, ``e = (cos phi, sin phi)``,

        EI u(s) = sum_k T_k r_k z_k / f_k e_k      (the tendons passing s),

    solved pointwise by fixed-point iteration (``r |u| << 1``), then ``p' = R e_z``,
    ``R' = R [(-u_y, u_x, 0)]x`` (the strain twist's axes, docs/model.md section 2) integrated
    by scipy's DOP853 at ``rtol = 1e-12``. Returns the backbone points at ``s_stops`` (m)."""
    from scipy.integrate import solve_ivp

    def u_at(s):
        act = [(r, phi0 + (0.0 if p is None else 2 * np.pi * s / p), 0.0 if p is None else 2 * np.pi * r / p, Tk)
               for (r, phi0, p, s_end), Tk in zip(tendons, T) if s <= s_end]
        u = np.zeros(2)
        for _ in range(100):
            un = np.zeros(2)
            for r, ph, a, Tk in act:
                e = np.array([np.cos(ph), np.sin(ph)])
                z = 1.0 - r * (u @ e)
                un += Tk * r * z / (EI * np.hypot(a, z)) * e
            if np.abs(un - u).max() <= 1e-15 * max(1.0, np.abs(un).max()):
                break
            u = un
        return un

    def rhs(s, y):
        ux, uy = u_at(s)
        W = np.array([[0.0, 0.0, ux], [0.0, 0.0, uy], [-ux, -uy, 0.0]])  # [(-uy, ux, 0)]x
        Rm = y[3:].reshape(3, 3)
        return np.concatenate([Rm[:, 2], (Rm @ W).ravel()])

    y, s0, out = np.concatenate([np.zeros(3), np.eye(3).ravel()]), 0.0, []
    for s1 in s_stops:  # stops at the tendons' ends, where u jumps
        y = solve_ivp(rhs, (s0, s1), y, method="DOP853", rtol=1e-12, atol=1e-14).y[:, -1]
        out.append(y[:3].copy())
        s0 = s1
    return np.array(out)


def test_tendon_arm_converges_to_the_kirchhoff_rod():
    """A straight tendon ending mid-arm and a helical one to the tip on an inextensible arm of
    3 x 0.1 m, no gravity: the helix's moment turns along the arm, so the exact rod's
    curvature varies within each segment and qchain's constant-curvature segments converge to
    it at second order as they are split (``k`` sub-segments a segment): the mid-arm point and
    the tip each move ~4 times closer to the rod at each halving."""
    L0, R, E = 0.1, 0.01, 1e6
    EI = E * np.pi * R ** 4 / 4
    tendons = [(0.008, 0.0, None, 2 * L0), (0.006, np.pi / 2, 0.25, 3 * L0)]
    T = np.array([1.2, 1.0])
    ref = _kirchhoff_tendon_arm(tendons, T, EI, [2 * L0, 3 * L0])
    errors = []
    for k in (2, 4, 8):
        segs = [qc.Segment(length=L0 / k, radius=R, mass=0.01 / k, chamber_area=1e-6, chamber_radius=0.005,
                           youngs_modulus=E, extensible=False) for _ in range(3 * k)]
        chain = qc.Chain(segs, gravity=(0.0, 0.0, 0.0),
                         tendons=[qc.Tendon(radius=0.008, angle=0.0, end=2 * k - 1),
                                  qc.Tendon(radius=0.006, angle=np.pi / 2, pitch=0.25)])
        eq = qc.equilibrium(chain, tension=T, tol=1e-13)
        assert eq.success
        got = np.array([chain.points(eq.q, [(2 * k - 1, 1.0)])[0], chain.tip_placement(eq.q).translation])
        errors.append(np.linalg.norm(got - ref, axis=1))
    errors = np.array(errors)  # (3 refinements, 2 points)
    deflection = np.linalg.norm(ref[1] - [0.0, 0.0, 3 * L0])
    assert deflection > 0.03  # a real bend: 40 mm at the tip of a 0.3 m arm
    assert np.all((errors[:-1] / errors[1:] > 3.5) & (errors[:-1] / errors[1:] < 4.5))
    assert errors[-1].max() < 1e-3 * deflection  # k = 8 (24 segments): within 0.1 % of the deflection


#: the published tendon robot of Till, Aloi and Rucker's examples (JohnDTill/ContinuumRobotExamples,
#: 01_Statics/05_Tendon_Robot): a 0.5 m steel rod of 1 mm radius, four straight tendons 15.06 mm
#: off the backbone at 90 degrees, 15 N on the +x one, gravity along +x
TILL_ROBOT = dict(length=0.5, radius=0.001, youngs_modulus=200e9, shear_modulus=80e9, density=8000.0,
                  gravity=(9.81, 0.0, 0.0), offset=0.01506, tension=(15.0, 0.0, 0.0, 0.0))


@pytest.mark.slow
def test_published_tendon_robot_converges_to_the_cosserat_rod():
    """qchain's constant-curvature segments against the Cosserat rod with Rucker and Webster's
    tendon model (tests/tendon_rod.py, scipy shooting) on the published tendon robot: the tip
    moves ~4 times closer to the rod at each halving of the segments (second order: the rod's
    curvature varies along it, under gravity and the tendon's own load), to 15 um of the 188 mm
    tip travel at 16 segments. The floor below that is the rod's shear (qchain's sections do not
    shear): 0.11 um here, far below the errors checked. The reference is first checked on its
    own against the exact circular arc of one tendon without gravity."""
    from tendon_rod import TendonRod

    P = TILL_ROBOT
    angles = np.array([0.0, np.pi / 2, np.pi, 3 * np.pi / 2])
    offsets = P["offset"] * np.column_stack([np.cos(angles), np.sin(angles), np.zeros(4)])
    rod = TendonRod(P["length"], P["radius"], P["youngs_modulus"], P["shear_modulus"], P["density"], P["gravity"],
                    offsets)
    # the reference itself: without gravity, one tendon's moment T r is uniform, so the rod is a
    # circular arc of curvature T r / EI, stretched by v = 1 - T / EA
    arc = TendonRod(P["length"], P["radius"], P["youngs_modulus"], P["shear_modulus"], P["density"], (0.0, 0.0, 0.0),
                    offsets[:1])
    T, L = P["tension"][0], P["length"]
    u = T * P["offset"] / (P["youngs_modulus"] * np.pi * P["radius"] ** 4 / 4)
    v = 1.0 - T / (P["youngs_modulus"] * np.pi * P["radius"] ** 2)
    exact = v * np.array([(1.0 - np.cos(u * L)) / u, 0.0, np.sin(u * L) / u])
    assert np.linalg.norm(arc.solve([T])[1][-1] - exact) < 1e-9

    ref = rod.solve(P["tension"])[1][-1]
    travel = np.linalg.norm(ref - [0.0, 0.0, P["length"]])
    assert travel > 0.15  # a large bend: 188 mm at the tip of the 0.5 m rod
    area = np.pi * P["radius"] ** 2
    errors = []
    for n in (4, 8, 16):
        segs = [qc.Segment(length=P["length"] / n, radius=P["radius"], mass=P["density"] * area * P["length"] / n,
                           chamber_area=np.pi * (0.4 * P["radius"]) ** 2, chamber_radius=0.5 * P["radius"],
                           youngs_modulus=P["youngs_modulus"]) for _ in range(n)]
        chain = qc.Chain(segs, gravity=P["gravity"], tendons=[qc.Tendon(radius=P["offset"], angle=a) for a in angles])
        eq = qc.equilibrium(chain, tension=P["tension"], tol=1e-9)  # tol: of the gravity scale, 0.12 N
        assert eq.success
        errors.append(np.linalg.norm(chain.tip_placement(eq.q).translation - ref))
    errors = np.array(errors)
    ratios = errors[:-1] / errors[1:]
    assert np.all((ratios > 3.5) & (ratios < 4.5)), ratios
    assert errors[-1] < 1e-4 * travel  # 16 segments: within 0.01 % of the tip travel (observed 15 um, 0.008 %)


def test_a_tension_controller_held_at_controller_rate_equals_its_equivalent_pressure_controller():
    """``tension=`` a controller with ``controller_rate``: sampled at the rate and held (the
    compiled engine between holds), as a held pressure controller. A straight tip tendon on
    chamber 1 is the pressure ``-T / A_ch`` there (test above), so the held tension controller
    and the held controller of its equivalent pressures give the same run (to round-off), and
    the samples' tensions are the holds'. A negative output is refused at the hold naming it."""
    segs = [_segment(damping=0.02), _segment(length=0.15, damping=0.02)]
    chain = qc.Chain(segs, tendons=[qc.Tendon(radius=segs[0].chamber_radius, angle=0.0)], gravity=(0, 0, -9.81))
    A_ch = segs[0].chamber_area

    def T_of(t, q, v):  # a feedback law in [0.5, 3.5] N
        return np.array([2.0 + 1.5 * np.tanh(20.0 * q[1] + 0.5 * v[1] + np.sin(9.0 * t))])

    def p_of(t, q, v):
        return np.tile([-T_of(t, q, v)[0] / A_ch, 0.0, 0.0], 2)

    kw = dict(method="radau5", rtol=1e-9, atol=1e-11, t_eval=np.linspace(0.0, 0.4, 41), controller_rate=50.0)
    q0, v0 = chain.neutral(), np.zeros(chain.nv)
    tr_t = qc.simulate(chain, q0, v0, (0.0, 0.4), tension=T_of, **kw)
    tr_p = qc.simulate(qc.Chain(segs, gravity=(0, 0, -9.81)), q0, v0, (0.0, 0.4), pressure=p_of, **kw)
    assert tr_t.success and tr_t.meta["engine"] == "compiled"
    assert np.abs(tr_t.q - tr_p.q).max() <= 1e-9 * np.abs(tr_p.q).max()
    held = -A_ch * tr_p.p[:, 0]  # the pressure run's held (sampled) pressures, as tensions
    assert np.abs(tr_t.tension[:, 0] - held).max() <= 1e-9 * held.max()
    Tn = tr_t.tension[:, 0]  # held: the samples at 0, 10 ms of each 20 ms hold see one value
    assert np.array_equal(Tn[0:40:2], Tn[1:40:2]) and not np.array_equal(Tn[1:39:2], Tn[2:40:2])
    with pytest.raises(ValueError, match=r"tension\(t, q, v\)\[0\] must be >= 0"):
        qc.simulate(chain, q0, v0, (0.0, 0.4), tension=lambda t, q, v: np.array([-1.0 if t > 0.05 else 1.0]), **kw)


#: the dynamic tendon robot of Till, Aloi and Rucker (02_Dynamics/03_Tendon_Robot/Cpp/main.cpp), SI units
TILL_ROLLOUT = dict(length=0.7144, radius=0.00135 / 2, youngs_modulus=207e9, mass=0.034, gravity=(-9.81, 0.0, 0.0),
                    offset=0.01506, bending_damping=5e-4, drag=1e-4)


def _till_rollout_reference():
    """The converged Cosserat-rod rollout recorded in ``tests/data/till_tendon_rollout.csv``.

    Returns
    -------
    t : (K,) s
        Sample times: the initial static state at 0 s, then every 0.025 s from 3.5 s to 10 s.
    tension : (K,) N
        The tendon's tension the reference solved for at each sample.
    tip : (K, 3) m
        The reference's tip position (world frame, base at the origin along +z).
    """
    from pathlib import Path

    a = np.loadtxt(Path(__file__).parent / "data" / "till_tendon_rollout.csv", delimiter=",", comments="#")
    return a[:, 0], a[:, 1], a[:, 2:5]


def _till_rollout_arm(n, bending_damping=TILL_ROLLOUT["bending_damping"], offset=TILL_ROLLOUT["offset"]):
    """qchain's arm of the published rod: ``n`` equal inextensible segments with the rod's radius,
    modulus and mass, the rod's Kelvin-Voigt bending damping ``B_bt`` (N m^2 s) as the
    ``damping_matrix`` ``diag(0, B_bt l0, B_bt l0)`` (the rod's ``B_se = 0``: no axial term), its
    drag coefficient as ``drag_quadratic``, one straight tendon to the tip at ``offset`` (m) on
    the base's +x side, and the rod's gravity (docs/tendons.md, "Against a published tendon
    rollout").

    Parameters
    ----------
    n : int
        Number of segments.
    bending_damping : float
        ``B_bt`` (N m^2 s).
    offset : float
        The tendon's distance from the backbone (m).

    Returns
    -------
    qchain.Chain
    """
    P = TILL_ROLLOUT
    l0 = P["length"] / n
    segs = [qc.Segment(length=l0, radius=P["radius"], mass=P["mass"] / n, chamber_area=np.pi * (0.4 * P["radius"]) ** 2,
                       chamber_radius=0.5 * P["radius"], youngs_modulus=P["youngs_modulus"],
                       damping_matrix=np.diag([0.0, bending_damping * l0, bending_damping * l0]),
                       drag_quadratic=P["drag"], extensible=False) for _ in range(n)]
    return qc.Chain(segs, gravity=P["gravity"], tendons=[qc.Tendon(radius=offset, angle=0.0)])


def _till_rollout_differences(chain, t, tension, tip):
    """Drive ``chain`` from its equilibrium under ``tension[0]`` with the tension history
    ``(t, tension)`` (linear between the samples; radau5, rtol 1e-8) and return the initial
    tip's distance from ``tip[0]`` (m) and the tip's distance from ``tip`` at each sample (K,) m."""
    from qchain.sim.inputs import Table

    eq = qc.equilibrium(chain, tension=tension[:1], tol=1e-10)
    assert eq.success
    tr = qc.simulate(chain, eq.q, np.zeros(chain.nv), (t[0], t[-1]), tension=Table(times=t, values=tension[:, None]),
                     method="radau5", rtol=1e-8, atol=1e-10, t_eval=t)
    assert tr.success and tr.meta["engine"] == "compiled"
    tips = np.array([chain.tip_placement(q).translation for q in tr.q])
    return np.linalg.norm(tips[0] - tip[0]), np.linalg.norm(tips - tip, axis=1)


@pytest.mark.slow
def test_published_tendon_rollout_against_its_cosserat_reference():
    """qchain's arm driven by the tension history of the published dynamic tendon robot (Till,
    Aloi and Rucker's Cosserat rod with a motor-driven tendon, Kelvin-Voigt bending damping and
    drag, BDF2 in time), converged by refining its steps and nodes and extrapolating
    (tests/data/till_tendon_rollout.csv): the pull swings the tip 504 mm across in 0.5 s and it
    rings for seconds. Measured over 0-10 s (docs/tendons.md): 4 segments max 19.5 mm, RMS 9.31
    mm; 8 segments 6.58 mm, 2.57 mm (1.31 % and 0.51 % of the tip travel). The initial (static)
    tip converges at second order (7.83, 1.94, 0.48 mm at 4, 8, 16). Below about 1 % (max) the
    difference is the reference's own: its tension is known only at its steps, and where the
    motor starts and stops it jumps by up to 1.2 N within a step (a 6 ms shift of the history
    moves 8 segments' tip by 6 mm more). The bounds fail with half or twice the bending damping
    (RMS 1.3 %, 2.1 %) or the tendon at 14.0 mm instead of 15.06 mm (RMS 8.2 %)."""
    t, T, tip = _till_rollout_reference()
    travel = np.linalg.norm(tip - tip[0], axis=1).max()
    assert 0.49 < travel < 0.52  # the first swing: from x = -148 mm to +344 mm
    e4, d4 = _till_rollout_differences(_till_rollout_arm(4), t, T, tip)
    e8, d8 = _till_rollout_differences(_till_rollout_arm(8), t, T, tip)
    chain16 = _till_rollout_arm(16)
    q16 = qc.equilibrium(chain16, tension=T[:1], tol=1e-10).q
    e16 = np.linalg.norm(chain16.tip_placement(q16).translation - tip[0])
    assert 3.5 < e4 / e8 < 4.5 and 3.5 < e8 / e16 < 4.5, (e4, e8, e16)  # second order (observed 4.04, 4.04)
    rms4, rms8 = np.sqrt(np.mean(d4 ** 2)), np.sqrt(np.mean(d8 ** 2))
    assert rms4 / rms8 > 3.0, (rms4, rms8)  # observed 3.6
    assert d8.max() < 0.016 * travel, d8.max()  # observed 1.31 %
    assert rms8 < 0.006 * travel, rms8  # observed 0.51 %
