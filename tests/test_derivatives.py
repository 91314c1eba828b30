"""Exact derivatives of the dynamics against central differences of the model and against
the model's other exact quantities (mass matrix, Coriolis matrix, elastic and pressure
stiffness)."""

import numpy as np
import pinocchio as pin
import pytest

from helpers import SEGMENT_KW, rel
from qchain import Chain, Segment
from qchain.algorithms.rnea_derivatives import segment_derivatives
from qchain.algorithms.slice_derivatives import LANE_SCRATCH, LANES
from qchain.model.arc import SCRATCH, arc_node, arc_node_derivatives, bend_functions, bend_h
from qchain.model.slices import segment_slices
from test_chain import DAMPING_LAWS, law_chain, make_chain, random_state

TOL = 1e-7  # relative (Frobenius); the bound is 1e-6, differences reach ~1e-9


def central(f, x, step, integrate=None, n=None):
    """Central differences of ``f`` at ``x``, columns along ``integrate(x, e)`` if given."""
    n = len(x) if n is None else n
    cols = []
    for k in range(n):
        e = np.zeros(n)
        e[k] = step
        if integrate is None:
            cols.append((f(x + e) - f(x - e)) / (2 * step))
        else:
            cols.append((f(integrate(x, e)) - f(integrate(x, -e))) / (2 * step))
    return np.stack(cols, axis=-1)


def shaking_base(t):
    """A prescribed base that turns and translates (placement, body twist, acceleration)."""
    w = 2.0
    X = pin.SE3(pin.exp3(np.array([0.3 * np.sin(w * t), 0.1, 0.2])), np.array([0.05 * np.sin(w * t), 0.0, 0.0]))
    V = np.array([0.1 * np.cos(w * t), 0.2, 0.05, 0.3, -0.2, 0.1])
    A = np.array([-0.2 * np.sin(w * t), 0.1, 0.0, 0.1, 0.3, -0.2])
    return X, V, A


CASES = [
    ("fixed", dict(base_placement=pin.SE3(pin.exp3(np.array([0.4, -1.0, 0.3])), np.array([0.1, 0.2, -0.3])))),
    ("floating", {}),
    ("prescribed", dict(base_motion=shaking_base)),
]


def case_chain(coords, base):
    kw = dict(CASES)[base]
    return make_chain(coords, base, **kw)


# ---------------------------------------------------------------- slice kinematics


def _node(alpha, q, qd):
    R, p, S, Sd = np.empty((3, 3)), np.empty(3), np.empty((6, 3)), np.empty((6, 3))
    arc_node(alpha, *q, *qd, R, p, S, Sd)
    return S, Sd @ qd


@pytest.mark.parametrize("q", [[0.2, 3.0, -4.0], [0.2, 0.0, 0.0], [0.21, 15.0, 9.0], [0.2, 1e-9, 0.0]])
@pytest.mark.parametrize("alpha", [0.3, 1.0])
def test_slice_jacobian_derivatives_match_differences(q, alpha, rng):
    """``dS/dq`` and ``d(Sd qdot)/dq`` on both branches of the bending functions (x < 2, x > 2)
    and at the straight pose."""
    q = np.array(q)
    qd = rng.normal(size=3)
    dS, K = np.empty((3, 6, 3)), np.empty((3, 6))
    arc_node_derivatives(alpha, *q, *qd, dS, K)
    fS = central(lambda x: _node(alpha, x, qd)[0], q, 1e-6)
    fK = central(lambda x: _node(alpha, x, qd)[1], q, 1e-6)
    assert rel(np.moveaxis(dS, 0, -1), fS) < TOL
    assert rel(K.T, fK) < TOL


