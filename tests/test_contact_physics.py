"""Contact physics against independent computations (docs/contact.md, docs/accuracy.md
"Contact"): an arm at rest on the ground against Newton-Euler statics, a frictionless drop
against energy conservation, the rebound of a flat impact against a one-degree-of-freedom
Hunt-Crossley contact integrated by scipy (and against Flores's nominal restitution), an arm on
an inclined plane against Coulomb's sticking and sliding (and the regularised law's creep speed),
the ball-chain discretisation's ripple over a thin pole against plane geometry, and a cantilever
pressed onto the ground against a Kirchhoff rod on the law's continuous foundation (scipy's
solve_bvp).

Every run but the cantilever's (scipy's BDF: its segments' damping is stiff) uses the compiled
``dopri5`` with a contact stiffness soft enough (1e5 or 1e6 N/m^2.5: a metre of tube takes
``k d^1.5``) that the contact's time scale is ~1-10 ms: explicit steps of ~0.1 ms resolve it,
so a run of a fraction of a second costs thousands of steps, not millions.
The figures quoted in the comments were measured on 2026-12-04 (docs/accuracy.md).
"""

import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import solve_bvp, solve_ivp

import qchain
from qchain import Chain, Segment
from qchain.contact import Capsule, ContactLaw, Environment, HalfSpace, hunt_crossley_damping
from support import SEGMENT

G = 9.81
R_S = SEGMENT["radius"]
L0 = SEGMENT["length"]


def _flat_base(height, roll=0.0, pitch=0.0, yaw=0.0):
    """The floating base's ``(x, y, z, qx, qy, qz, qw)`` that lays the arm (which grows along
    the base's +z) along world +x, its axis ``height`` above the ground, turned by the
    small angles given (rad)."""
    R = pin.rpy.rpyToMatrix(roll, np.pi / 2 + pitch, yaw)
    return pin.SE3ToXYZQUAT(pin.SE3(R, np.array([0.0, 0.0, height])))


def _com(ch, q):
    """The arm's centre of mass (3,), m, world frame."""
    m = np.array([s.mass for s in ch.segments])
    return ch.centers_of_mass(q).T @ m / m.sum()


def _contact_energy(ch, q, v, env):
    """``U_c = sum (l0 / nodes) k d^(e+1) / (e+1)`` (J) over the contacts ``chain.contacts``
    reports: the potential of the frictionless, undamped law (docs/contact.md)."""
    law, c = env.law, ch.contacts(q, v, env)
    ell = np.array([ch.segments[j].length for j in c.segment]) / env.nodes
    e = law.exponent
    return float(np.sum(ell * law.stiffness * c.penetration ** (e + 1) / (e + 1)))


# -- (1) an arm at rest on the ground: Newton-Euler statics of the whole arm


