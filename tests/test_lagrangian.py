"""The Lagrangian form (LagrangianChain) against the chain's quasi-Lagrangian model: the
inertia from the kinetic energy, the Christoffel Coriolis matrix and the paper's C_xi against
their identities, forward dynamics and a whole trajectory against the quaternion free-flyer,
energy conservation, and the attitude singularity."""

import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import solve_ivp

from helpers import SEGMENT_KW, bent, rel
from qchain import Chain, DomainError, LagrangianChain, Segment, SingularConfigurationError
from qchain.arm.lagrangian import ATTITUDE_SINGULAR_COS
from qchain.sim.simulation import simulate
from support import CHF, QB, refused
from test_chain import make_chain, random_state

TOL = 1e-8  # identities between exact quantities, relative
TOL_FD = 1e-6  # where the test differentiates numerically
H_FD = 1e-6  # central-difference step

CASES = [("curvature", "floating"), ("paper", "floating"), ("curvature", "fixed"), ("paper", "fixed")]
IDS = [f"{c}-{b}" for c, b in CASES]


def lagrangian_state(ch, rng):
    """A random chain state away from the attitude singularity, in both forms."""
    L = LagrangianChain(ch)
    while True:
        q, v = random_state(ch, rng)
        q_L, qd_L = L.from_chain_state(q, v)
        if not ch.floating or abs(np.cos(q_L[4])) > 0.3:
            return L, q, v, q_L, qd_L


def velocity_product(ch, q, v):
    """The chain's velocity-product force ``C_xi xi`` (nv,)."""
    return ch.nonlinear_effects(q, v) - ch.generalized_gravity(q)


@pytest.fixture(params=CASES, ids=IDS)
def state(request, rng):
    coords, base = request.param
    return lagrangian_state(make_chain(coords, base), rng)


# ---------------------------------------------------------------- kinematics


def test_chain_state_round_trip(state):
    L, q, v, q_L, qd_L = state
    q2, v2 = L.to_chain_state(q_L, qd_L)
    assert np.linalg.norm(L.chain.difference(q, q2)) < 1e-14
    assert rel(v2, v) < 1e-14
    q_L2, qd_L2 = L.from_chain_state(q2, v2)
    assert rel(q_L2, q_L) < 1e-14 and rel(qd_L2, qd_L) < 1e-14


def test_velocity_transform_is_the_base_twist_and_its_rate(rng):
    """``T qd_L`` is the chain velocity of the curve ``q_L + s qd_L`` (differences of the chain
    configurations along its Lie group); ``Tdot`` is the difference of ``T``."""
    L, q, v, q_L, qd_L = lagrangian_state(make_chain("curvature", "floating"), rng)
    ch = L.chain
    qa = L.to_chain_state(q_L - H_FD * qd_L, qd_L)[0]
    qb = L.to_chain_state(q_L + H_FD * qd_L, qd_L)[0]
    xi_fd = ch.difference(qa, qb) / (2 * H_FD)
    T = L.velocity_transform(q_L)
    assert rel(T @ qd_L, xi_fd) < TOL_FD
    assert rel(T @ qd_L, v) < 1e-14
    assert rel(T[:3, :3], pin.rpy.rpyToMatrix(q_L[3:6]).T) < 1e-14
    Td_fd = (L.velocity_transform(q_L + H_FD * qd_L) - L.velocity_transform(q_L - H_FD * qd_L)) / (2 * H_FD)
    assert rel(L.velocity_transform_dot(q_L, qd_L), Td_fd) < TOL_FD


# ---------------------------------------------------------------- inertia and Coriolis


def test_mass_matrix_is_the_kinetic_energy(state):
    """``H`` rebuilt entry by entry from ``chain.kinetic_energy`` of the mapped velocities
    (polarisation), an independent pass (root twists and segment masses)."""
    L, q, v, q_L, qd_L = state
    ch = L.chain
    T = L.velocity_transform(q_L)
    K = lambda qd: 2.0 * ch.kinetic_energy(q, T @ qd)  # noqa: E731  qd^T H qd
    E = np.eye(L.nv)
    diag = np.array([K(e) for e in E])
    H_ref = np.empty((L.nv, L.nv))
    for i in range(L.nv):
        for j in range(L.nv):
            H_ref[i, j] = diag[i] if i == j else 0.5 * (K(E[i] + E[j]) - diag[i] - diag[j])
    H = L.mass_matrix(q_L)
    assert rel(H, H_ref) < TOL
    assert rel(H, T.T @ ch.mass_matrix(q) @ T) < 1e-14
    assert np.allclose(H, H.T, rtol=0, atol=1e-15 * np.abs(H).max())
    assert np.linalg.eigvalsh(H).min() > 0
    assert abs(0.5 * qd_L @ H @ qd_L - ch.kinetic_energy(q, v)) < TOL * ch.kinetic_energy(q, v)