@pytest.mark.parametrize("x", [0.0, 0.5, 1.99, 2.0, 2.01, 7.0])
def test_bend_h_is_the_derivative_of_g_over_x(x):
    h = 1e-5
    g = lambda y: bend_functions(y, derivatives=True)[1][1:]  # noqa: E731 (g1, g2)
    ref = (g(x + h) - g(x - h)) / (2 * h) / x if x > 0 else np.array([1 / 90, 1 / 630])
    assert np.allclose(bend_h(x), ref, rtol=1e-8, atol=0)


# ---------------------------------------------------------------- a segment's force, node by node in lanes


@pytest.mark.parametrize("nodes", [1, 6, LANES + 9])
@pytest.mark.parametrize("q", [[0.15, 20.0, -12.0], [0.2, 3.0, 1.0], [0.2, 0.0, 0.0]])
def test_segment_force_derivatives_match_central_differences(nodes, q, rng):
    """``dQ/dq`` and ``dQ/dxi`` of one segment (:mod:`qchain.algorithms.slice_derivatives`)
    against central differences of its slice pass: bends past the series' range (x up to 3.5
    rad at the tip), the straight pose, and more nodes than a block of lanes holds. The root
    twist's columns come from ``M_xi`` and node sums (the Euler-Poincare identity), not from
    the slices' forces: differences of ``Q`` check that identity."""
    x, wts = np.polynomial.legendre.leggauss(nodes)
    alpha, w = 0.5 * (x + 1), 0.5 * wts
    q = np.array(q)
    xi, xid = rng.normal(size=9), rng.normal(size=9)
    M, Q, QqT, QxT = np.zeros((9, 9)), np.zeros(9), np.zeros((3, 9)), np.zeros((9, 9))
    segment_derivatives(alpha, w, 0.3, 0.02, q, xi, xid, M, Q, QqT, QxT, np.zeros(SCRATCH))

    def force(qq, xx, xxd):
        Mo, Qo = np.zeros((9, 9)), np.zeros(9)
        segment_slices(alpha, w, 0.3, 0.02, qq, xx, xxd, True, Mo, Qo, np.zeros(SCRATCH))
        return Qo, Mo

    assert LANE_SCRATCH + 24 <= SCRATCH  # the chain's pass carves 24 floats before the lanes' blocks
    Q0, M0 = force(q, xi, xid)
    assert rel(Q, Q0) < 1e-14 and rel(M, M0) < 1e-14
    assert rel(QqT.T, central(lambda y: force(y, xi, xid)[0], q, 1e-6)) < TOL
    # quadratic in xi: exact up to rounding at any step
    assert rel(QxT.T, central(lambda y: force(q, y, xid)[0], xi, 1e-2)) < 1e-10


# ---------------------------------------------------------------- inverse dynamics


@pytest.mark.parametrize("coords", ["curvature", "paper"])
@pytest.mark.parametrize("base", [b for b, _ in CASES])
def test_inverse_dynamics_derivatives_match_central_differences(coords, base, rng):
    """Mixed chains (paper coordinates in every other segment, one tip-plate actuated
    segment); a turned fixed base, a floating base with a turned attitude, a shaking
    prescribed base."""
    ch = case_chain(coords, base)
    q, v = random_state(ch, rng)
    a = rng.normal(size=ch.nv)
    t = 0.3
    d = ch.inverse_dynamics_derivatives(q, v, a, t=t)
    assert rel(d.tau, ch.inverse_dynamics(q, v, a, t=t)) < 1e-14
    assert rel(d.dtau_da, ch.mass_matrix(q)) < 1e-14
    f = lambda x: ch.inverse_dynamics(x, v, a, t=t)  # noqa: E731
    assert rel(d.dtau_dq, central(f, q, 1e-6, ch.integrate, ch.nv)) < TOL
    # quadratic in v: central differences are exact up to rounding at any step
    assert rel(d.dtau_dv, central(lambda x: ch.inverse_dynamics(q, x, a, t=t), v, 1e-2)) < 1e-10