@pytest.mark.slow
def test_an_arm_at_rest_on_the_ground_carries_its_weight_and_no_moment():
    """Three segments, damped and with friction, dropped from 3 mm tilted and turned, settled
    for 1 s: the contact forces add up to the weight and their moment about the centre of
    mass is zero (gravity's moment about it). The residual of both is the rate of change of
    the arm's momentum, which the settling leaves: measured 2026-12-04 |sum F / W - 1| = 4e-7,
    |moment| / (W L) = 4e-9, with the momentum rate 3.8e-7 W at the end (the force residual is
    that rate)."""
    n, k, e = 3, 1e5, 1.5
    ch = Chain([Segment(**SEGMENT) for _ in range(n)], base="floating")
    q0 = ch.neutral()
    q0[:7] = _flat_base(R_S + 3e-3, pitch=0.03, yaw=0.2)
    v0 = np.zeros(ch.nv)
    v0[2] = 0.05  # along the base's z: the arm slides along its axis as it lands
    law = ContactLaw(stiffness=k, exponent=e, damping=hunt_crossley_damping(0.3, 0.1), mu_static=0.6, mu_dynamic=0.5)
    env = Environment([HalfSpace()], law)
    T = 1.0
    tr = qchain.simulate(ch, q0, v0, (0.0, T), method="dopri5", env=env, rtol=1e-7, atol=1e-10,
                         t_eval=[T - 2e-3, T - 1e-3, T])
    assert tr.success
    q, v = tr.q[-1], tr.v[-1]
    W = sum(s.mass for s in ch.segments) * G
    # settled: the momentum's rate (central difference) is a millionth of the weight, so
    # Newton-Euler leaves the contact forces nothing but the statics
    h = np.array([ch.momentum(qi, vi) for qi, vi in zip(tr.q, tr.v)])
    hdot = (h[2] - h[0]) / 2e-3
    assert np.abs(hdot[:3]).max() < 1e-5 * W
    c = ch.contacts(q, v, env)
    assert len(c.segment) == n * env.nodes  # every contact point of the straight arm touches
    np.testing.assert_allclose(c.force.sum(axis=0), [0.0, 0.0, W], rtol=0, atol=1e-5 * W)
    arm_length = n * L0
    moment = np.cross(c.point - _com(ch, q), c.force).sum(axis=0)
    np.testing.assert_allclose(moment, 0.0, rtol=0, atol=1e-5 * W * arm_length)
    # the sinking at rest is the law's (w / k)^(1/e), w the weight per metre, within the
    # slight curl (0.01 1/m) that friction locks into the arm as it lands: measured
    # 1.3282 to 1.3775 mm against 1.3400 mm
    sink = (W / (arm_length * k)) ** (1 / e)
    assert np.abs(c.penetration / sink - 1).max() < 0.05


# -- (2) a frictionless, undamped drop conserves energy through impact and rebound


def test_a_frictionless_undamped_drop_conserves_energy_through_impact_and_rebound():
    """Two undamped segments dropped from 3 cm, tilted, onto a frictionless ground without
    contact damping: ``E = T + U(gravity + elastic) + U_c`` stays constant through the
    impacts and rebounds (five contact changes in 0.25 s) to the integrator's tolerance, and
    the drift shrinks with it: measured 2026-12-04 max |E - E0| / max T = 1.2e-5 at rtol 1e-6
    and 9.3e-7 at rtol 1e-8 (max T = 0.0235 J)."""
    ch = Chain([Segment(**dict(SEGMENT, damping=0.0)) for _ in range(2)], base="floating")
    q0 = ch.neutral()
    q0[:7] = _flat_base(0.03, roll=0.1, pitch=-0.15, yaw=0.3)
    env = Environment([HalfSpace()], ContactLaw(stiffness=1e5, exponent=1.5), nodes=16)
    v0 = np.zeros(ch.nv)
    T = 0.25
    drift = {}
    for rtol in (1e-6, 1e-8):
        tr = qchain.simulate(ch, q0, v0, (0.0, T), method="dopri5", env=env, rtol=rtol, atol=rtol * 1e-2,
                             t_eval=np.linspace(0, T, 501))
        assert tr.success
        E = np.array([ch.kinetic_energy(q, v) + ch.potential_energy(q) + _contact_energy(ch, q, v, env)
                      for q, v in zip(tr.q, tr.v)])
        touching = np.array([len(ch.contacts(q, v, env).segment) > 0 for q, v in zip(tr.q, tr.v)])
        # the run goes through impact and rebound: contact is made and lost more than once
        assert np.count_nonzero(np.diff(touching)) >= 4
        drift[rtol] = np.abs(E - E[0]).max() / tr.kinetic_energy.max()
    assert drift[1e-6] < 5e-5
    assert drift[1e-8] < 5e-6
    assert drift[1e-8] < drift[1e-6] / 5


# -- (2b) the contact's time scale


