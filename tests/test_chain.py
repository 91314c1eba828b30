"""The n-segment chain against particle brute force, Pinocchio, conservation laws and itself."""

import numpy as np
import pinocchio as pin
import pytest

from helpers import SEGMENT_KW, rel
from particles import brute_chain
from qchain import Chain, DomainError, Segment, SingularConfigurationError
from qchain.arm.chain import Frames

G_W = np.array([0.0, 0.0, -9.81])


def make_chain(coords="curvature", base="fixed", n=3, **kw):
    """Segments that differ: coordinates, actuation, geometry, damping."""
    segs = []
    for j in range(n):
        segs.append(
            Segment(
                **{**SEGMENT_KW, "length": 0.2 - 0.02 * j, "radius": 0.02 - 0.002 * j, "mass": 0.3 - 0.05 * j},
                coords=coords if j % 2 == 0 else "curvature",
                actuation="paper" if j == 2 else "volume",
                damping=0.01 * j,
            )
        )
    return Chain(segs, base=base, **kw)


def random_state(ch, rng, bend=6.0):
    q = ch.neutral()
    for j, s in enumerate(ch.segments):
        l = s.length * rng.uniform(0.9, 1.1)
        if s.coords == "paper":
            q[ch.q_slice(j)] = [l, rng.uniform(-3, 3), rng.uniform(0.3, bend)]
        else:
            q[ch.q_slice(j)] = [l, *rng.uniform(-bend, bend, 2)]
    if ch.floating:
        q[:7] = pin.SE3ToXYZQUAT(pin.SE3(pin.exp3(rng.normal(size=3)), rng.normal(size=3)))
    v = rng.normal(size=ch.nv)
    v[ch._voff :: 3] *= 0.05  # ldot, m/s
    return q, v


BASES = [
    ("fixed", dict(base_placement=pin.SE3(pin.exp3(np.array([0.4, -1.0, 0.3])), np.array([0.1, 0.2, -0.3])))),
    ("floating", {}),
]


@pytest.mark.parametrize("coords", ["curvature", "paper"])
@pytest.mark.parametrize("base, kw", BASES, ids=[b for b, _ in BASES])
def test_mass_matrix_and_nle_match_particle_brute_force(coords, base, kw, rng):
    ch = make_chain(coords, base, **kw)
    q, v = random_state(ch, rng)
    X = ch.placements(q)[0]
    q_e = q[ch._qoff :].reshape(ch.n, 3)
    M_ref, nle_ref = brute_chain(ch.segments, q_e, v, ch.floating, X.rotation.T @ G_W)
    assert rel(ch.mass_matrix(q), M_ref) < 1e-8
    assert rel(ch.nonlinear_effects(q, v), nle_ref) < 1e-8


@pytest.mark.parametrize("coords", ["curvature", "paper"])
@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_pinocchio_style_identities(coords, base, rng):
    ch = make_chain(coords, base)
    q, v = random_state(ch, rng)
    a = rng.normal(size=ch.nv)
    p = rng.uniform(0, 4e4, ch.nu)
    tau = rng.normal(size=ch.nv)
    M = ch.mass_matrix(q)
    nle = ch.nonlinear_effects(q, v)
    assert np.allclose(M, M.T, rtol=0, atol=1e-14 * np.abs(M).max())
    assert np.linalg.eigvalsh(M).min() > 0
    assert rel(ch.inverse_dynamics(q, v, a), M @ a + nle) < 1e-12
    assert rel(nle, ch.inverse_dynamics(q, v, np.zeros(ch.nv))) < 1e-14
    assert rel(ch.generalized_gravity(q), ch.inverse_dynamics(q, np.zeros(ch.nv), np.zeros(ch.nv))) < 1e-14
    f = ch.input_matrix(q) @ p - ch.damping_force(q, v) - ch.elastic_force(q)
    assert rel(ch.internal_forces(q, v, p), f) < 1e-12
    acc = ch.forward_dynamics(q, v, p, tau)
    assert rel(acc, np.linalg.solve(M, f + tau - nle)) < 1e-10
    assert rel(ch.inverse_dynamics(q, v, acc), f + tau) < 1e-10
    # pressures never push the base
    B = ch.input_matrix(q)
    assert np.all(B[: ch._voff] == 0)
    assert ch.kinetic_energy(q, v) == pytest.approx(0.5 * v @ M @ v, rel=1e-12)