def test_derivatives_are_continuous_through_the_straight_pose(rng):
    """Curvature coordinates at kappa = 0 exactly: equal to central differences there, and
    within O(kappa) of a chain bent by kappa = 1e-9 1/m."""
    ch = make_chain("curvature", "floating")
    q, v = random_state(ch, rng)
    for j in range(ch.n):
        q[ch.q_slice(j)][1:] = 0.0
    a = rng.normal(size=ch.nv)
    p = rng.uniform(0, 4e4, ch.nu)
    d0 = ch.forward_dynamics_derivatives(q, v, p)
    f = lambda x: ch.forward_dynamics(x, v, p)  # noqa: E731
    assert rel(d0.da_dq, central(f, q, 1e-6, ch.integrate, ch.nv)) < TOL
    i0 = ch.inverse_dynamics_derivatives(q, v, a)
    assert rel(i0.dtau_dq, central(lambda x: ch.inverse_dynamics(x, v, a), q, 1e-6, ch.integrate, ch.nv)) < TOL
    qb = q.copy()
    for j in range(ch.n):
        qb[ch.q_slice(j)][1:] = 1e-9 * np.array([0.6, 0.8])
    d1 = ch.forward_dynamics_derivatives(qb, v, p)
    i1 = ch.inverse_dynamics_derivatives(qb, v, a)
    for x0, x1 in [(d0.da_dq, d1.da_dq), (d0.da_dv, d1.da_dv), (i0.dtau_dq, i1.dtau_dq), (i0.dtau_dv, i1.dtau_dv)]:
        assert np.all(np.isfinite(x0))
        assert rel(x1, x0) < 1e-7


# ---------------------------------------------------------------- forward dynamics


@pytest.mark.parametrize("coords", ["curvature", "paper"])
@pytest.mark.parametrize("base", [b for b, _ in CASES])
def test_forward_dynamics_derivatives_match_central_differences(coords, base, rng):
    ch = case_chain(coords, base)
    q, v = random_state(ch, rng)
    p = rng.uniform(0, 4e4, ch.nu)
    tau = rng.normal(size=ch.nv)
    t = 0.3
    d = ch.forward_dynamics_derivatives(q, v, p, tau, t=t)
    assert np.array_equal(d.a, ch.forward_dynamics(q, v, p, tau, t=t))
    assert rel(d.da_dq, central(lambda x: ch.forward_dynamics(x, v, p, tau, t=t), q, 1e-6, ch.integrate, ch.nv)) < TOL
    assert rel(d.da_dv, central(lambda x: ch.forward_dynamics(q, x, p, tau, t=t), v, 1e-2)) < 1e-9
    assert rel(d.da_dp, central(lambda x: ch.forward_dynamics(q, v, x, tau, t=t), p, 1e3)) < 1e-9
    assert rel(d.da_dtau, central(lambda x: ch.forward_dynamics(q, v, p, x, t=t), tau, 1.0)) < 1e-9


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_forward_dynamics_derivatives_over_blocks_of_lanes(base, rng):
    """Seven segments of six nodes: 42 nodes, two blocks of lanes, a segment split between
    them; two segments bent past the series' range. Against central differences."""
    ch = Chain([Segment(**{**SEGMENT_KW, "length": 0.2 - 0.01 * j}, damping=0.01) for j in range(7)], base=base)
    assert sum(s.node_count for s in ch.segments) == 42 > LANES
    q, v = random_state(ch, rng)
    for j in (2, 5):
        q[ch.q_slice(j)][1:] = [14.0, -10.0]  # x = 17.2 l > 2 rad near the tip
    p = rng.uniform(0, 4e4, ch.nu)
    d = ch.forward_dynamics_derivatives(q, v, p)
    assert rel(d.da_dq, central(lambda x: ch.forward_dynamics(x, v, p), q, 1e-6, ch.integrate, ch.nv)) < TOL
    assert rel(d.da_dv, central(lambda x: ch.forward_dynamics(q, x, p), v, 1e-2)) < 1e-9


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_forward_and_inverse_derivatives_agree_with_the_model_identities(base, rng):
    """``da_dtau = M^-1``, ``dtau_da = M``, ``da_dp = M^-1 B`` and ``da_dq = -M^-1 (dtau_dq -
    dB p/dq + K_el)``: the internal-force part is the model's own exact ``elastic_stiffness``
    and ``pressure_stiffness`` (curvature coordinates: ``D`` is constant)."""
    ch = make_chain("curvature", base)
    q, v = random_state(ch, rng)
    p = rng.uniform(0, 4e4, ch.nu)
    d = ch.forward_dynamics_derivatives(q, v, p)
    M = ch.mass_matrix(q)
    Minv = np.linalg.inv(M)
    assert rel(d.da_dtau, Minv) < 1e-12
    assert rel(d.da_dp, Minv @ ch.input_matrix(q)) < 1e-12
    i = ch.inverse_dynamics_derivatives(q, v, d.a)
    assert rel(i.dtau_da, M) < 1e-14
    Kf = ch.pressure_stiffness(q, p) - ch.elastic_stiffness(q)
    assert rel(d.da_dq, -Minv @ (i.dtau_dq - Kf)) < 1e-11
    assert rel(d.da_dv, -Minv @ (i.dtau_dv + ch.dissipation_matrix(q))) < 1e-11


