"""The n-segment chain against particle brute force, Pinocchio, conservation laws and itself;
its methods, workspaces and kinematics refuse bad arrays by name and never return NaN."""

import copy
import math
import pickle
import time
from decimal import Decimal

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given
from hypothesis import strategies as st

import qchain
from helpers import SEGMENT_KW, rel
from particles import brute_chain
from qchain import Chain, DomainError, QchainError, Segment, SingularConfigurationError
from qchain.arm.chain import Frames
from qchain.arm.data import Data
from qchain.errors import NonFiniteError
from qchain.sim.simulation import Event, simulate
from support import CH1, CH2, CHF, FEW, QB, S, SEGMENT, RaisingFloat, refused, soft_arm, soft_segment, value_id

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


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
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


# --------------------------------------------------------------------------------------
# Bad input (issue 18): refused where it enters, naming the argument, the value and the bound;
# never a foreign traceback, a hang, a crash, a silent NaN or lost data.

Q2 = np.r_[QB, 0.1, -3.0, 4.0]
V2 = np.array([0.01, 1.0, -0.5, 0.0, 0.3, 0.2])
P2 = np.full(6, 1e4)


def prescribed(motion):
    return Chain([S], base="prescribed", base_motion=motion)


STILL = prescribed(lambda t: (pin.SE3.Identity(), np.zeros(6), np.zeros(6)))
NOT_REAL = [True, np.True_, "0.1", None, 0.1 + 0j, {"a": 1}, object(), RaisingFloat(), Decimal("0.1"), np.array([0.1])]
NOT_FINITE_OR_HUGE = [math.nan, math.inf, -math.inf, 2**70, 10**400, 1e300]


@pytest.mark.parametrize("value", NOT_REAL + NOT_FINITE_OR_HUGE, ids=value_id)
def test_times_are_checked_where_they_enter_even_where_they_do_not_matter(value):
    """A fixed base ignores ``t``, a prescribed one calls ``base_motion(t)``: either way a
    time that is not a real number within +-1e12 s is refused by name (it was ignored, or
    reached ``float()`` and the user's callable)."""
    refused(lambda: CH2.kinetic_energy(Q2, V2, t=value), "t")
    refused(lambda: STILL.base_state(value), "t")
    refused(lambda: STILL.tip_placement(QB, value), "t")
    if any(value is x for x in NOT_REAL) or isinstance(value, float) and not math.isfinite(value) or value is NOT_FINITE_OR_HUGE[4]:
        refused(lambda: Event(lambda t, q, v: 1.0, direction=value), "direction")  # its sign is what counts


def test_integrate_and_difference_never_return_non_finite_configurations():
    for bad in ([np.nan, 9, -2.5, 0.1, -2.7, 4.2], [0.1, 9, -2.5, 0.1, -2.7, np.inf]):
        refused(lambda: CH2.integrate(bad, V2), "q")
        refused(lambda: CH2.difference(bad, Q2), "q0")
        refused(lambda: CH2.difference(Q2, bad), "q1")
    with pytest.raises(NonFiniteError, match=r"Chain.integrate: q \(\+\) v dt is not finite .* q\[0\]"):
        CH2.integrate(Q2, np.full(6, 1e300), 1e10)
    with pytest.raises(NonFiniteError, match="Chain.difference"):
        CH2.difference(np.full(6, -1e308), np.full(6, 1e308))
    refused(lambda: CH2.integrate(Q2, V2, 2**70), "dt")
    qf = CHF.neutral()
    assert np.all(np.isfinite(CHF.integrate(qf, np.ones(9), 0.5)))


def test_a_missing_velocity_is_named_not_a_numba_typing_error():
    msg = refused(lambda: CH2.tip_velocity(Q2, None), "v", TypeError)
    assert "Chain.tip_velocity" in msg