@pytest.mark.parametrize("coords", ["curvature", "paper"])
@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_coriolis_matrix_skew_property(coords, base, rng):
    ch = make_chain(coords, base)
    q, v = random_state(ch, rng)
    C = ch.coriolis_matrix(q, v)
    assert rel(C @ v + ch.generalized_gravity(q), ch.nonlinear_effects(q, v)) < 1e-12
    h = 1e-6
    Mdot = (ch.mass_matrix(ch.integrate(q, v, h)) - ch.mass_matrix(ch.integrate(q, v, -h))) / (2 * h)
    N = Mdot - 2 * C
    assert np.abs(N + N.T).max() < 1e-7 * np.abs(Mdot).max()


def test_frozen_shape_composite_inertia_and_bias_match_pinocchio(rng):
    """With its shape frozen the arm is one rigid body made of the slice disks: the base block
    of M and of nle (for qdot_e = 0) equal pinocchio.crba/rnea of those disks on a free flyer."""
    ch = make_chain("curvature", "floating")
    q, v = random_state(ch, rng)
    v[6:] = 0.0
    model = pin.Model()
    model.gravity = pin.Motion(np.r_[G_W, 0, 0, 0])
    jid = model.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    X0 = ch.placements(q)[0]
    X_roots = [X0.inverse() * X for X in ch.placements(q)]  # in the base frame
    for j, s in enumerate(ch.segments):
        for a, w in zip(s.alpha_nodes, s.alpha_weights):
            m = s.mass * w
            r = s.radius
            I = pin.Inertia(m, np.zeros(3), np.diag([m * r * r / 4, m * r * r / 4, m * r * r / 2]))
            model.appendBodyToJoint(jid, I, X_roots[j] * s.slice_placement(q[ch.q_slice(j)], a))
    data = model.createData()
    M_pin = pin.crba(model, data, q[:7])
    M_pin = np.triu(M_pin) + np.triu(M_pin, 1).T
    assert rel(ch.mass_matrix(q)[:6, :6], M_pin) < 1e-12
    nle_pin = pin.rnea(model, data, q[:7], v[:6], np.zeros(6))
    assert rel(ch.nonlinear_effects(q, v)[:6], nle_pin) < 1e-12


def test_zero_gravity_floating_arm_conserves_momentum_under_pressure(rng):
    ch = make_chain("curvature", "floating", gravity=np.zeros(3))
    q, v = random_state(ch, rng, bend=4.0)
    p = rng.uniform(0, 5e4, ch.nu)
    # instantaneous balance: dh/dt = 0 along (v, a)
    a = ch.forward_dynamics(q, v, p)
    h0 = ch.momentum(q, v)
    eps = 1e-6
    dh = (ch.momentum(ch.integrate(q, v, eps), v + eps * a) - ch.momentum(ch.integrate(q, v, -eps), v - eps * a)) / (2 * eps)
    assert np.linalg.norm(dh) < 1e-6 * np.linalg.norm(h0)
    # over an integrated second (RK4 in a local chart of the base, exact up to 4th order)
    q1, v1 = rk4_chart(ch, q, v, lambda q, v: ch.forward_dynamics(q, v, p), T=1.0, dt=5e-4)
    h1 = ch.momentum(q1, v1)
    assert np.linalg.norm(h1 - h0) < 1e-6 * np.linalg.norm(h0)
    assert np.linalg.norm(ch.difference(q, q1)) > 0.1  # it did move