def test_locked_coordinates_have_zero_rows_and_columns(rng):
    """A planar chain with an inextensible segment: the free block equals central differences
    along the free coordinates, ``da_dtau`` is the inverse of the free block of M."""
    segs = [Segment(**SEGMENT_KW, extensible=(j != 1), damping=0.01) for j in range(3)]
    ch = Chain(segs, planar=True)
    q = ch.neutral()
    v = np.zeros(ch.nv)
    for j in range(3):
        q[ch.q_slice(j)][1] = rng.uniform(-5, 5)
        v[ch.v_slice(j)][1] = rng.normal()
        if j != 1:
            q[ch.q_slice(j)][0] *= 1.05
            v[ch.v_slice(j)][0] = 0.01 * rng.normal()
    p = rng.uniform(0, 4e4, ch.nu)
    d = ch.forward_dynamics_derivatives(q, v, p)
    free = ch.active
    assert not free.all()
    for x in (d.da_dq, d.da_dv, d.da_dtau):
        assert np.all(x[~free] == 0.0) and np.all(x[:, ~free] == 0.0)
    assert np.all(d.da_dp[~free] == 0.0)
    idx = np.flatnonzero(free)
    E = np.zeros((ch.nv, idx.size))
    E[idx, np.arange(idx.size)] = 1.0
    fq = central(lambda x: ch.forward_dynamics(q + E @ x, v, p), np.zeros(idx.size), 1e-6)
    fv = central(lambda x: ch.forward_dynamics(q, v + E @ x, p), np.zeros(idx.size), 1e-2)
    assert rel(d.da_dq[np.ix_(idx, idx)], fq[idx]) < TOL
    assert rel(d.da_dv[np.ix_(idx, idx)], fv[idx]) < 1e-9
    M = ch.mass_matrix(q)
    assert rel(d.da_dtau[np.ix_(idx, idx)], np.linalg.inv(M[np.ix_(idx, idx)])) < 1e-12


def test_linear_law_segments(rng):
    """The paper's literal ``K_e``, ``D`` (in paper coordinates) next to material-law segments."""
    K = np.diag([50.0, 0.0, 0.02]) + 0.001
    D = np.diag([0.5, 0.0, 0.001]) + 1e-4
    segs = [
        Segment(**SEGMENT_KW, coords="paper", stiffness_matrix=K, damping_matrix=D),
        Segment(**SEGMENT_KW, coords="paper", damping=0.02),
        Segment(**SEGMENT_KW, stiffness_matrix=K, actuation="paper"),
    ]
    ch = Chain(segs)
    q, v = random_state(ch, rng)
    p = rng.uniform(0, 4e4, ch.nu)
    d = ch.forward_dynamics_derivatives(q, v, p)
    assert rel(d.da_dq, central(lambda x: ch.forward_dynamics(x, v, p), q, 1e-6)) < TOL
    assert rel(d.da_dv, central(lambda x: ch.forward_dynamics(q, x, p), v, 1e-2)) < 1e-9