def test_indices_and_workspaces_are_checked():
    refused(lambda: CH2.coordinate_name(-5), "i")
    refused(lambda: CH2.coordinate_name(True), "i")
    refused(lambda: CH2.coordinate_name(20.0), "i")
    assert CH2.coordinate_name(0) == "segment 0, l"
    refused(lambda: CH2.q_slice(2), "j")
    refused(lambda: CH2.v_slice(-1), "j")
    for n in (True, 0, -5, 10**30, 20.0, "3", None):
        refused(lambda n=n: Data(n, 3), "n")
    refused(lambda: Data(2, 7), "nv")
    other = Chain([S, S, S]).create_data()
    for call in (lambda d: CH2.forward_dynamics(Q2, V2, P2, data=d), lambda d: CH2.mass_matrix(Q2, data=d),
                 lambda d: CH2.forward_dynamics_derivatives(Q2, V2, P2, data=d),
                 lambda d: CH2.inverse_dynamics_derivatives(Q2, V2, V2, data=d),
                 lambda d: CH2.mass_matrix_derivative(Q2, data=d),
                 lambda d: CH2.forward_dynamics(Q2, V2, P2, data=d, skip_checks=True)):
        refused(lambda: call(other), "data", ValueError)
        refused(lambda: call(object()), "data", TypeError)
    d = CH2.create_data()
    assert np.array_equal(CH2.forward_dynamics(Q2, V2, P2, data=d), CH2.forward_dynamics(Q2, V2, P2))


def test_calls_without_data_work_in_a_workspace_of_their_thread():
    """Without ``data=`` a thread's calls reuse the workspace the chain keeps for it: fresh
    results equal to those with a ``data``, another thread its own, and a copy or pickle of
    the chain takes none along."""
    import threading

    ch = Chain([S, S])
    ref = ch.forward_dynamics(Q2, V2, P2, data=ch.create_data())
    refd = ch.forward_dynamics_derivatives(Q2, V2, P2, data=ch.create_data())
    a1 = ch.forward_dynamics(Q2, V2, P2)
    d1 = ch.forward_dynamics_derivatives(Q2, V2, P2)
    a2 = ch.forward_dynamics(Q2, V2, 2 * P2)
    d2 = ch.forward_dynamics_derivatives(Q2, V2, 2 * P2)
    assert np.array_equal(a1, ref) and not np.array_equal(a2, ref)  # a1 was not overwritten
    for x, y in zip(d1, refd):
        assert np.array_equal(x, y)
    assert not np.array_equal(d1.da_dq, d2.da_dq)
    other = []
    t = threading.Thread(target=lambda: other.append(ch.forward_dynamics(Q2, V2, P2)))
    t.start()
    t.join()
    assert np.array_equal(other[0], ref)
    assert len(ch._own_data) == 2
    for clone in (pickle.loads(pickle.dumps(ch)), copy.deepcopy(ch)):
        assert clone._own_data == {}
        assert np.array_equal(clone.forward_dynamics(Q2, V2, P2), ref)


def test_frames_batch_checks_the_arrays_it_writes_into_even_on_the_unchecked_path():
    """A float32 ``out`` crashed the process (the compiled pass wrote float64 into it)."""
    Q = np.tile(Q2, (4, 1))
    good = CH2.frames_batch(Q, 5)
    for out in (tuple(a.astype(np.float32) for a in good), CH2.frames_batch(Q[:2], 5), CH2.frames_batch(Q, 3),
                tuple(np.asfortranarray(a) if a.ndim > 2 else a for a in good)):
        refused(lambda out=out: CH2.frames_batch(Q, 5, skip_checks=True, out=out), "out", ValueError)
    refused(lambda: CH2.frames_batch(Q, 5, skip_checks=True, out=([1], [2], [3], [4])), "out")
    mine = tuple(np.empty_like(a) for a in good)
    got = CH2.frames_batch(Q.astype(">f8"), 5, skip_checks=True, out=mine)  # big-endian Q: converted, not a crash
    assert all(np.array_equal(a, b) for a, b in zip(got, good))
    Qp = np.tile(QB, (3, 1))
    refused(lambda: STILL.frames_batch(Qp, 4, t=[0.0, 1.0]), "t")
    refused(lambda: STILL.frames_batch(Qp, 4, t=np.nan), "t")
    refused(lambda: STILL.frames_batch(Qp, 4, t="x"), "t")


def test_a_singular_inertia_names_the_segment_and_its_coordinates():
    for q in ([1e-300, 0.0, 0.0], [5e-324, 1.0, 0.0]):
        for call in (lambda: CH1.forward_dynamics(q, np.ones(3)),
                     lambda: CH1.forward_dynamics_derivatives(q, np.ones(3), np.full(3, 1e4))):
            msg = refused(call, "segment 0", QchainError)
            assert "not positive definite" in msg and "q[0:3]" in msg, msg