def test_mass_matrix_derivative_matches_differences(state):
    L, q, v, q_L, qd_L = state
    fd = np.stack([(L.mass_matrix(q_L + H_FD * e) - L.mass_matrix(q_L - H_FD * e)) / (2 * H_FD)
                   for e in np.eye(L.nv)], axis=-1)
    assert rel(L.mass_matrix_derivative(q_L), fd) < TOL_FD


def test_dH_dt_minus_2C_is_skew(state):
    L, q, v, q_L, qd_L = state
    C = L.coriolis_matrix(q_L, qd_L)
    Hdot = (L.mass_matrix(q_L + H_FD * qd_L) - L.mass_matrix(q_L - H_FD * qd_L)) / (2 * H_FD)
    N = Hdot - 2 * C
    assert np.abs(N + N.T).max() < TOL_FD * np.abs(Hdot).max()
    assert rel(C + C.T, Hdot) < TOL_FD


def test_coriolis_product_is_the_chain_velocity_product(state):
    """``C qd_L = T^T (M Tdot qd_L + C_xi xi)``, ``C_xi xi`` the chain's ``nle - g`` and its
    ``coriolis_matrix(q, v) v``."""
    L, q, v, q_L, qd_L = state
    ch = L.chain
    T = L.velocity_transform(q_L)
    Td = L.velocity_transform_dot(q_L, qd_L)
    h_xi = velocity_product(ch, q, v)
    assert rel(ch.coriolis_matrix(q, v) @ v, h_xi) < TOL
    Cqd = L.coriolis_matrix(q_L, qd_L) @ qd_L
    assert rel(Cqd, T.T @ (ch.mass_matrix(q) @ Td @ qd_L + h_xi)) < TOL
    assert rel(L._christoffel_product(L.mass_matrix_derivative(q_L), qd_L), Cqd) < 1e-12


def test_quasi_coriolis_is_passive_and_gives_the_velocity_product(state):
    """The paper's ``C_xi = T^-T C T^-1 - M Tdot T^-1``: ``C_xi + C_xi^T = dM/dt`` (along the
    motion, by differences on the Lie group and exactly) and ``C_xi xi = nle - g``."""
    L, q, v, q_L, qd_L = state
    ch = L.chain
    Cxi = L.quasi_coriolis_matrix(q_L, qd_L)
    Mdot_fd = (ch.mass_matrix(ch.integrate(q, v, H_FD)) - ch.mass_matrix(ch.integrate(q, v, -H_FD))) / (2 * H_FD)
    assert rel(Cxi + Cxi.T, Mdot_fd) < TOL_FD
    assert rel(Cxi + Cxi.T, ch.mass_matrix_derivative(q) @ v) < TOL
    assert rel(Cxi @ v, velocity_product(ch, q, v)) < TOL


def test_gravity_is_the_gradient_of_the_potential(state):
    """``g + dU_el/dq = dU/dq_L`` by differences of ``chain.potential_energy``."""
    L, q, v, q_L, qd_L = state
    ch = L.chain
    U = lambda x: ch.potential_energy(L.to_chain_state(x, qd_L)[0])  # noqa: E731
    grad = np.array([(U(q_L + H_FD * e) - U(q_L - H_FD * e)) / (2 * H_FD) for e in np.eye(L.nv)])
    g = L.generalized_gravity(q_L)
    assert rel(g + ch.elastic_force(q), grad) < TOL_FD
    assert rel(g, L.velocity_transform(q_L).T @ ch.generalized_gravity(q)) < 1e-14


# ---------------------------------------------------------------- dynamics


def test_forward_dynamics_is_the_chain_s(state, rng):
    """``xidot = T qdd_L + Tdot qd_L`` equals the chain's forward dynamics with the same
    pressures and the chain force ``tau_xi``, entered as ``tau = T^T tau_xi``."""
    L, q, v, q_L, qd_L = state
    ch = L.chain
    p = rng.uniform(0.0, 3e4, ch.nu)
    tau_xi = rng.normal(size=ch.nv)
    tau = L.lagrangian_force(q_L, tau_xi)
    assert abs(qd_L @ tau - v @ tau_xi) < 1e-12 * np.abs(v).max() * np.abs(tau_xi).max()  # power
    qdd = L.forward_dynamics(q_L, qd_L, p, tau)
    xid = L.velocity_transform(q_L) @ qdd + L.velocity_transform_dot(q_L, qd_L) @ qd_L
    assert rel(xid, ch.forward_dynamics(q, v, p, tau_xi)) < TOL
    f = L.internal_forces(q_L, qd_L, p)
    assert rel(f, ch.internal_forces(q, v, p)) < 1e-14 and not f[: 6 if ch.floating else 0].any()