def test_a_resting_arm_bounces_on_the_ground_at_the_laws_frequency():
    """A straight segment resting flat on the ground, nudged 10 um up from its rest
    penetration ``d0 = (w / k)^(1/e)``, bounces at ``omega = sqrt(e g / d0)`` (docs/contact.md:
    each contact point's linearised stiffness ``e (w l) / d0`` over its mass ``m / nodes``;
    whatever the mass, length or node count): measured 2026-12-04 the period 75.5422 ms
    against 75.5422 ms (1.2e-6 relative; tolerance 1e-4, the amplitude's nonlinear shift
    being ~ (10 um / d0)^2 = 2e-5)."""
    l0, m, k, e = 0.05, 0.05, 1e5, 1.5
    ch = Chain([Segment(**dict(SEGMENT, length=l0, mass=m, youngs_modulus=1e6, damping=0.0))], base="floating")
    d0 = (m * G / l0 / k) ** (1 / e)
    q0 = ch.neutral()
    q0[:7] = _flat_base(R_S - d0 + 1e-5)
    env = Environment([HalfSpace()], ContactLaw(stiffness=k, exponent=e), nodes=8)
    tr = qchain.simulate(ch, q0, np.zeros(ch.nv), (0.0, 0.3), method="dopri5", env=env, rtol=1e-7, atol=1e-10,
                         t_eval=np.linspace(0, 0.3, 1201))
    assert tr.success
    z = np.array([_com(ch, q)[2] for q in tr.q]) - (R_S - d0)
    i = np.nonzero((z[:-1] < 0) & (z[1:] >= 0))[0]  # upward crossings of the rest height
    crossings = tr.t[i] - z[i] * (tr.t[i + 1] - tr.t[i]) / (z[i + 1] - z[i])
    assert len(crossings) >= 3
    period = np.diff(crossings).mean()
    assert period == pytest.approx(2 * np.pi * np.sqrt(d0 / (e * G)), rel=1e-4)


# -- (3) restitution of a flat impact


def _point_contact_rebound(m, ell, k, e, c, v):
    """The rebound speed ratio of one Hunt-Crossley contact ``m x'' = ell k d^e max(0, 1 + c d')``
    (``d = -x``) met at speed ``v``: scipy's DOP853 at rtol 1e-12, the independent reference."""

    def f(t, y):
        d, dd = -y[0], -y[1]
        fn = ell * k * d ** e * max(0.0, 1.0 + c * dd) if d > 0 else 0.0
        return [y[1], fn / m]

    sol = solve_ivp(f, (0.0, 0.02), [0.0, -v], method="DOP853", rtol=1e-12, atol=1e-15)
    return sol.y[1, -1] / v


@pytest.mark.parametrize("e", [0.5, 0.8, 0.95])
def test_a_flat_impact_rebounds_as_one_hunt_crossley_contact(e):
    """A short, stiff (E = 1e8 Pa) straight segment, floating and horizontal, meets the
    ground flat at v = 0.5 m/s with ``c = hunt_crossley_damping(e, v)`` (no gravity, so the
    speeds before and after are the run's first and last). Every contact point then carries
    its own share (mass m / nodes, rest length l0 / nodes) of one and the same contact, so the
    ratio of the centre of mass's vertical speeds after / before is that of a single
    Hunt-Crossley point contact, integrated independently by scipy: measured 2026-12-04 to
    1.4e-8 (tolerance 1e-6, the runs' rtol 1e-9 compounded over ~2600 steps).

    Against the nominal ``e`` the ratio is lower: 0.4704, 0.7885, 0.9468 for e = 0.5, 0.8,
    0.95. Flores et al. (2011) derive ``c = 8 (1 - e) / (5 e v)`` from an approximate energy
    balance over the hysteresis loop (exact as e -> 1), so its error grows with ``1 - e``:
    the measured shortfall is 0.059, 0.057 and 0.063 of ``1 - e``; the test allows 0.1 (1 - e)."""
    v, k, ex, K, l0, m = 0.5, 1e6, 1.5, 8, 0.05, 0.05
    seg = Segment(**dict(SEGMENT, length=l0, mass=m, youngs_modulus=1e8, damping=0.0))
    ch = Chain([seg], base="floating", gravity=[0.0, 0.0, 0.0])
    R = pin.rpy.rpyToMatrix(0.0, np.pi / 2, 0.0)
    q0 = ch.neutral()
    q0[:7] = pin.SE3ToXYZQUAT(pin.SE3(R, np.array([0.0, 0.0, R_S])))  # touching, not penetrating
    v0 = np.zeros(ch.nv)
    v0[:3] = R.T @ [0.0, 0.0, -v]  # the base's velocity is in its own frame
    c = hunt_crossley_damping(e, v)
    env = Environment([HalfSpace()], ContactLaw(stiffness=k, exponent=ex, damping=c), nodes=K)
    tr = qchain.simulate(ch, q0, v0, (0.0, 0.02), method="dopri5", env=env, rtol=1e-9, atol=1e-12,
                         t_eval=[0.0, 0.02])
    assert tr.success
    assert len(ch.contacts(tr.q[-1], tr.v[-1], env).segment) == 0  # it has left the ground
    ratio = ch.momentum(tr.q[-1], tr.v[-1])[2] / (m * v)
    reference = _point_contact_rebound(m / K, l0 / K, k, ex, c, v)
    assert abs(ratio - reference) < 1e-6
    assert e - 0.1 * (1 - e) < ratio < e