def test_the_articulated_block_inverse_matches_numpy_and_refuses_an_indefinite_block(rng):
    """``aba`` inverts each segment's 3 x 3 articulated block through its Cholesky factor, written
    out; a pivot that is not positive leaves the block as it was (the pass then reports it)."""
    from qchain.algorithms.recursive import _spd3_inverse

    for cond in (1.0, 1e4, 1e8):  # a segment's stretch and bending inertias differ by orders
        Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        A = Q @ np.diag([1.0, cond ** 0.5, cond]) @ Q.T
        A = 0.5 * (A + A.T)
        got = A.copy()
        assert _spd3_inverse(got)
        assert np.array_equal(got, got.T)
        assert rel(got, np.linalg.inv(A)) < 1e-15 * cond * 10
    for bad in (np.diag([1.0, -1.0, 1.0]), np.diag([1.0, 1.0, 0.0]), np.full((3, 3), np.nan)):
        got = bad.copy()
        assert not _spd3_inverse(got)
        assert np.array_equal(got, bad, equal_nan=True)


def test_placements_must_be_rotations_within_the_declared_positions():
    refused(lambda: Chain([S], base_placement=pin.SE3(2 * np.eye(3), np.zeros(3))), "base_placement.rotation")
    refused(lambda: Chain([S], base_placement=pin.SE3(np.eye(3), np.array([1e300, 0, 0]))), "base_placement")
    skewed = prescribed(lambda t: (pin.SE3(2 * np.eye(3), np.zeros(3)), np.zeros(6), np.zeros(6)))
    refused(lambda: skewed.forward_dynamics(QB, np.zeros(3)), "base_motion")
    refused(lambda: simulate(skewed, QB, np.zeros(3), (0, 0.01)), "base_motion")
    refused(lambda: CHF.mass_matrix(np.r_[1e300, 0, 0, 0, 0, 0, 1.0, QB]), "base position")
    refused(lambda: Chain(S), "segments", TypeError)
    refused(lambda: Chain(None), "segments", TypeError)


def test_the_base_placement_is_given_as_a_copy():
    """It was the chain's own SE3: changing it left the passes' gravity in the base frame stale."""
    X = pin.SE3(pin.rpy.rpyToMatrix(0.3, 0.0, 0.0), np.array([0.0, 0.0, 1.0]))
    ch = Chain([S], base_placement=X)
    q = ch.neutral()
    g0 = ch.generalized_gravity(q)
    got = ch.base_placement
    got.rotation = np.eye(3)
    X.rotation = np.eye(3)
    again = ch.generalized_gravity(q)
    assert np.array_equal(g0, again)
    assert np.allclose(ch.base_placement.rotation, pin.rpy.rpyToMatrix(0.3, 0.0, 0.0), atol=0, rtol=0)


@FEW
@given(kind=st.sampled_from(["bool", "str", "complex", "nan", "short", "2-D", "object"]),
       method=st.sampled_from(["integrate", "difference", "tip_velocity", "momentum", "coriolis_matrix",
                               "inverse_dynamics_derivatives", "pressure_stiffness", "mass_matrix_derivative"]))
def test_chain_methods_refuse_bad_arrays_by_name(kind, method):
    bad = {"bool": np.ones(6, bool), "str": ["0.1"] * 6, "complex": Q2 + 0j, "nan": np.r_[np.nan, Q2[1:]],
           "short": Q2[:5], "2-D": Q2[None], "object": np.array([0.1, object(), 0, 0, 0, 0], dtype=object)}[kind]
    call = {"integrate": lambda: CH2.integrate(bad, V2), "difference": lambda: CH2.difference(bad, Q2),
            "tip_velocity": lambda: CH2.tip_velocity(bad, V2), "momentum": lambda: CH2.momentum(bad, V2),
            "coriolis_matrix": lambda: CH2.coriolis_matrix(bad, V2),
            "inverse_dynamics_derivatives": lambda: CH2.inverse_dynamics_derivatives(bad, V2, V2),
            "pressure_stiffness": lambda: CH2.pressure_stiffness(bad, P2),
            "mass_matrix_derivative": lambda: CH2.mass_matrix_derivative(bad)}[method]
    refused(call, "q0" if method == "difference" else "q")


