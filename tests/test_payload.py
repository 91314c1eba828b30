"""A rigid tip payload (``Chain(payload=pinocchio.Inertia(...))``) against computations that do
not use the passes' payload code: the payload's kinetic energy from the tip twist
(``Chain.tip_velocity``), its gravity from the tip placement and Jacobian, Lagrange's equations
by central differences, the derivative passes against central differences, energy
conservation in a simulation, and the planar kernel against the spatial one."""

import numpy as np
import pinocchio as pin
import pytest

import qchain
from qchain import Chain, Segment
from qchain.algorithms import planar as planar_alg

from support import SEGMENT

S = Segment(**SEGMENT)
I_C = np.array([[2e-4, 1e-5, 2e-5], [1e-5, 3e-4, -1e-5], [2e-5, -1e-5, 1.5e-4]])  # kg m^2, about the COM
#: a payload heavier than a segment, off the axis, its principal axes not the tip frame's
PAYLOAD = pin.Inertia(0.08, np.array([0.01, -0.005, 0.02]), I_C)
#: symmetric about the x-z plane (a planar chain's)
PLANAR_PAYLOAD = pin.Inertia(0.08, np.array([0.01, 0.0, 0.02]),
                             np.array([[2e-4, 0.0, 2e-5], [0.0, 3e-4, 0.0], [2e-5, 0.0, 1.5e-4]]))


def arms(base="fixed", n=3, payload=PAYLOAD, **kw):
    """The same arm with and without the payload."""
    return (Chain([S] * n, base=base, payload=payload, **kw), Chain([S] * n, base=base, **kw))


def state(ch, seed=0):
    rng = np.random.default_rng(seed)
    q = ch.neutral()
    q[ch._qoff:] += rng.normal(size=3 * ch.n) * np.tile([0.005, 3.0, 3.0], ch.n)
    if ch.floating:
        q[:3] = rng.normal(size=3) * 0.1
        quat = rng.normal(size=4)
        q[3:7] = quat / np.linalg.norm(quat)
    if ch.planar:
        q[ch._qoff + 2::3] = 0.0
    v = rng.normal(size=ch.nv)
    v[~ch.active] = 0.0
    return q, v


def payload_kinetic_energy(ch, q, v):
    """``1/2 V^T I_p V`` with the tip twist ``V`` (tip frame) of ``Chain.tip_velocity``."""
    V = ch.tip_velocity(q, v, "local")
    return 0.5 * V @ PAYLOAD.matrix() @ V


def payload_potential(ch, q, payload=PAYLOAD):
    """``-m g . c_W``, the payload's centre of mass in the world from the tip placement."""
    return -payload.mass * ch.tip_placement(q).act(payload.lever) @ ch.gravity


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_mass_matrix_is_the_hessian_of_the_kinetic_energy(base):
    """crba with a payload = crba without + the Hessian in v of the payload's kinetic energy
    from the tip twist (a quadratic form: its Hessian by polarisation is exact)."""
    ch, ch0 = arms(base)
    q, _ = state(ch)
    E = lambda v: payload_kinetic_energy(ch, q, v)
    nv = ch.nv
    H = np.array([[E(ei + ej) - E(ei) - E(ej) for ej in np.eye(nv)] for ei in np.eye(nv)])
    M_p = ch.mass_matrix(q) - ch0.mass_matrix(q)
    assert np.abs(H).max() > 1e-3  # the payload matters
    np.testing.assert_allclose(M_p, H, rtol=0, atol=1e-12 * np.abs(H).max())
    v = np.random.default_rng(3).normal(size=nv)
    np.testing.assert_allclose(ch.kinetic_energy(q, v), ch0.kinetic_energy(q, v) + E(v), rtol=1e-13)


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_statics_of_a_straight_cantilever(base):
    """At rest, inverse dynamics = the arm's own gravity - J_tip^T (the payload's gravity
    wrench at the tip origin, tip frame); straight and bent (a floating base: turned, its
    rows the base wrench)."""
    ch, ch0 = arms(base)
    q_straight = ch.neutral()
    if ch.floating:
        q_straight[3:7] = state(ch, 1)[0][3:7]
    for q in (q_straight, state(ch, 1)[0]):
        X = ch.tip_placement(q)
        f = PAYLOAD.mass * X.rotation.T @ ch.gravity  # tip frame
        W = np.concatenate([f, np.cross(PAYLOAD.lever, f)])
        J = ch.tip_jacobian(q, "local")
        z = np.zeros(ch.nv)
        want = ch0.inverse_dynamics(q, z, z) - J.T @ W
        np.testing.assert_allclose(ch.inverse_dynamics(q, z, z), want, rtol=0, atol=1e-13 * np.abs(want).max())
        # and the gradient of the potential energy (gravity + elastic) at rest
        Ue = ch.potential_energy(q) - ch0.potential_energy(q)
        np.testing.assert_allclose(Ue, payload_potential(ch, q), rtol=1e-13)