def test_locked_coordinates_have_zero_acceleration(rng):
    """A planar floating chain with an inextensible segment: locked rows of ``qdd_L`` are zero,
    the rest is the chain's motion."""
    segs = [Segment(**SEGMENT_KW, extensible=False), Segment(**SEGMENT_KW)]
    ch = Chain(segs, base="floating", planar=True)
    L = LagrangianChain(ch)
    q_L = np.r_[0.1, 0.2, -0.1, 0.3, -0.4, 0.5, 0.2, 3.0, 0.0, 0.21, -4.0, 0.0]
    qd_L = np.r_[0.1, -0.2, 0.3, 0.5, 0.2, -0.4, 0.0, 2.0, 0.0, 0.03, 1.0, 0.0]
    qdd = L.forward_dynamics(q_L, qd_L)
    assert not qdd[~ch.active].any()
    q, v = L.to_chain_state(q_L, qd_L)
    xid = L.velocity_transform(q_L) @ qdd + L.velocity_transform_dot(q_L, qd_L) @ qd_L
    assert rel(xid, ch.forward_dynamics(q, v)) < TOL
    bad = q_L.copy()
    bad[6] = 0.21
    with pytest.raises(ValueError, match=r"q_L\[6\] is locked at 0.2, got 0.21"):
        L.forward_dynamics(bad, qd_L)
    bad = qd_L.copy()
    bad[8] = 0.5
    with pytest.raises(ValueError, match=r"qd_L\[8\] is locked and must be 0, got 0.5"):
        L.forward_dynamics(q_L, bad)


T_END = 0.2  # s
T_EVAL = np.linspace(0.0, T_END, 5)


@pytest.fixture(scope="module")
def undamped_run():
    """A two-segment floating arm without damping or pressure, falling and tumbling, integrated
    in Lagrangian form (DOP853 on ``(q_L, qd_L)``) and as the quaternion free-flyer
    (``qchain.sim.simulation``, DOP853 on the Lie group), both at rtol = atol = 1e-12."""
    segs = [Segment(**{**SEGMENT_KW, "length": 0.2 - 0.03 * j, "mass": 0.3 - 0.1 * j}) for j in range(2)]
    ch = Chain(segs, base="floating")
    assert all(s.damping == 0.0 and s.damping_matrix is None for s in segs)
    L = LagrangianChain(ch)
    q_L0 = np.r_[0.1, -0.2, 0.3, 0.3, 0.4, -0.5, bent("curvature", 0.8, 0.7, 0.21), bent("curvature", -0.5, 2.0, 0.18)]
    qd_L0 = np.r_[0.2, -0.1, 0.3, 1.5, -1.0, 2.0, 0.02, 1.0, -2.0, -0.01, 3.0, 1.0]
    nv = L.nv
    sol = solve_ivp(lambda t, y: np.r_[y[nv:], L.forward_dynamics(y[:nv], y[nv:])], (0.0, T_END),
                    np.r_[q_L0, qd_L0], method="DOP853", rtol=1e-12, atol=1e-12, t_eval=T_EVAL)
    assert sol.success, sol.message
    q0, v0 = L.to_chain_state(q_L0, qd_L0)
    ref = simulate(ch, q0, v0, (0.0, T_END), method="DOP853", rtol=1e-12, atol=1e-12, t_eval=T_EVAL)
    assert ref.success, ref.message
    return L, sol, ref


@pytest.mark.slow
def test_lagrangian_trajectory_equals_the_free_flyer_s(undamped_run):
    L, sol, ref = undamped_run
    ch = L.chain
    assert np.abs(np.cos(sol.y[4])).min() > 0.3  # pitch stays away from pi/2
    assert np.ptp(sol.y[3:6], axis=1).min() > 0.1  # every attitude angle moves
    for k in range(len(T_EVAL)):
        q, v = L.to_chain_state(sol.y[: L.nv, k], sol.y[L.nv :, k])
        assert np.linalg.norm(ch.difference(ref.q[k], q)) < 1e-9  # m, rad
        assert np.linalg.norm(v - ref.v[k]) < 1e-9 * np.linalg.norm(ref.v[k])


def test_lagrangian_energy_is_conserved_without_damping_and_pressure(undamped_run):
    L, sol, ref = undamped_run
    ch = L.chain
    E = []
    for y in sol.y.T:
        q_L, qd_L = y[: L.nv], y[L.nv :]
        E.append(0.5 * qd_L @ L.mass_matrix(q_L) @ qd_L + ch.potential_energy(L.to_chain_state(q_L, qd_L)[0]))
    E = np.array(E)
    kinetic = 0.5 * sol.y[L.nv :, 0] @ L.mass_matrix(sol.y[: L.nv, 0]) @ sol.y[L.nv :, 0]
    assert np.abs(E - E[0]).max() < 1e-9 * kinetic
    assert rel(E - E[0] + ref.total_energy[0], ref.total_energy) < 1e-9