@pytest.mark.filterwarnings("ignore:the matrix subclass:PendingDeprecationWarning")
def test_masked_arrays_are_refused_by_name_or_taken_as_plain_arrays():
    """A masked array with a masked entry is refused where it enters (it reached numba, or
    its masked entries were used silently); an unmasked one, or an np.matrix row, is a plain
    array for compiled code."""
    from qchain.checks.convert import as_batch, as_matrix, as_real, as_real_array, as_vector

    masked = np.ma.masked_array(QB, mask=[0, 1, 0])
    for call in (lambda: simulate(CH1, masked, np.zeros(3), (0, 0.01)),
                 lambda: as_vector("q0", masked, 3), lambda: as_real_array("q0", masked),
                 lambda: as_batch("q0", masked, 3), lambda: as_matrix("q0", masked.reshape(1, 3), (1, 3))):
        assert "masked entries" in refused(call, "q0")
    refused(lambda: Chain([S], gravity=np.ma.masked_array([0, 0, -9.81], mask=[0, 0, 1])), "gravity")
    refused(lambda: simulate(CH1, QB, np.zeros(3), (0, 0.01), t_eval=np.ma.masked_array([0, 0.005], mask=[0, 1])),
            "t_eval")
    refused(lambda: simulate(CH1, QB, np.zeros(3), (0, 0.01), pressure=np.ma.masked_array(np.ones(3), mask=[0, 1, 0])),
            "pressure")
    refused(lambda: simulate(CH1, QB, np.zeros(3), (0, 0.01),
                             pressure=lambda t, q, v: np.ma.masked_array(np.ones(3), mask=[0, 1, 0])), "pressure")
    refused(lambda: as_real("t", np.ma.masked_array(1.0, mask=True)), "t")
    for plain in (np.ma.masked_array(QB), np.ma.masked_array(QB, mask=[0, 0, 0])):
        a = as_vector("q0", plain, 3)
        assert type(a) is np.ndarray and np.array_equal(a, QB)
        r = simulate(CH1, plain, np.zeros(3), (0, 0.01))
        assert r.success and np.array_equal(r.q[-1], simulate(CH1, QB, np.zeros(3), (0, 0.01)).q[-1])
    assert type(as_real_array("x", np.matrix([[1.0, 2.0]]))) is np.ndarray
    refused(lambda: simulate(CH1, np.matrix(QB), np.zeros(3), (0, 0.01)), "q0")


def test_a_0d_object_array_of_segments_is_refused_by_name():
    msg = refused(lambda: Chain(np.array(S, dtype=object)), "segments")
    assert "sequence" in msg
    assert Chain(np.array([S, S], dtype=object)).n == 2


@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
def test_copies_of_a_model_keep_its_arrays_read_only(how):
    """numpy unpickles every array writeable: a copy's gravity could be set outside its bound."""
    from qchain.sim.inputs import Sine

    dup = copy.deepcopy if how == "deepcopy" else (lambda x: pickle.loads(pickle.dumps(x)))
    ch = dup(soft_arm(floating=True) if "floating" in Chain.__init__.__code__.co_varnames else soft_arm())
    for a in (ch.gravity, ch.active, ch.segments[0].alpha_weights, ch.segments[0].disk_inertia):
        assert not a.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            a[...] = 0.0
    s = dup(Sine([1.0] * 9, 2.0))
    assert not s.amplitude.flags.writeable
    q, v, p = ch.neutral(), np.zeros(ch.nv), np.zeros(ch.nu)
    np.testing.assert_array_equal(ch.forward_dynamics(q, v, p), soft_arm().forward_dynamics(q, v, p))