# -- (4) an arm on an inclined plane: Coulomb's sticking and sliding


def _slope_run(mu, ratio, T=0.5, eps=1e-3):
    """Two segments lying down the slope of a half-space tilted by ``theta = atan(ratio mu)``
    (the arm along the fall line, so that it cannot roll), started at the penetration that
    carries its weight: the centre of mass's displacement (m) down the slope at 51 samples
    over ``T`` s."""
    ch = Chain([Segment(**SEGMENT) for _ in range(2)], base="floating")
    th = np.arctan(ratio * mu)
    nrm = np.array([np.sin(th), 0.0, np.cos(th)])
    down = np.array([np.cos(th), 0.0, -np.sin(th)])
    R = np.column_stack([nrm, np.cross(down, nrm), down])  # base z down the slope, x out of it
    k, e = 1e5, 1.5
    w = sum(s.mass for s in ch.segments) * G / (2 * L0)  # weight per metre, N/m
    sink = (w * np.cos(th) / k) ** (1 / e)
    q0 = ch.neutral()
    q0[:7] = pin.SE3ToXYZQUAT(pin.SE3(R, nrm * (R_S - sink)))
    law = ContactLaw(stiffness=k, exponent=e, damping=20.0, mu_static=mu, mu_dynamic=mu, slip_velocity=eps)
    env = Environment([HalfSpace(normal=nrm)], law)
    tr = qchain.simulate(ch, q0, np.zeros(ch.nv), (0.0, T), method="dopri5", env=env, rtol=1e-7, atol=1e-10,
                         t_eval=np.linspace(0, T, 51))
    assert tr.success
    s = np.array([down @ _com(ch, q) for q in tr.q])
    return tr.t, s - s[0], th


def test_an_arm_on_a_slope_below_the_friction_angle_sticks_and_creeps_as_the_law_says():
    """tan(theta) = 0.8 mu: the arm sticks. The regularised friction
    ``mu f_n s / sqrt(s^2 + eps^2)`` can only hold the slope's pull ``f_n tan(theta)`` by
    sliding at the creep speed ``s = eps rho / sqrt(1 - rho^2)``, ``rho = tan(theta) / mu``
    (docs/contact.md): 1.3333 eps here. Measured 2026-12-04: 1.3355 mm/s after the first
    0.1 s (0.16 % above; tolerance 2 %, the arm's own settling), 0.71 mm over 0.5 s, against
    155 mm sliding at 1.3 mu."""
    mu, eps = 0.5, 1e-3
    t, s, th = _slope_run(mu, 0.8, eps=eps)
    rho = np.tan(th) / mu
    creep = eps * rho / np.sqrt(1 - rho ** 2)
    rate = np.polyfit(t[10:], s[10:], 1)[0]
    assert abs(rate / creep - 1) < 0.02
    assert 0 < s[-1] < 1.1 * creep * t[-1]