def test_lagrange_equations_by_central_differences():
    """nle(payload) - nle(no payload) = the payload's Lagrangian terms, with its mass matrix
    ``M_p`` and potential ``U_p`` differentiated numerically:
    ``sum_jk (dM_p,ij/dq_k - 1/2 dM_p,jk/dq_i) v_j v_k + dU_p/dq_i`` (fixed base: q is flat)."""
    ch, ch0 = arms("fixed")
    q, v = state(ch, 2)
    h = 1e-6
    Mp = lambda q: ch.mass_matrix(q) - ch0.mass_matrix(q)
    dM = np.empty((ch.nv,) * 3)  # dM[k] = dM_p/dq_k
    dU = np.empty(ch.nv)
    for k in range(ch.nv):
        e = np.zeros(ch.nv)
        e[k] = h
        dM[k] = (Mp(q + e) - Mp(q - e)) / (2 * h)
        dU[k] = (payload_potential(ch, q + e) - payload_potential(ch, q - e)) / (2 * h)
    want = np.einsum("kij,j,k->i", dM, v, v) - 0.5 * np.einsum("ijk,j,k->i", dM, v, v) + dU
    got = ch.nonlinear_effects(q, v) - ch0.nonlinear_effects(q, v)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-8 * np.abs(want).max())  # measured 4e-11


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_aba_solves_the_crba_system(base):
    ch, _ = arms(base)
    q, v = state(ch, 4)
    tau = np.random.default_rng(5).normal(size=ch.nv)
    a = ch.forward_dynamics(q, v, tau=tau)
    tau_total = tau + ch.internal_forces(q, v)
    want = np.linalg.solve(ch.mass_matrix(q), tau_total - ch.nonlinear_effects(q, v))
    np.testing.assert_allclose(a, want, rtol=1e-10, atol=1e-10 * np.abs(want).max())
    # and inverse dynamics undoes it
    np.testing.assert_allclose(ch.inverse_dynamics(q, v, a), tau_total, rtol=0, atol=1e-9 * np.abs(tau_total).max())