def test_kinematics_arguments_are_checked_where_they_enter():
    ch = soft_arm()
    q = ch.neutral()
    Q = np.stack([q, q])
    ch.backbone(q, 20)
    for bad in ([20], np.array(20.0), 20.0, True):
        with pytest.raises(ValueError, match=r"points_per_segment must be an int >= 2 and <= 10000"):
            ch.backbone(q, bad)
    for t in (float("nan"), "soon"):
        with pytest.raises((TypeError, ValueError), match=r"\bt\b"):
            ch.frames_batch(Q, t=t)
    for flag in (np.array([True, False]), "no"):
        with pytest.raises(TypeError, match=r"skip_checks must be True or False"):
            ch.forward_dynamics(q, np.zeros(ch.nv), np.zeros(ch.nu), skip_checks=flag)
    for segs in ({Segment(**SEGMENT)}, {0: Segment(**SEGMENT)}):
        with pytest.raises(TypeError, match=r"segments must be a sequence"):
            Chain(segs)
    assert not hasattr(qchain, "no_such.sub") and not hasattr(qchain, "..x") and hasattr(qchain, "cli")


def test_read_only_and_strided_arrays_do_not_compile_the_passes_again():
    ch = soft_arm()
    q, v, p, tau = ch.neutral(), np.zeros(ch.nv), np.zeros(ch.nu), np.zeros(ch.nv)
    ch.forward_dynamics_derivatives(q, v, p, tau)
    q2 = np.zeros(2 * ch.nq)
    q2[::2] = q
    for a in (q, v, p, tau):
        a.flags.writeable = False
    t0 = time.perf_counter()
    ch.forward_dynamics_derivatives(q2[::2], v, p, tau)
    ch.forward_dynamics(q, v, p)
    assert time.perf_counter() - t0 < 2.0  # a compile of the passes takes 8-20 s


@pytest.mark.slow
def test_a_workspace_cannot_be_relabelled_and_gravity_cannot_be_reassigned():
    """d.n, d.nv = 8, 24 made a 2-segment workspace pass for 8 segments: a wrong answer, then
    a segmentation fault; Chain.gravity = ... was taken by some passes and not others."""
    ch = soft_arm(2)
    d = ch.create_data()
    ch.mass_matrix(ch.neutral(), data=d)
    for name, value in (("n", 8), ("nv", 24), ("M", np.zeros((1, 1)))):
        with pytest.raises(AttributeError, match=rf"Data.{name} cannot be set"):
            setattr(d, name, value)
    with pytest.raises(AttributeError, match="Chain.gravity is read-only"):
        ch.gravity = np.zeros(3)
    import itertools

    with pytest.raises(ValueError, match=r"segments must hold at most 1e\+06 Segments"):
        Chain(itertools.repeat(Segment(**SEGMENT)))


def test_a_workspace_s_arrays_are_views_of_its_one_buffer_at_the_layout_s_places():
    """Every array of a Data lies in ``kernel_buffer`` where ``kernel_layout`` says, with the
    allocators' shapes (what compiled code carves from the buffer and the table), made at the
    first use of any of them; the buffer is zeros until a pass writes."""
    from qchain.algorithms.layout import kernel_arrays

    ch = soft_arm(3, base="floating")
    d = ch.create_data()
    buf, table = d.kernel_buffer, d.kernel_layout
    assert buf.shape == (table[-1, 0],) and not buf.any()
    fields = [*d.aba_workspace()._fields, *d.rnea_workspace()._fields, *d.aba_derivatives_workspace()._fields,
              *d.planar_workspace()._fields]
    for name, ref, row in zip(fields, kernel_arrays(ch.n, ch.nv), table[:-1], strict=True):
        x = getattr(d, name)
        assert x.shape == ref.shape and x.dtype == np.float64 and x.flags.c_contiguous
        assert x.ctypes.data == buf.ctypes.data + 8 * int(row[0]) and np.shares_memory(x, buf)
    out = ch.forward_dynamics_derivatives(ch.neutral(), np.zeros(ch.nv), data=d)
    assert out.da_dtau is d.da_dtau and np.shares_memory(d.da_dtau, buf) and buf.any()


def test_the_data_module_s_table_names_every_array_of_a_workspace_and_no_other():
    """``qchain.arm.data``'s table of arrays (the first column of each row) against a fresh
    Data: each name it lists is an array of it, and each array of it is listed."""
    import re

    from qchain.arm import data as data_module
    from qchain.arm.data import _KERNEL_NAMES

    listed = set()
    for line in data_module.__doc__.splitlines():
        m = re.match(r"^``([^`]+)``", line)
        if m:
            listed.update(name.strip() for name in m.group(1).split(","))
    d = Data(2, 12)
    for name in listed:
        assert isinstance(getattr(d, name), np.ndarray), name
    assert set(_KERNEL_NAMES) == listed