@pytest.mark.parametrize("base", ["fixed", "floating"])
@pytest.mark.parametrize("law", list(DAMPING_LAWS))
def test_every_damping_law_s_derivatives_are_exact(law, base, rng):
    """The compiled derivatives of a chain with each damping law (its matrices in the compiled
    arrays, the drag's tangent passes) against central differences of the forward dynamics,
    and the drag's own derivatives against differences of ``drag_force``."""
    ch = law_chain(law, base)
    q, v = random_state(ch, rng)
    p = rng.uniform(0, 4e4, ch.nu)
    d = ch.forward_dynamics_derivatives(q, v, p)
    assert rel(d.da_dq, central(lambda x: ch.forward_dynamics(x, v, p), q, 1e-6, ch.integrate, ch.nv)) < TOL
    assert rel(d.da_dv, central(lambda x: ch.forward_dynamics(q, x, p), v, 1e-4)) < TOL
    data = ch.create_data()  # the unchecked fast path adds the drag's too
    du = ch.forward_dynamics_derivatives(q, v, p, data=data, skip_checks=True)
    assert rel(du.da_dq, d.da_dq) < 1e-12 and rel(du.da_dv, d.da_dv) < 1e-12
    if "drag" in law:
        dq, dv = ch.drag_force_derivatives(q, v)
        assert rel(dq, central(lambda x: ch.drag_force(x, v), q, 1e-6, ch.integrate, ch.nv)) < TOL
        assert rel(dv, central(lambda x: ch.drag_force(q, x), v, 1e-4)) < TOL
        assert np.linalg.eigvalsh(dv + dv.T).max() < 1e-12 * np.abs(dv).max()  # -d tau/dv is positive semi-definite


def test_quadratic_drag_derivative_at_rest_is_zero_and_continuous(rng):
    """``d(|v| v)/dv`` vanishes at ``v = 0`` and tends to zero there: the exact derivative at rest
    is the limit of the derivatives at vanishing speeds."""
    ch = law_chain("drag_quadratic")
    q = random_state(ch, rng)[0]
    v = rng.normal(size=ch.nv)
    assert not ch.drag_force_derivatives(q, np.zeros(ch.nv))[1].any()
    small = [np.abs(ch.drag_force_derivatives(q, e * v)[1]).max() for e in (1e-2, 1e-4)]
    assert small[1] < 1.1e-2 * small[0]  # linear in the speed


# ---------------------------------------------------------------- mass matrix and pressure


@pytest.mark.parametrize("coords", ["curvature", "paper"])
@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_mass_matrix_derivative(coords, base, rng):
    """Against differences of ``mass_matrix``, and ``dM/dq . v = dM/dt = C + C^T`` with the
    model's own Coriolis matrix (the passivity identity)."""
    ch = case_chain(coords, base)
    q, v = random_state(ch, rng)
    dM = ch.mass_matrix_derivative(q)
    assert rel(dM, central(ch.mass_matrix, q, 1e-6, ch.integrate, ch.nv)) < TOL
    C = ch.coriolis_matrix(q, v)
    assert rel(dM @ v, C + C.T) < 1e-12


@pytest.mark.parametrize("coords", ["curvature", "paper"])
@pytest.mark.parametrize("actuation", ["volume", "paper"])
def test_pressure_stiffness_both_actuation_models(coords, actuation, rng):
    seg = Segment(**SEGMENT_KW, coords=coords, actuation=actuation)
    q = np.array([0.22, 0.7, 6.0]) if coords == "paper" else np.array([0.22, 4.0, -3.0])
    p = rng.uniform(0, 4e4, 3)
    ref = central(lambda x: seg.input_matrix(x) @ p, q, 1e-6)
    assert rel(seg.pressure_stiffness(q, p), ref) < TOL