def rk4_chart(ch, q0, v0, acc, T, dt):
    """Classical RK4 on ``(delta, q_e, v)`` with ``q = integrate(q0, delta)``; the base chart uses
    ``delta_dot = Jexp6(delta)^-1 v_B`` so the scheme is 4th order on the Lie group."""
    def f(y):
        d, v = y[: ch.nv], y[ch.nv :]
        q = ch.integrate(q0, d)
        dd = v.copy()
        if ch.floating:
            dd[:6] = np.linalg.solve(pin.Jexp6(pin.Motion(d[:6])), v[:6])
        return np.concatenate([dd, acc(q, v)])

    y = np.concatenate([np.zeros(ch.nv), v0])
    for _ in range(int(round(T / dt))):
        k1 = f(y)
        k2 = f(y + 0.5 * dt * k1)
        k3 = f(y + 0.5 * dt * k2)
        k4 = f(y + dt * k3)
        y = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return ch.integrate(q0, y[: ch.nv]), y[ch.nv :]


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_energy_is_conserved_without_damping_and_pressure(base, rng):
    segs = [Segment(**SEGMENT_KW), Segment(**SEGMENT_KW, coords="paper"), Segment(**SEGMENT_KW)]
    ch = Chain(segs, base=base)
    q, v = random_state(ch, rng, bend=3.0)
    q[ch.q_slice(1)] = [0.2, 0.5, 6.0]  # keep the paper-coordinate segment away from kappa = 0
    v[ch.v_slice(1)] *= 0.1
    E = lambda q, v: ch.kinetic_energy(q, v) + ch.potential_energy(q)  # noqa: E731
    E0 = E(q, v)
    q1, v1 = rk4_chart(ch, q, v, lambda q, v: ch.forward_dynamics(q, v), T=0.3, dt=5e-4)
    # the arm falls and swings: compare with the kinetic energy it exchanges (error is RK4's,
    # falling as dt^4 or faster: 2.8e-8, 6.0e-10, 1.9e-12 J at dt = 1e-3, 5e-4, 2.5e-4)
    scale = max(ch.kinetic_energy(q, v), ch.kinetic_energy(q1, v1))
    assert scale > 0.5
    assert abs(E(q1, v1) - E0) < 1e-6 * scale


def test_prescribed_base_equals_floating_base_with_that_motion(rng):
    """A prescribed base's inverse dynamics is the floating chain's, with the base acceleration given."""
    X = pin.SE3(pin.exp3(np.array([0.3, 0.2, -0.5])), np.array([0.1, 0.0, 0.4]))
    V = rng.normal(size=6)
    A = rng.normal(size=6)
    pre = make_chain("curvature", "prescribed", base_motion=lambda t: (X, V, A))
    flo = make_chain("curvature", "floating")
    q, v = random_state(pre, rng)
    a = rng.normal(size=pre.nv)
    qf = np.concatenate([pin.SE3ToXYZQUAT(X), q])
    vf = np.concatenate([V, v])
    af = np.concatenate([A, a])
    assert rel(pre.inverse_dynamics(q, v, a), flo.inverse_dynamics(qf, vf, af)[6:]) < 1e-12
    p = rng.uniform(0, 3e4, pre.nu)
    acc = pre.forward_dynamics(q, v, p)
    assert rel(pre.inverse_dynamics(q, v, acc), pre.internal_forces(q, v, p)) < 1e-10
    assert pre.kinetic_energy(q, v) == pytest.approx(flo.kinetic_energy(qf, vf), rel=1e-12)
    assert rel(pre.backbone(q), flo.backbone(qf)) < 1e-14
    with pytest.raises(ValueError, match="coriolis_matrix is defined for base='fixed' or 'floating'"):
        pre.coriolis_matrix(q, v)


# ------------------------------------------------------------------ kinematics