def test_configurations_that_overflow_raise_instead_of_returning_nan():
    seg = soft_segment()
    with pytest.raises(NonFiniteError, match=r"Segment.mass_matrix: the mass matrix M_xi is not finite at q_e = "
                                             r"\(1e\+300, 0, 0\)"):
        seg.mass_matrix([1e300, 0, 0])
    with pytest.raises(NonFiniteError, match=r"elastic energy"):
        seg.elastic_energy([1e300, 0, 0])
    with pytest.raises(NonFiniteError, match=r"kinetic energy"):
        seg.kinetic_energy(seg.neutral(), [1e200] * 9)
    ch = Chain([seg, seg, seg])
    q = ch.neutral()
    q[6] = 1e300
    for call in (lambda: ch.mass_matrix(q), lambda: ch.potential_energy(q), lambda: ch.elastic_force(q),
                 lambda: ch.forward_dynamics(q, np.zeros(ch.nv), t=0.25)):
        with pytest.raises(NonFiniteError, match=r"is not finite.*segment 2 \(q\[6:9\] = \(1e\+300, 0, 0\)"):
            call()
    with pytest.raises(NonFiniteError, match=r"Chain.forward_dynamics: the acceleration is not finite at t = 0.25 s"):
        ch.forward_dynamics(q, np.zeros(ch.nv), t=0.25)
    assert issubclass(NonFiniteError, QchainError) and issubclass(NonFiniteError, ValueError)


def test_complex_boolean_and_string_states_are_refused_by_name():
    seg = soft_segment()
    with pytest.raises(TypeError, match=r"q_e must be an array of real numbers \(complex numbers are refused, not cut"):
        seg.mass_matrix([0.1, 1 + 2j, 0.0])
    with pytest.raises(TypeError, match=r"q_e must be an array of real numbers \(complex"):
        seg.mass_matrix(np.array([0.1, 1, 0], dtype=complex))
    with pytest.raises(TypeError, match=r"q_e must be an array of real numbers \(booleans are not numbers\)"):
        seg.mass_matrix([0.1, True, 0.0])
    ch = Chain([seg])
    with pytest.raises(TypeError, match=r"q must be an array of real numbers, got a str 'abc'"):
        ch.mass_matrix("abc")
    with pytest.raises(TypeError, match=r"v must be an array of real numbers, got a list \[0, 'x', 0\]"):
        ch.forward_dynamics(ch.neutral(), [0, "x", 0])
    with pytest.raises(TypeError, match=r"p must be an array of real numbers"):
        ch.forward_dynamics(ch.neutral(), np.zeros(3), p=[1e4, 0j, 0])
    with pytest.raises(ValueError, match=r"q must be a rectangular array of real numbers"):
        ch.mass_matrix([[0.1, 0], [0]])
    with pytest.raises(ValueError, match=r"gravity\[2\] must be >= -10000 and <= 10000 m/s\^2, got 1e\+300"):
        Chain([seg], gravity=[0, 0, 1e300])
    with pytest.raises(TypeError, match=r"gravity must be an array of real numbers \(booleans"):
        Chain([seg], gravity=[0, 0, True])


# ---------------------------------------------------------------- damping laws

K_LAW = np.array([[80.0, 1.0, 0.5], [1.0, 0.03, 0.001], [0.5, 0.001, 0.02]])  # N/m, N, N m: SPD, coupled
D_LAW = np.array([[2.0, 0.05, 0.0], [0.05, 0.004, 0.0005], [0.0, 0.0005, 0.003]])  # axial, bending: SPD, coupled

#: the damping laws on one segment in curvature coordinates (the stiffness-proportional one the default's)
DAMPING_LAWS = {
    "stiffness": dict(damping=0.02),
    "matrix": dict(damping_matrix=D_LAW),
    "linear_law": dict(stiffness_matrix=K_LAW, damping=0.01, rest_q_e=[0.2, 1.0, 0.0]),
    "drag_linear": dict(drag_linear=0.5),
    "drag_quadratic": dict(drag_quadratic=5.0),
}