def test_an_arm_on_a_slope_above_the_friction_angle_slides_at_coulombs_acceleration():
    """tan(theta) = 1.3 mu: the arm slides with ``g (sin theta - mu cos theta)``; sliding at
    s >> eps the regularisation takes off only ``eps^2 / (2 s^2)`` of the friction, and the
    normal force carries ``m g cos theta`` once the first 0.1 s have settled its oscillation.
    Measured 2026-12-04: 1.233789 vs 1.233770 m/s^2 (1.6e-5 relative; tolerance 1e-3)."""
    mu = 0.5
    t, s, th = _slope_run(mu, 1.3)
    a = 2 * np.polyfit(t[10:], s[10:], 2)[0]
    assert a == pytest.approx(G * (np.sin(th) - mu * np.cos(th)), rel=1e-3)


# -- (5) the discretisation: the tube as a chain of balls


@pytest.mark.parametrize("nodes", [8, 16, 32])
def test_over_a_thin_pole_the_ball_chain_ripples_as_plane_geometry_says(nodes):
    """A straight tube lowered by ``delta`` onto a thin pole (a capsule of radius ``rho``
    across it) would penetrate ``delta`` wherever it lies; the chain of ``nodes`` balls per
    segment (spacing ``h = l0 / nodes``) penetrates ``r_s + rho - sqrt(s^2 + H^2)`` at the
    ball whose centre is ``s`` along the arm from the pole (``H`` the axis height above the
    pole's axis). Sliding the arm over one spacing, the deepest penetration runs between
    ``delta`` (a ball right above the pole) and ``delta`` less the ripple
    ``sqrt(H^2 + h^2 / 4) - H`` (~ ``h^2 / (8 H)``, docs/contact.md): measured 2026-12-04
    1.332, 0.345 and 0.087 mm for 8, 16 and 32 balls (rho 2 mm, delta 3 mm; the penetrations
    match plane geometry to 1e-15 m).
    On a flat obstacle parallel to a straight tube there is no ripple: every ball touches at
    its lowest point, which lies on the tube (test (1) sinks by the law's value)."""
    ch = Chain([Segment(**SEGMENT)], base="floating")
    rho, delta = 0.002, 0.003
    h = L0 / nodes
    env = Environment([Capsule([0.0, -1.0, 0.0], [0.0, 1.0, 0.0], rho)], nodes=nodes)
    H = R_S + rho - delta
    centres = (np.arange(nodes) + 0.5) * h  # along the arm from its root
    R = pin.rpy.rpyToMatrix(0.0, np.pi / 2, 0.0)
    deepest = []
    for u in np.linspace(0.0, h, 9):
        x0 = -L0 / 2 + u  # the root's x; the pole is at x = 0
        q = ch.neutral()
        q[:7] = pin.SE3ToXYZQUAT(pin.SE3(R, np.array([x0, 0.0, H])))
        c = ch.contacts(q, np.zeros(ch.nv), env)
        expected = R_S + rho - np.hypot(x0 + centres, H)
        np.testing.assert_allclose(np.sort(c.penetration), np.sort(expected[expected > 0]), rtol=0, atol=1e-15)
        deepest.append(c.penetration.max())
    ripple = np.sqrt(H ** 2 + h ** 2 / 4) - H
    assert max(deepest) == pytest.approx(delta, abs=1e-15)
    assert max(deepest) - min(deepest) == pytest.approx(ripple, abs=1e-15)