def test_placements_backbone_and_tip_jacobian(rng):
    ch = make_chain("paper", "floating")
    q, v = random_state(ch, rng)
    X = ch.placements(q)
    X_pin = [pin.XYZQUATToSE3(q[:7])]  # composed with Pinocchio's exp6 segment by segment
    for j, s in enumerate(ch.segments):
        X_pin.append(X_pin[-1] * s.tip_placement(q[ch.q_slice(j)]))
    for a, b in zip(X, X_pin):
        assert np.abs(a.homogeneous - b.homogeneous).max() < 1e-14
    Xf, bbf = ch.frames(q, 11)
    assert all(np.abs(a.homogeneous - b.homogeneous).max() < 1e-15 for a, b in zip(Xf, X))
    bb = ch.backbone(q, 11)
    assert np.array_equal(bb, bbf)
    assert bb.shape == (3, 11, 3)
    for j in range(3):
        assert np.allclose(bb[j, 0], X[j].translation, atol=1e-14)
        assert np.allclose(bb[j, -1], X[j + 1].translation, atol=1e-14)
    # tip Jacobian against the finite difference of the tip placement along v
    h = 1e-6
    Xp = ch.tip_placement(ch.integrate(q, v, h))
    Xm = ch.tip_placement(ch.integrate(q, v, -h))
    fd = pin.log6(Xm.inverse() * Xp).vector / (2 * h)
    Jl = ch.tip_jacobian(q)
    assert rel(Jl @ v, fd) < 1e-7
    assert rel(ch.tip_velocity(q, v), Jl @ v) < 1e-12
    assert rel(ch.tip_jacobian(q, "world") @ v, X[-1].action @ (Jl @ v)) < 1e-12
    Jw = ch.tip_jacobian(q, "local_world_aligned")
    assert rel(Jw[:3] @ v, X[-1].rotation @ (Jl[:3] @ v)) < 1e-12
    # integrate / difference round trip on the Lie group
    q1 = ch.integrate(q, v, 0.3)
    assert rel(ch.difference(q, q1), 0.3 * v) < 1e-12


def _quat_equal(q, R):
    """``q`` (x, y, z, w), w >= 0, is Pinocchio's quaternion of ``R`` up to its sign."""
    ref = pin.Quaternion(R).coeffs()
    ref = ref if ref[3] >= 0 else -ref
    return np.abs(np.asarray(q) - ref).max()


@pytest.mark.parametrize("coords, base", [("curvature", "fixed"), ("paper", "floating"), ("curvature", "prescribed")])
def test_frames_batch_equals_one_configuration_at_a_time(coords, base, rng):
    """frames_batch (one compiled call for K configurations) == placements/frames of each,
    quaternions == Pinocchio's, backbone ends == the frame origins."""
    motion = lambda t: (pin.SE3(pin.exp3(np.array([0.2 * t, -0.5, 0.1])), np.array([t, 0.2, -0.1])),  # noqa: E731
                        np.zeros(6), np.zeros(6))
    kw = {"base_motion": motion} if base == "prescribed" else dict(BASES[0][1]) if base == "fixed" else {}
    ch = make_chain(coords, base, **kw)
    Q = np.array([random_state(ch, rng)[0] for _ in range(7)])
    t = np.linspace(0.0, 0.6, 7)
    f = ch.frames_batch(Q, 9, t=t)
    assert f.rotation.shape == (7, 4, 3, 3) and f.translation.shape == (7, 4, 3)
    assert f.quaternion.shape == (7, 4, 4) and f.backbone.shape == (7, 3, 9, 3)
    for k in range(7):
        X, bb = ch.frames(Q[k], 9, t=t[k])
        np.testing.assert_array_equal(bb, f.backbone[k])
        for j in range(4):
            np.testing.assert_array_equal(X[j].rotation, f.rotation[k, j])
            np.testing.assert_array_equal(X[j].translation, f.translation[k, j])
            assert _quat_equal(f.quaternion[k, j], X[j].rotation) < 1e-15
            assert f.quaternion[k, j, 3] >= 0.0
        np.testing.assert_allclose(f.backbone[k, :, -1], f.translation[k, 1:], rtol=0, atol=1e-15)
        np.testing.assert_allclose(f.backbone[k, :, 0], f.translation[k, :-1], rtol=0, atol=1e-15)