def law_chain(law, base="fixed", n=2, **kw):
    """``n`` segments of ``DAMPING_LAWS[law]`` (the second a little shorter and lighter)."""
    segs = [Segment(**{**SEGMENT_KW, "length": 0.2 - 0.02 * j, "mass": 0.3 - 0.05 * j}, **DAMPING_LAWS[law])
            for j in range(n)]
    return Chain(segs, base=base, **kw)


def drag_reference(ch, q, v):
    """``(tau_drag, power)``: the drag's generalised force ``-sum_k w_k l J_k^T (c_1 + c_2 |v_k|) v_k``
    from the world point Jacobians of :meth:`Chain.point_jacobian` at the segments' nodes
    (independent of the compiled pass), and its power ``-sum_k w_k l (c_1 + c_2 |v_k|) |v_k|^2``."""
    tau, power = np.zeros(ch.nv), 0.0
    for j, s in enumerate(ch.segments):
        l = q[ch.q_slice(j)][0]
        for a, w in zip(s.alpha_nodes, s.alpha_weights):
            J = ch.point_jacobian(q, j, a)
            vp = J @ v
            c = w * l * (s.drag_linear + s.drag_quadratic * np.linalg.norm(vp))
            tau -= c * J.T @ vp
            power -= c * vp @ vp
    return tau, power


def segment_forces(ch, q, v, p):
    """``B p - D v - dU_el/dq`` of each :class:`Segment`'s own Python methods, zero on the base."""
    f = np.zeros(ch.nv)
    for j, s in enumerate(ch.segments):
        qe, ve = q[ch.q_slice(j)], v[ch.v_slice(j)]
        f[ch.v_slice(j)] = s.input_matrix(qe) @ p[3 * j : 3 * j + 3] - s.damping_force(qe, ve) - s.elastic_force(qe)
    return f


@pytest.mark.parametrize("base", ["fixed", "floating"])
@pytest.mark.parametrize("law", list(DAMPING_LAWS))
def test_every_damping_law_stays_compiled_and_matches_the_segments(law, base, rng):
    """A curvature-coordinate chain with any damping law keeps the one-call compiled forward
    dynamics and gives ``M^-1 (B p - D v - dU_el/dq + tau_drag - C v - g)`` of the segments'
    own Python methods and the point Jacobians, to rounding."""
    ch = law_chain(law, base)
    assert ch._fused and ch.kernel_arrays() is not None
    q, v = random_state(ch, rng)
    p = rng.uniform(0, 3e4, ch.nu)
    f = segment_forces(ch, q, v, p)
    tau_drag = drag_reference(ch, q, v)[0]
    assert rel(ch.internal_forces(q, v, p), f) < 1e-13
    assert rel(ch.drag_force(q, v), tau_drag) < 1e-13 if "drag" in law else not ch.drag_force(q, v).any()
    a_ref = np.linalg.solve(ch.mass_matrix(q), f + tau_drag - ch.nonlinear_effects(q, v))
    assert rel(ch.forward_dynamics(q, v, p), a_ref) < 1e-11
    data = ch.create_data()  # the unchecked fast path too
    assert rel(ch.forward_dynamics(q, v, p, data=data, skip_checks=True), a_ref) < 1e-11


@pytest.mark.parametrize("law", list(DAMPING_LAWS))
def test_every_damping_law_dissipates(law, rng):
    """The damping force's power ``-v^T D v`` and the drag's ``v^T tau_drag`` are never positive;
    the drag's equals ``-int (c_1 + c_2 |v|) |v|^2 ds`` of the point velocities."""
    ch = law_chain(law, "floating")
    for _ in range(5):
        q, v = random_state(ch, rng)
        damping_power = v @ (ch.internal_forces(q, v) - ch.internal_forces(q, np.zeros(ch.nv)))
        assert damping_power <= 0.0 and abs(damping_power + v @ ch.dissipation_matrix(q) @ v) < 1e-12
        power = v @ ch.drag_force(q, v)
        assert power <= 0.0 and abs(power - drag_reference(ch, q, v)[1]) <= 1e-13 * max(1.0, abs(power))
        if "drag" in law:
            assert power < 0.0