@pytest.mark.parametrize("stiffness", [1e4, 1e5, 1e6])
def test_contact_nodes_keep_the_ripple_over_an_edge_within_a_quarter_of_the_rest_penetration(stiffness):
    """``contact_nodes`` picks the fewest balls a segment whose ripple over the sharpest obstacle
    (an edge: a pole of radius -> 0) stays within ``RIPPLE`` (1/4) of the depth ``d0`` a segment
    sinks under its own weight. Measured by sliding a straight tube resting at ``d0`` over a
    1 um pole by one spacing (the penetrations as ``chain.contacts`` reports them): the ripple is
    ``sqrt(H^2 + h^2/4) - H <= h^2 / (8 H)``, ``H = r_s + rho - d0``; the rule bounds
    ``h^2 / (8 r_s)``, so the measured ripple may exceed ``d0 / 4`` by the factor ``r_s / H``
    and no more; with one ball fewer it exceeds ``d0 / 4``."""
    from qchain.contact import contact_nodes
    from qchain.contact.environment import RIPPLE

    law = ContactLaw(stiffness=stiffness)
    ch = Chain([Segment(**SEGMENT)], base="floating", gravity=(0.0, 0.0, -G))
    K = contact_nodes(ch.segments, law, ch.gravity)
    d0 = (SEGMENT["mass"] * G / (L0 * stiffness)) ** (1 / law.exponent)
    rho = 1e-6
    H = R_S + rho - d0
    R = pin.rpy.rpyToMatrix(0.0, np.pi / 2, 0.0)

    def ripple(nodes):
        h = L0 / nodes
        env = Environment([Capsule([0.0, -1.0, 0.0], [0.0, 1.0, 0.0], rho)], law, nodes=nodes)
        deepest = []
        for u in np.linspace(0.0, h, 41):
            q = ch.neutral()
            q[:7] = pin.SE3ToXYZQUAT(pin.SE3(R, np.array([-L0 / 2 + u, 0.0, H])))
            deepest.append(ch.contacts(q, np.zeros(ch.nv), env).penetration.max())
        assert max(deepest) == pytest.approx(d0, rel=1e-9)  # a ball right over the edge
        return max(deepest) - min(deepest)

    assert 1 < K < 64
    assert ripple(K) <= RIPPLE * d0 * R_S / H * (1 + 1e-9)
    assert ripple(K - 1) > RIPPLE * d0
    # the scene's default is the rule's count
    assert K == contact_nodes([Segment(**SEGMENT)], law, (0.0, 0.0, -G))


def test_contact_nodes_refuses_what_it_cannot_use():
    from qchain.contact import contact_nodes

    segs = [Segment(**SEGMENT)]
    with pytest.raises(ValueError, match=r"ripple must be in \(0, 1\].*got 0\.0"):
        contact_nodes(segs, ContactLaw(), (0, 0, -G), ripple=0.0)
    with pytest.raises(TypeError, match="law must be a ContactLaw, got dict"):
        contact_nodes(segs, {"stiffness": 1e6}, (0, 0, -G))
    with pytest.raises(ValueError, match="gravity"):
        contact_nodes(segs, ContactLaw(), (0, 0, np.nan))
    # weightless: reckoned at a milli-g, so a finite count (the stiffest laws reach the cap)
    assert contact_nodes(segs, ContactLaw(), (0, 0, 0)) >= contact_nodes(segs, ContactLaw(), (0, 0, -G))
    assert contact_nodes(segs, ContactLaw(stiffness=1e12), (0, 0, -G)) == 64


# -- (6) a cantilever bending down onto the ground: the shape and the contact force


CANT_L, CANT_R, CANT_E, CANT_RHO = 0.2, 0.01, 5e6, 1100.0  # m, m, Pa, kg/m^3
CANT_GAP = 0.012  # m: the ground's surface is 12 mm + r below the clamp's axis
CANT_K, CANT_EXP = 1e6, 1.5


def _rod_on_foundation():
    """The planar Kirchhoff rod (inextensible, unshearable) clamped horizontally at the origin
    under its own weight ``w`` on the law's contact as a continuous foundation: where its
    surface is below the ground (``d = z_g + r - z > 0``) the ground pushes up with
    ``p = k d^e`` per metre (the ball chain's limit of many points, frictionless, at rest).
    ``EI theta'' = V cos(theta)``, ``V' = -(w - p)`` (``V`` the net downward load beyond
    ``s``), ``theta(0) = x(0) = z(0) = 0``, ``theta'(L) = V(L) = 0``; scipy's solve_bvp at
    tol 1e-8. Returns its solution ``(s) -> (theta, kappa, x, z, V)``, the ground pressure
    ``p(s)`` and the total contact force (N)."""
    A = np.pi * CANT_R ** 2
    EI, w = CANT_E * np.pi * CANT_R ** 4 / 4, CANT_RHO * A * G
    zg = -CANT_GAP - CANT_R

    def pressure(z):
        return CANT_K * np.maximum(0.0, zg + CANT_R - z) ** CANT_EXP

    def f(s, y):
        th, kap, _, z, V = y
        return np.vstack([kap, V * np.cos(th) / EI, np.cos(th), np.sin(th), -(w - pressure(z))])

    def bc(ya, yb):
        return np.array([ya[0], ya[2], ya[3], yb[1], yb[4]])

    s = np.linspace(0.0, CANT_L, 401)
    guess = np.zeros((5, s.size))
    guess[2] = s
    sol = solve_bvp(f, bc, s, guess, tol=1e-8, max_nodes=100000)
    assert sol.success, sol.message
    ss = np.linspace(0.0, CANT_L, 20001)
    return sol.sol, float(np.trapezoid(pressure(sol.sol(ss)[3]), ss))