@pytest.mark.parametrize("coords, base", [("curvature", "fixed"), ("paper", "floating"), ("curvature", "prescribed")])
def test_frames_batch_skip_checks_into_out_gives_the_same_frames(coords, base, rng):
    """The recorder's fast path (``skip_checks``, written into the first K rows of ``out``,
    from a strided view of record rows) == the checked call, bit for bit; ``out`` alone is
    refused."""
    motion = lambda t: (pin.SE3(pin.exp3(np.array([0.2 * t, -0.5, 0.1])), np.array([t, 0.2, -0.1])),  # noqa: E731
                        np.zeros(6), np.zeros(6))
    kw = {"base_motion": motion} if base == "prescribed" else dict(BASES[0][1]) if base == "fixed" else {}
    ch = make_chain(coords, base, **kw)
    Q = np.array([random_state(ch, rng)[0] for _ in range(5)])
    t = np.linspace(0.0, 0.6, 5)
    rows = np.zeros((8, ch.nq + 3))
    rows[:5, 2 : 2 + ch.nq] = Q
    view = rows[:5, 2 : 2 + ch.nq]  # not contiguous, as the recorder's rows
    out = Frames(np.full((8, ch.n + 1, 3, 3), np.nan), np.full((8, ch.n + 1, 3), np.nan),
                 np.full((8, ch.n + 1, 4), np.nan), np.full((8, ch.n, 9, 3), np.nan))
    fast = ch.frames_batch(view, 9, t=t, skip_checks=True, out=out)
    ref = ch.frames_batch(Q, 9, t=t)
    for a, b, o in zip(fast, ref, out):
        np.testing.assert_array_equal(a, b)
        assert a.shape == b.shape and np.shares_memory(a, o) and np.isnan(o[5:]).all()
    for a, b in zip(ch.frames_batch(view, 9, t=t, skip_checks=True), ref):
        np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="out is for skip_checks=True only"):
        ch.frames_batch(Q, 9, t=t, out=out)


def test_evenly_spaced_backbone_points_equal_each_point_s_own_arc_pose(rng):
    """``recursive.frames`` steps along a segment by one rigid arc step for evenly spaced
    points: each point within 1e-15 m of its own ``arc_pose`` placed by its root frame,
    straight, bent and nearly straight (the series branch), 2 to 41 points."""
    from qchain.model.arc import arc_pose
    from qchain.algorithms.recursive import frames

    q = np.array([[[0.2, 0.0, 0.0], [0.25, 7.0, -3.0], [0.15, 1e-9, 2e-9], [0.3, -12.0, 0.5]]])
    paper = np.zeros(4, dtype=np.bool_)
    X = pin.SE3(pin.exp3(np.array([0.3, -1.2, 0.4])), np.array([0.1, -0.2, 0.3]))
    for P in (2, 3, 12, 41):
        alpha = np.linspace(0.0, 1.0, P)
        R, o, quat = np.empty((1, 5, 3, 3)), np.empty((1, 5, 3)), np.empty((1, 5, 4))
        pts = np.empty((1, 4, P, 3))
        frames(q, paper, X.rotation[None].copy(), X.translation[None].copy(), alpha, R, o, quat, pts)
        Rs, ps = np.empty((3, 3)), np.empty(3)
        for j in range(4):
            for i, a in enumerate(alpha):
                arc_pose(a, *q[0, j], Rs, ps)
                np.testing.assert_allclose(pts[0, j, i], o[0, j] + R[0, j] @ ps, rtol=0, atol=1e-15)
            assert np.array_equal(pts[0, j, 0], o[0, j]) and np.array_equal(pts[0, j, -1], o[0, j + 1])


def test_frames_batch_quaternions_on_every_branch():
    """Rotations by ~pi about each axis (where 1 + trace -> 0) and the identity: every branch
    of the rotation -> quaternion conversion against Pinocchio."""
    seg = Segment(**{**SEGMENT_KW, "length": 0.2, "radius": 0.02})
    for axis in np.eye(3):
        for angle in (0.0, 1.0, np.pi - 1e-9, np.pi):
            X = pin.SE3(pin.exp3(angle * axis), np.zeros(3))
            ch = Chain([seg], base_placement=X)
            q = ch.neutral()
            f = ch.frames_batch(q[None], 2)
            assert _quat_equal(f.quaternion[0, 0], X.rotation) < 1e-15
            R = pin.Quaternion(f.quaternion[0, 0, 3], *f.quaternion[0, 0, :3]).toRotationMatrix()
            assert np.abs(R - X.rotation).max() < 1e-15