def test_bad_acceleration_is_refused_where_it_enters():
    ch = make_chain()
    q = ch.neutral()
    v = np.zeros(ch.nv)
    with pytest.raises(ValueError, match=r"a must have shape \(9,\)"):
        ch.inverse_dynamics_derivatives(q, v, np.zeros(4))
    a = np.zeros(ch.nv)
    a[2] = np.nan
    with pytest.raises(ValueError, match=r"a has non-finite entries at indices \[2\]"):
        ch.inverse_dynamics_derivatives(q, v, a)
    with pytest.raises(ValueError, match=r"p must have shape"):
        ch.forward_dynamics_derivatives(q, v, np.zeros(2))


# ---------------------------------------------------------------- workspace and fast path


@pytest.mark.slow
@pytest.mark.parametrize("base", [b for b, _ in CASES])
def test_data_workspace_and_unchecked_fast_path(base, rng):
    """With ``data`` the passes write in it (the result's arrays are its arrays, reused call
    after call); ``skip_checks=True`` gives the checked results bit for bit."""
    ch = Chain([Segment(**SEGMENT_KW, damping=0.01 * j) for j in range(3)], base=base, **dict(CASES)[base])
    d = ch.create_data()
    t = 0.3
    results = []
    for _ in range(2):
        q, v = random_state(ch, rng)
        p = rng.uniform(0, 4e4, ch.nu)
        tau = rng.normal(size=ch.nv)
        ref = ch.forward_dynamics_derivatives(q, v, p, tau, t=t)
        got = ch.forward_dynamics_derivatives(q, v, p, tau, t=t, data=d)
        assert got.da_dq is d.da_dq and got.a is d.a
        for x, y in zip(got, ref):
            assert np.array_equal(x, y)
        fast = ch.forward_dynamics_derivatives(q, v, p, tau, t=t, data=d, skip_checks=True)
        for x, y in zip(fast, ref):
            assert np.array_equal(x, y)
        assert ch.forward_dynamics_derivatives(q, v, p.reshape(ch.n, 3), tau, t=t, data=d, skip_checks=True) is fast
        for x, y in zip(fast, ref):  # p by segment rows: the same call
            assert np.array_equal(x, y)
        a_ref = ch.forward_dynamics(q, v, p, tau, t=t)
        assert np.array_equal(ch.forward_dynamics(q, v, p, tau, t=t, data=d), a_ref)
        assert np.array_equal(ch.forward_dynamics(q, v, p, tau, t=t, data=d, skip_checks=True), a_ref)
        results.append(ref.da_dq.copy())
    assert not np.array_equal(results[0], d.da_dq)  # the second call overwrote the first's
    i_ref = ch.inverse_dynamics_derivatives(q, v, ref.a, t=t)
    i_got = ch.inverse_dynamics_derivatives(q, v, ref.a, t=t, data=d)
    assert i_got.dtau_dq is d.dtau_dq
    for x, y in zip(i_got, i_ref):
        assert np.array_equal(x, y)


def test_fast_path_refuses_what_it_does_not_serve():
    paper = make_chain("paper")
    q = paper.neutral()
    with pytest.raises(ValueError, match="skip_checks=True needs data"):
        paper.forward_dynamics_derivatives(q, np.zeros(paper.nv), data=paper.create_data(), skip_checks=True)
    ch = Chain([Segment(**SEGMENT_KW)])
    with pytest.raises(ValueError, match="skip_checks=True needs data"):
        ch.forward_dynamics(ch.neutral(), np.zeros(ch.nv), skip_checks=True)
    with pytest.raises(ValueError, match="skip_checks=True needs data"):
        ch.forward_dynamics_derivatives(ch.neutral(), np.zeros(ch.nv), skip_checks=True)