def _cantilever_on_ground(n):
    """``n`` inextensible segments clamped horizontally (backbone along world +x) at the
    origin, the ground below, settled from straight for 1 s (scipy's BDF: the segments'
    stiffness-proportional damping makes the explicit steppers' steps tiny at n = 8). Returns
    the settled backbone at arclengths ``s`` and the contacts."""
    A = np.pi * CANT_R ** 2
    segs = [Segment(length=CANT_L / n, radius=CANT_R, mass=CANT_RHO * A * CANT_L / n, chamber_area=1e-6,
                    chamber_radius=0.005, youngs_modulus=CANT_E, damping=0.02, extensible=False) for _ in range(n)]
    ch = Chain(segs, base_placement=pin.SE3(pin.utils.rotate("y", np.pi / 2), np.zeros(3)))
    law = ContactLaw(stiffness=CANT_K, exponent=CANT_EXP, damping=5.0)
    env = Environment([HalfSpace([0.0, 0.0, -CANT_GAP - CANT_R])], law, nodes=16)
    tr = qchain.simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, 1.0), method="BDF", env=env, rtol=1e-6,
                         atol=1e-9, t_eval=[1.0])
    assert tr.success
    q, v = tr.q[-1], tr.v[-1]
    assert np.abs(v).max() < 1e-6  # settled (measured 1.6e-9 and 7.2e-10)
    P = 11
    s = (np.arange(n)[:, None] + np.linspace(0.0, 1.0, P)[None, :]).ravel() * CANT_L / n  # inextensible
    return s, ch.backbone(q, P).reshape(-1, 3), ch.contacts(q, v, env)


@pytest.mark.slow
def test_a_cantilever_pressed_onto_the_ground_matches_a_rod_on_the_laws_foundation():
    """A 0.2 m cantilever (r 10 mm, E 5 MPa, 1100 kg/m^3) clamped 12 mm above the ground sags
    onto it (free, it would sag 17 mm); its tip end rests on the ground. The reference is the
    Kirchhoff rod on the law's continuous foundation (the many-points limit of the ball chain;
    `_rod_on_foundation`). Measured 2026-12-04: total contact force 0.06339 and 0.06663 N
    against 0.06769 N (6.4 % and 1.6 % low; 0.39 % at n = 16), the backbone within 0.152 and
    0.037 mm of the reference at equal arclength, for n = 4 and 8 segments: the
    constant-curvature segments' error, second order in 1/n (the 64 rather than 16 contact
    points per segment change the force by 0.03 %). The same scene against PyElastica:
    tests/test_contact_pyelastica.py."""
    ref, F_ref = _rod_on_foundation()
    force_err, shape_err = [], []
    for n in (4, 8):
        s, bb, c = _cantilever_on_ground(n)
        assert len(c.segment) > 0 and np.all(c.segment == n - 1)  # only the last segment's end touches
        # frictionless: the ground pushes straight up
        np.testing.assert_allclose(c.force[:, :2], 0.0, atol=1e-12)
        force_err.append(c.force[:, 2].sum() / F_ref - 1)
        _, _, x, z, _ = ref(s)
        shape_err.append(np.hypot(bb[:, 0] - x, bb[:, 2] - z).max())
    assert -0.08 < force_err[0] < 0 and -0.02 < force_err[1] < 0
    assert 3.0 < force_err[0] / force_err[1] < 5.0  # second order in 1/n
    assert shape_err[0] < 2e-4 and shape_err[1] < 5e-5