def test_frames_batch_errors_name_the_row(rng):
    ch = make_chain("curvature", "floating")
    Q = np.array([random_state(ch, rng)[0] for _ in range(5)])
    bad = Q.copy()
    bad[3, 9] = np.nan
    with pytest.raises(ValueError, match=r"Q\[3\]: q has non-finite entries at indices \[9\]"):
        ch.frames_batch(bad)
    bad = Q.copy()
    bad[2, 7] = -0.1  # segment 0's length
    with pytest.raises(DomainError, match=r"Q\[2\]: segment 0"):
        ch.frames_batch(bad)
    bad = Q.copy()
    bad[4, 3:7] *= 1.1
    with pytest.raises(ValueError, match=r"Q\[4\]: .*quaternion"):
        ch.frames_batch(bad)
    with pytest.raises(ValueError, match=r"Q must have shape \(K, nq\) = \(K, 16\), got \(5, 15\)"):
        ch.frames_batch(Q[:, :-1])
    with pytest.raises(ValueError, match="points_per_segment must be an int >= 2 and <= 10000, got an int 1"):
        ch.frames_batch(Q, 1)
    assert ch.frames_batch(Q[:0]).backbone.shape == (0, 3, 20, 3)


# ------------------------------------------------------------------ errors


def test_input_errors():
    ch = make_chain("paper", "floating")
    q = ch.neutral()
    q[ch.q_slice(0)] = [0.2, 0.0, 1.0]
    q[ch.q_slice(2)] = [0.16, 0.0, 1.0]
    v = np.zeros(ch.nv)
    with pytest.raises(ValueError, match=r"q must have shape \(16,\), got shape \(15,\)"):
        ch.mass_matrix(q[:-1])
    with pytest.raises(ValueError, match=r"v must have shape \(15,\), got shape \(3,\)"):
        ch.nonlinear_effects(q, np.zeros(3))
    with pytest.raises(ValueError, match=r"a must have shape \(15,\)"):
        ch.inverse_dynamics(q, v, np.zeros(14))
    with pytest.raises(ValueError, match=r"p must have shape \(9,\), got shape \(3,\)"):
        ch.forward_dynamics(q, v, np.zeros(3))
    with pytest.raises(ValueError, match=r"tau must have shape \(15,\)"):
        ch.forward_dynamics(q, v, None, np.zeros(9))
    bad = q.copy()
    bad[8] = np.nan
    with pytest.raises(ValueError, match=r"q has non-finite entries at indices \[8\]"):
        ch.mass_matrix(bad)
    bad = q.copy()
    bad[3:7] = [0, 0, 0, 1.001]
    with pytest.raises(ValueError, match=r"quaternion .* norm 1.001.* within 1e-06 of 1"):
        ch.mass_matrix(bad)
    ok = q.copy()
    ok[3:7] = [0, 0, 0, 1 + 5e-7]
    assert np.all(np.isfinite(ch.mass_matrix(ok)))
    bad = q.copy()
    bad[ch.q_slice(1)] = [0.18, 60.0, 0.0]
    with pytest.raises(DomainError, match=r"segment 1 \(q\[10:13\]\): \|kappa\| r_s = 1.08 must be < 1"):
        ch.forward_dynamics(bad, v)
    bad = q.copy()
    bad[ch.q_slice(2)] = [-0.1, 0.0, 0.0]
    with pytest.raises(DomainError, match=r"segment 2 \(q\[13:16\]\): length l = -0.1 m must be > 0"):
        ch.forward_dynamics(bad, v)
    sing = q.copy()
    sing[ch.q_slice(0)] = [0.2, 0.0, 0.0]
    with pytest.raises(SingularConfigurationError, match=r"segment 0 .*coords='curvature'"):
        ch.forward_dynamics(sing, v)
    with pytest.raises(ValueError, match=r"base must be one of"):
        Chain(ch.segments, base="wheeled")
    with pytest.raises(ValueError, match=r"needs base_motion"):
        Chain(ch.segments, base="prescribed")
    with pytest.raises(TypeError, match=r"segments\[1\] must be a qchain.Segment"):
        Chain([ch.segments[0], "x"])