def _fd(f, x, step, h):
    cols = []
    for k in range(step.shape[0] if step is not None else x.shape[0]):
        cols.append((f(k, h) - f(k, -h)) / (2 * h))
    return np.array(cols).T


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_rnea_derivatives_against_central_differences(base):
    ch, _ = arms(base)
    q, v = state(ch, 6)
    a = np.random.default_rng(7).normal(size=ch.nv)
    d = ch.inverse_dynamics_derivatives(q, v, a)
    E = np.eye(ch.nv)
    h = 1e-6
    dq = _fd(lambda k, s: ch.inverse_dynamics(ch.integrate(q, s * E[k]), v, a), q, E, h)
    dv = _fd(lambda k, s: ch.inverse_dynamics(q, v + s * E[k], a), v, E, h)
    np.testing.assert_allclose(d.tau, ch.inverse_dynamics(q, v, a), rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(d.dtau_dq, dq, rtol=0, atol=5e-8 * np.abs(dq).max())
    np.testing.assert_allclose(d.dtau_dv, dv, rtol=0, atol=5e-8 * np.abs(dv).max())
    np.testing.assert_allclose(d.dtau_da, ch.mass_matrix(q), rtol=0, atol=1e-13 * np.abs(d.dtau_da).max())


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_aba_derivatives_against_central_differences(base):
    # undamped and fast: the payload's velocity terms are not hidden by the material damping
    ch = Chain([Segment(**dict(SEGMENT, damping=0.0))] * 3, base=base, payload=PAYLOAD)
    q, v = state(ch, 8)
    v *= 3.0
    p = np.random.default_rng(9).uniform(0, 2e4, size=ch.nu)
    d = ch.forward_dynamics_derivatives(q, v, p)
    E = np.eye(ch.nv)
    # steps where rounding and truncation balance (measured: 1e-10 to 4e-9 relative error)
    dq = _fd(lambda k, s: ch.forward_dynamics(ch.integrate(q, s * E[k]), v, p), q, E, 1e-6)
    dv = _fd(lambda k, s: ch.forward_dynamics(q, v + s * E[k], p), v, E, 1e-5)
    np.testing.assert_allclose(d.a, ch.forward_dynamics(q, v, p), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(d.da_dq, dq, rtol=0, atol=5e-8 * np.abs(dq).max())
    np.testing.assert_allclose(d.da_dv, dv, rtol=0, atol=5e-8 * np.abs(dv).max())


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_coriolis_matrix_with_a_payload(base):
    """``C v = nle - g`` and ``C + C^T = dM/dt`` (``dM/dt`` from the exact ``mass_matrix_derivative``)."""
    ch, ch0 = arms(base)
    q, v = state(ch, 14)
    C = ch.coriolis_matrix(q, v)
    want = ch.nonlinear_effects(q, v) - ch.generalized_gravity(q)
    assert np.abs(want - (ch0.nonlinear_effects(q, v) - ch0.generalized_gravity(q))).max() > 1e-3 * np.abs(want).max()
    np.testing.assert_allclose(C @ v, want, rtol=0, atol=1e-12 * np.abs(want).max())
    Mdot = ch.mass_matrix_derivative(q) @ v
    np.testing.assert_allclose(C + C.T, Mdot, rtol=0, atol=1e-12 * np.abs(Mdot).max())


def test_momentum_is_the_mass_weighted_velocity_of_the_centres_of_mass():
    """Linear momentum = d/dt of (segment masses x their centres of mass + the payload's
    mass x its centre of mass), by central differences along ``integrate``."""
    ch, _ = arms("floating")
    q, v = state(ch, 10)
    h = 1e-6

    def weighted_com(q):
        return ch._mass @ ch.centers_of_mass(q) + PAYLOAD.mass * ch.tip_placement(q).act(PAYLOAD.lever)

    want = (weighted_com(ch.integrate(q, h * v)) - weighted_com(ch.integrate(q, -h * v))) / (2 * h)
    np.testing.assert_allclose(ch.momentum(q, v)[:3], want, rtol=1e-7)


def test_planar_kernel_with_a_planar_payload():
    """planar_aba (what a planar chain on a fixed base uses) and planar_rnea equal the
    spatial passes with the same in-plane payload."""
    ch, _ = arms("fixed", payload=PLANAR_PAYLOAD, planar=True)
    assert ch._planar_kernel
    q, v = state(ch, 11)
    tau = np.random.default_rng(12).normal(size=ch.nv)
    tau[~ch.active] = 0.0
    a = ch.forward_dynamics(q, v, tau=tau)
    arr = tuple(ch.kernel_arrays())
    n = ch.n
    q_c, v_c = q.reshape(n, 3), v.reshape(n, 3)
    f = (tau + ch.internal_forces(q, v)).reshape(n, 3)
    A0 = ch._A0(ch._state(q, v))
    qdd = np.empty((n, 3))
    ws = qchain.algorithms.recursive.aba_workspace(n, ch.nv)
    assert qchain.algorithms.recursive.aba(arr, q_c, v_c, f, np.zeros(6), A0, False, np.zeros(6), qdd, np.empty(6),
                                           tuple(ws), ws.scratch)
    np.testing.assert_allclose(a, qdd.ravel(), rtol=0, atol=1e-11 * np.abs(qdd).max())
    pw = planar_alg.planar_workspace(n)
    tau_p, F0 = np.empty((n, 3)), np.empty(6)
    planar_alg.planar_rnea(arr, q_c, v_c, qdd, A0, tau_p, F0, tuple(pw), pw.pscratch)
    tau_s = ch.inverse_dynamics(q, v, qdd.ravel()).reshape(n, 3)
    np.testing.assert_allclose(tau_p[:, :2], tau_s[:, :2], rtol=0, atol=1e-11 * np.abs(tau_s).max())


def test_planar_kernel_on_a_moving_base():
    """planar_aba_moving (a planar chain on a prescribed base moving in its x-z plane, the
    engine's planar path) equals recursive.aba with the payload, base twist in the plane."""
    ch, _ = arms("fixed", payload=PLANAR_PAYLOAD, planar=True)
    q, v = state(ch, 15)
    n = ch.n
    arr = tuple(ch.kernel_arrays())
    q_c, v_c = q.reshape(n, 3), v.reshape(n, 3)
    f = ch.internal_forces(q, v).reshape(n, 3)
    V0 = np.array([0.3, 0.0, -0.2, 0.0, 1.5, 0.0])
    A0 = np.array([0.5, 0.0, 9.81, 0.0, -2.0, 0.0])
    qa, qp = np.empty((n, 3)), np.empty((n, 3))
    ws = qchain.algorithms.recursive.aba_workspace(n, ch.nv)
    assert qchain.algorithms.recursive.aba(arr, q_c, v_c, f, V0, A0, False, np.zeros(6), qa, np.empty(6), tuple(ws),
                                           ws.scratch)
    pw = planar_alg.planar_workspace(n)
    assert planar_alg.planar_aba_moving(arr, q_c, v_c, f, V0, A0, qp, tuple(pw), pw.pscratch)
    np.testing.assert_allclose(qp[:, :2], qa[:, :2], rtol=0, atol=1e-11 * np.abs(qa).max())


def test_planar_and_spatial_engines_agree_with_a_payload():
    """A planar chain (the engine's planar kernel) and the same chain unconstrained (the
    spatial kernel), started in the plane with a plane-symmetric payload, follow the same
    trajectory (the symmetry keeps the free chain in the plane)."""
    seg = Segment(**SEGMENT)
    chp = Chain([seg] * 2, planar=True, payload=PLANAR_PAYLOAD)
    chs = Chain([seg] * 2, payload=PLANAR_PAYLOAD)
    q0 = chp.neutral()
    q0[1::3] = [5.0, -4.0]
    v0 = np.zeros(chp.nv)
    kw = dict(method="dopri5", rtol=1e-10, atol=1e-12)
    rp = qchain.simulate(chp, q0, v0, (0.0, 0.2), **kw)
    rs = qchain.simulate(chs, q0, v0, (0.0, 0.2), **kw)
    assert np.abs(rp.q[-1] - q0).max() > 1.0  # it moves
    np.testing.assert_allclose(rp.q[-1], rs.q[-1], rtol=0, atol=1e-7)
    np.testing.assert_allclose(rs.q[:, 2::3], 0.0, atol=1e-12)


def test_no_payload_is_no_change():
    """``payload=None`` and a zero ``pinocchio.Inertia`` give the same results, bit for bit."""
    ch0 = Chain([S] * 3, base="floating")
    chz = Chain([S] * 3, base="floating", payload=pin.Inertia.Zero())
    assert ch0.payload is None and chz.payload is None
    q, v = state(ch0, 13)
    assert np.array_equal(ch0.forward_dynamics(q, v), chz.forward_dynamics(q, v))
    assert np.array_equal(ch0.mass_matrix(q), chz.mass_matrix(q))
    assert np.array_equal(ch0.inverse_dynamics(q, v, v), chz.inverse_dynamics(q, v, v))


def test_payload_property_and_checks():
    ch, _ = arms("fixed")
    P = ch.payload
    assert isinstance(P, pin.Inertia)
    np.testing.assert_array_equal(P.matrix(), PAYLOAD.matrix())
    with pytest.raises(AttributeError):
        ch.payload = None
    with pytest.raises(TypeError, match="payload must be a pinocchio.Inertia"):
        Chain([S], payload=0.1)
    with pytest.raises(ValueError, match="payload.mass"):
        Chain([S], payload=pin.Inertia(-1.0, np.zeros(3), np.eye(3) * 1e-4))
    with pytest.raises(ValueError, match="payload.mass"):
        Chain([S], payload=pin.Inertia(np.nan, np.zeros(3), np.eye(3) * 1e-4))
    with pytest.raises(ValueError, match=r"payload.lever\[1\]"):
        Chain([S], payload=pin.Inertia(1.0, np.array([0.0, np.inf, 0.0]), np.eye(3) * 1e-4))
    # (Pinocchio's constructor refuses a negative diagonal, not an indefinite matrix)
    with pytest.raises(ValueError, match="positive semi-definite"):
        Chain([S], payload=pin.Inertia(1.0, np.zeros(3), np.array([[1, 2, 0], [2, 1, 0], [0, 0, 1]]) * 1e-4))
    bad = pin.Inertia(1.0, np.zeros(3), np.eye(3) * 1e-4)
    bad.inertia = np.diag([1e-4, 1e-4, -1e-4])  # its attribute is not checked
    with pytest.raises(ValueError, match="positive semi-definite"):
        Chain([S], payload=bad)
    with pytest.raises(ValueError, match="payload.mass is 0"):
        Chain([S], payload=pin.Inertia(0.0, np.zeros(3), np.eye(3) * 1e-4))
    with pytest.raises(ValueError, match="planar=True needs a payload symmetric"):
        Chain([S], planar=True, payload=PAYLOAD)


def test_energy_is_conserved_with_a_payload():
    """An undamped, unforced arm with a payload, released bent under gravity: kinetic +
    gravity + elastic energy stays constant over the run (dopri5, rtol 1e-10)."""
    seg = Segment(**dict(SEGMENT, damping=0.0))
    ch = Chain([seg] * 2, payload=pin.Inertia(0.02, np.array([0.005, -0.003, 0.01]), I_C * 0.1))
    q0 = ch.neutral()
    q0[1::3] = [4.0, -3.0]
    q0[2::3] = [2.0, 1.0]
    v0 = np.zeros(ch.nv)
    res = qchain.simulate(ch, q0, v0, (0.0, 0.3), method="dopri5", rtol=1e-10, atol=1e-12)
    E = np.array([ch.kinetic_energy(q, v) + ch.potential_energy(q) for q, v in zip(res.q, res.v)])
    K = max(ch.kinetic_energy(q, v) for q, v in zip(res.q, res.v))
    assert K > 1e-3  # it moves
    assert np.abs(E - E[0]).max() < 1e-9 * K  # measured 3e-11


def test_a_pickled_chain_keeps_its_payload():
    """Batches send the chain to worker processes pickled."""
    import pickle

    ch, _ = arms("floating")
    copy = pickle.loads(pickle.dumps(ch))
    np.testing.assert_array_equal(copy.payload.matrix(), PAYLOAD.matrix())
    q, v = state(ch, 16)
    assert np.array_equal(copy.forward_dynamics(q, v), ch.forward_dynamics(q, v))


def test_the_compiled_engines_energies_include_the_payload():
    seg = Segment(**dict(SEGMENT, damping=0.0))
    ch = Chain([seg] * 2, payload=pin.Inertia(0.02, np.array([0.005, -0.003, 0.01]), I_C * 0.1))
    q0 = ch.neutral()
    q0[1::3] = [4.0, -3.0]
    res = qchain.simulate(ch, q0, np.zeros(ch.nv), (0.0, 0.05), method="dopri5", rtol=1e-8, atol=1e-10)
    K = np.array([ch.kinetic_energy(q, v) for q, v in zip(res.q, res.v)])
    U = np.array([ch.potential_energy(q) for q in res.q])
    np.testing.assert_allclose(res.kinetic_energy, K, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(res.potential_energy, U, rtol=1e-10, atol=1e-12)


# -- scene files: the [payload] table (qchain/scene/payload.py)

def _payload_scene(payload, pressure=None, **top):
    from support import base_scene, to_toml

    d = base_scene()
    d["payload"] = payload
    if pressure is not None:
        d["pressure"] = pressure
    d.update(top)
    return to_toml(d)


SCENE_PAYLOAD = {"mass": 0.06, "lever": [0.01, 0.0, 0.02], "inertia": [[2e-5, 0.0, 3e-6], [0.0, 3e-5, 0.0],
                                                                        [3e-6, 0.0, 1e-5]]}


def _weight_as_tip_load(chain, bare, p, iterations=60):
    """The static shape of ``bare`` (the arm without the payload) carrying ``chain.payload``'s
    weight as a world-frame PointLoad at the tip: force m g, moment (R c) x m g about the tip
    origin, the moment updated from each shape until the shape stops moving."""
    from qchain import equilibrium
    from qchain.contact import Environment, PointLoad

    P = chain.payload
    f = P.mass * chain.gravity
    q = bare.neutral()
    for _ in range(iterations):
        arm = chain.tip_placement(q).rotation @ P.lever
        res = equilibrium(bare, p, q0=q, env=Environment([], loads=[PointLoad(chain.n - 1, 1.0, f, np.cross(arm, f))]),
                          tol=1e-13)
        assert res.success, res.message
        step = np.abs(res.q - q).max()
        q = res.q
        if step < 1e-13:
            return q
    raise AssertionError(f"the tip load's shape did not settle (last step {step:.3g})")


def test_a_scene_payload_is_the_chains_and_its_statics_are_its_weight_at_the_tip():
    """The [payload] table makes the Chain's payload (mass, lever, inertia as written); the static
    shape of the scene's arm equals the bare arm's carrying the payload's weight as a tip
    PointLoad (the environment's load path, not the passes' payload code), and its weight
    lowers the tip against the bare arm's (the arm hanging, bent by its pressures)."""
    from qchain import equilibrium
    from qchain.scene import parse_scene

    hanging = {"type": "fixed", "position": [0.0, 0.0, 0.5], "rpy": [np.pi, 0.0, 0.0]}
    sc = parse_scene(_payload_scene(SCENE_PAYLOAD, base=hanging), "p.toml")
    ch = sc.model.chain
    P = ch.payload
    assert P.mass == 0.06
    np.testing.assert_array_equal(P.lever, SCENE_PAYLOAD["lever"])
    np.testing.assert_array_equal(P.inertia, SCENE_PAYLOAD["inertia"])
    assert ch.planar  # lever y = 0 and y a principal axis: the reduction stays
    full = sc.build(reduce=False).chain
    bare = Chain([s.segment() for s in sc.segments], gravity=sc.gravity, base_placement=sc.base.placement)
    p = sc.pressure(0.0)
    eq_full = equilibrium(full, p, tol=1e-13)
    assert eq_full.success
    q_load = _weight_as_tip_load(full, bare, p)
    np.testing.assert_allclose(eq_full.q, q_load, rtol=0, atol=1e-10)
    eq_planar = equilibrium(ch, p)  # the planar model: the same shape
    np.testing.assert_allclose(eq_planar.q, eq_full.q, rtol=0, atol=1e-9)
    drop = bare.tip_placement(equilibrium(bare, p).q).translation[2] - full.tip_placement(eq_full.q).translation[2]
    assert drop > 1e-3  # m: the payload matters


def test_a_point_mass_payload_by_default_and_mass_zero_is_none():
    from qchain.scene import parse_scene

    P = parse_scene(_payload_scene({"mass": 0.02})).model.chain.payload
    assert P.mass == 0.02 and not np.any(P.lever) and not np.any(P.inertia)
    sc = parse_scene(_payload_scene({"mass": 0.0}))
    assert sc.payload is None and sc.model.chain.payload is None
    assert not any(x.startswith("payload:") for x in sc.describe())


@pytest.mark.parametrize("payload, line", [
    ({"mass": -0.1}, "payload.mass: expected a number >= 0 and <= 1e+06 (kg), found -0.1"),
    ({"lever": [0.0, 0.0, 0.1]}, "payload.mass: expected a number >= 0 and <= 1e+06 (kg), found nothing"),
    ({"mass": 0.1, "lever": [0.0, 0.0, 1e3]},
     "payload.lever[2]: expected a number >= -100 and <= 100 (m), found 1000.0"),
    ({"mass": 0.1, "lever": [0.0, 0.1]},
     "payload.lever: expected an array of 3 numbers (m), found 2 numbers [0.0, 0.1]"),
    ({"mass": 0.1, "inertia": [1e-5, 1e-5, 1e-5]},
     "payload.inertia: expected 3 arrays of 3 numbers, one a row (kg m^2), found an array [1e-05, 1e-05, 1e-05]"),
    ({"mass": 0.1, "inertia": [[1e-5, 0.0, 0.0], [0.0, 1e-5, 0.0], [0.0, 0.0, float("nan")]]},
     "payload.inertia[2][2]: expected a finite number, found a float nan"),
    ({"mass": 0.1, "inertia": [[1e-5, 2e-6, 0.0], [0.0, 1e-5, 0.0], [0.0, 0.0, 1e-5]]},
     "payload.inertia: expected a rigid body's rotational inertia about its centre of mass: symmetric, positive "
     "semi-definite (kg m^2), found a matrix that is not symmetric, ((1e-05, 2e-06, 0), (0, 1e-05, 0), (0, 0, 1e-05))"),
    ({"mass": 0.1, "inertia": [[1e-5, 2e-5, 0.0], [2e-5, 1e-5, 0.0], [0.0, 0.0, 1e-5]]},
     "found a matrix that is not positive semi-definite, eigenvalues (-1e-05, 1e-05, 3e-05) kg m^2"),
    ({"mass": 0.0, "inertia": [[1e-5, 0.0, 0.0], [0.0, 1e-5, 0.0], [0.0, 0.0, 1e-5]]},
     "payload.inertia: expected zeros with payload.mass = 0 (a body without mass has no rotational inertia)"),
    ({"mass": 0.1, "offset": [0.0, 0.0, 0.1]}, "payload.offset: expected one of the keys mass, lever, inertia"),
])
def test_bad_payload_values_are_refused_by_key_value_and_bound(payload, line):
    from qchain.scene import SceneError, parse_scene

    with pytest.raises(SceneError) as err:
        parse_scene(_payload_scene(payload), "p.toml")
    assert any(line in str(p) for p in err.value.problems), str(err.value)


def test_a_scene_payload_refuses_what_chain_refuses():
    """The scene's rigid-body check is the Chain's (qchain.arm.payload.inertia_problem): the same
    matrices pass and fail both ways."""
    from qchain.arm.payload import inertia_problem
    from qchain.scene import SceneError, parse_scene

    for I in (np.diag([1e-5, 2e-5, 0.0]), np.array([[1e-5, 2e-5, 0], [2e-5, 1e-5, 0], [0, 0, 1e-5]]),
              np.array([[1e-5, 1e-6, 0], [1e-6, 1e-5, 0], [0, 0, 1e-5]])):
        text = _payload_scene({"mass": 0.1, "inertia": I.tolist()})
        try:
            Chain([S], payload=pin.Inertia(0.1, np.zeros(3), I))
        except ValueError:
            with pytest.raises(SceneError):
                parse_scene(text)
            assert inertia_problem(I) is not None
        else:
            assert parse_scene(text).payload is not None and inertia_problem(I) is None


@pytest.mark.parametrize("payload, why", [
    ({"mass": 0.05, "lever": [0.0, 0.01, 0.02]},
     "payload: its lever (0, 0.01, 0.02) m leaves the tip frame's x-z plane (y = 0.01 m, not 0)"),
    ({"mass": 0.05, "inertia": [[2e-5, 1e-6, 0.0], [1e-6, 2e-5, 0.0], [0.0, 0.0, 1e-5]]},
     "payload: its inertia couples the tip frame's y axis with x or z (inertia[0][1] = 1e-06"),
])
def test_an_asymmetric_payload_gives_the_full_model_with_the_reason(payload, why):
    """A payload off the tip's x-z plane: the planar reduction is refused, the reason in
    SceneModel.kept (`qchain info`); the full model does accelerate out of the plane."""
    from qchain.scene import parse_scene

    sym = {"type": "constant", "value": [1e4, 0, 0, 1e4, 0, 0]}  # chambers 2 and 3 equal: planar but for the payload
    sc = parse_scene(_payload_scene(payload, sym))
    assert why in sc.planar_obstacle()
    assert not sc.model.chain.planar and any(k == f"planar: not applicable: {sc.planar_obstacle()}"
                                             for k in sc.model.kept)
    m = sc.model
    q = m.q0.copy()
    q[1::3] = 2.0  # bent in the plane: the lever's or the inertia's y coupling then pushes out of it
    a = m.chain.forward_dynamics(q, m.v0, sc.pressure(0.0))
    assert np.abs(a[2::3]).max() > 1e-3
    sc_sym = parse_scene(_payload_scene({"mass": 0.05, "lever": [0.01, 0.0, 0.02]}, sym))
    assert sc_sym.planar_obstacle() is None and sc_sym.model.chain.planar
    assert any("tip payload symmetric about the base x-z plane" in r for r in sc_sym.model.reductions)


def test_info_lists_the_payload():
    from qchain.scene import parse_scene

    lines = parse_scene(_payload_scene(SCENE_PAYLOAD)).describe()
    assert ("payload: 0.06 kg (0.6 x the arm's 0.1 kg) at lever (0.01, 0, 0.02) m (tip frame), inertia "
            "((2e-05, 0, 3e-06), (0, 3e-05, 0), (3e-06, 0, 1e-05)) kg m^2 about its centre of mass; weight 0.5886 N"
            ) in lines
    ball = parse_scene(_payload_scene({"mass": 0.05, "inertia": np.diag([1e-5, 1e-5, 2e-5]).tolist()})).describe()
    assert any("principal moments (1e-05, 1e-05, 2e-05) kg m^2 along the tip axes" in x for x in ball)


def test_the_format_docs_payload_example_is_a_valid_scene():
    from qchain.scene import format as F
    from qchain.scene import parse_scene

    sc = parse_scene(F.EXAMPLE + "\n" + F.PAYLOAD_EXAMPLE, "example.toml")
    assert sc.payload.mass == 0.06 and sc.planar_obstacle() is None