# ---------------------------------------------------------------- singularity and inputs


def test_attitude_singularity_raises_naming_the_cure():
    ch = make_chain("curvature", "floating", n=2)
    L = LagrangianChain(ch)
    q_L = np.r_[0.0, 0.0, 0.0, 0.2, np.pi / 2 - 1e-8, -0.3, ch.neutral()[7:]]
    qd_L = np.zeros(L.nv)
    msg = (r"q_L\[4\]: pitch = 1.57079632 rad gives \|cos\(pitch\)\| = 1\.000e-08, below ATTITUDE_SINGULAR_COS = "
           r"1e-06: the roll-pitch-yaw attitude is singular at \|pitch\| = pi/2 .*Chain\(base='floating'\)")
    for call in (lambda: L.mass_matrix(q_L), lambda: L.forward_dynamics(q_L, qd_L),
                 lambda: L.coriolis_matrix(q_L, qd_L), lambda: L.quasi_coriolis_matrix(q_L, qd_L),
                 lambda: L.generalized_gravity(q_L)):
        with pytest.raises(SingularConfigurationError, match=msg):
            call()
    assert isinstance(SingularConfigurationError("x"), ValueError)
    # the forward maps are defined there
    q, v = L.to_chain_state(q_L, qd_L)
    assert abs(np.linalg.det(L.velocity_transform(q_L)[3:6, 3:6])) < 2e-8
    with pytest.raises(SingularConfigurationError, match=r"q\[3:7\]: pitch = .*Chain\(base='floating'\)"):
        L.from_chain_state(q, v)
    # the bound: just outside it the model is evaluated
    q_L[4] = np.pi / 2 - 10 * ATTITUDE_SINGULAR_COS
    assert np.all(np.isfinite(L.forward_dynamics(q_L, qd_L)))
    q_L[4] = -np.pi / 2 + 0.5 * ATTITUDE_SINGULAR_COS
    with pytest.raises(SingularConfigurationError):
        L.mass_matrix(q_L)


def test_inputs_are_checked_where_they_enter():
    ch = make_chain("curvature", "floating", n=2)
    L = LagrangianChain(ch)
    q_L, qd_L = L.from_chain_state(ch.neutral(), np.zeros(ch.nv))
    with pytest.raises(ValueError, match=r"q_L must have shape \(12,\), got shape \(13,\)"):
        L.mass_matrix(np.zeros(13))
    bad = qd_L.copy()
    bad[2] = np.nan
    with pytest.raises(ValueError, match=r"qd_L has non-finite entries at indices \[2\]"):
        L.forward_dynamics(q_L, bad)
    with pytest.raises(ValueError, match=r"tau must have shape \(12,\), got shape \(3,\)"):
        L.forward_dynamics(q_L, qd_L, tau=np.zeros(3))
    with pytest.raises(ValueError, match=r"p must have shape \(6,\), got shape \(2,\)"):
        L.forward_dynamics(q_L, qd_L, p=np.zeros(2))
    bad = q_L.copy()
    bad[9] = -0.1
    with pytest.raises(DomainError, match=r"segment 1 \(q_L\[9:12\]\): length l = -0.1 m must be > 0"):
        L.forward_dynamics(bad, qd_L)
    with pytest.raises(ValueError, match=r"q\[3:7\] quaternion \(qx, qy, qz, qw\) has norm 2"):
        L.from_chain_state(np.r_[0, 0, 0, 0, 0, 0, 2.0, ch.neutral()[7:]], np.zeros(ch.nv))
    with pytest.raises(TypeError, match="chain must be a qchain.Chain, got str"):
        LagrangianChain("arm")
    with pytest.raises(ValueError, match=r"attitude must be one of \('rpy',\), got 'euler'"):
        LagrangianChain(ch, attitude="euler")
    moving = Chain(ch.segments, base="prescribed", base_motion=lambda t: (pin.SE3.Identity(), np.zeros(6), np.zeros(6)))
    with pytest.raises(ValueError, match="base='floating' or 'fixed', got base='prescribed'"):
        LagrangianChain(moving)


# --------------------------------------------------------------------------------------
# Bad input (issue 18): refused where it enters, naming the argument, the value and the bound;
# never a foreign traceback, a hang, a crash, a silent NaN or lost data.

def test_the_lagrangian_form_and_engine_entry_points_name_bad_arguments():
    from qchain import compile_all
    from qchain.sim.engine import packing

    L = LagrangianChain(CHF)
    refused(lambda: L.forward_dynamics(np.r_[0.1, 0.2, 0.3, 0.1, 0.2, 0.3, QB], [True] * 9), "qd_L")
    refused(lambda: compile_all(["bogus"]), "methods")
    refused(lambda: compile_all("rk4"), "methods")
    refused(lambda: packing.pack("chain", None, None), "chain")
