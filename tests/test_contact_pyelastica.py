"""Contact against another code: PyElastica (docs/contact.md and docs/accuracy.md, "Against
PyElastica").

The scene is test (6) of tests/test_contact_physics.py with a linear contact law, which is
what PyElastica's rod-plane contact has: a 0.2 m cantilever (r 10 mm, E 5 MPa,
1100 kg/m^3) clamped horizontally with its axis 12 mm above a frictionless ground sags onto
it (free, it would sag 17 mm) and its tip end rests there. Both codes settle it with damping
(PyElastica's ``AnalyticalLinearDamper``, qchain's segment and contact damping: neither changes
the state of rest) and the settled backbones and total contact forces are compared.

The two contact laws, side by side (elastica/_contact_functions.py,
``_calculate_contact_forces_rod_plane``, pyelastica 1.0.0):

- PyElastica checks each element's centre, a ball of the rod's radius: the element of length
  ``ds`` penetrating ``d`` is pushed by ``k d + nu d'`` (``k`` in N/m per element), plus a
  *response force* that cancels the inward normal part of the element's other forces
  (internal and external, averaged from its nodes) whenever its surface is within
  ``surface_tol`` = 0.1 mm of the plane. qchain's ``ContactLaw(exponent=1)`` pushes each
  ball of rest length ``l0 / nodes`` with ``(l0 / nodes) k d`` (``k`` in N/m per metre of
  tube). The springs match per metre of tube when ``k_PyElastica = k_qchain ds`` and the
  balls sit where the elements' centres do: ``ds = l0 / nodes`` (here 16 segments of 4 and 8
  balls against 64 and 128 elements).
- The response force has no counterpart in qchain: at rest it carries part of the load, so
  PyElastica's lone tip element sinks a quarter of what qchain's ball does for the same ``k``
  (measured below). Both contacts are stiff enough here (k 1e7 N/m^2) that the penetrations
  (0.6 to 5 um) are small against the comparison's tolerance.

PyElastica is imported only inside the test, which is skipped when it is not installed.
The figures quoted were measured on 2026-12-04.
"""

import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

import qchain
from qchain import Chain, Segment
from qchain.contact import ContactLaw, Environment, HalfSpace

G = 9.81
L, R, E, RHO = 0.2, 0.01, 5e6, 1100.0  # m, m, Pa, kg/m^3
GAP = 0.012  # m: the ground's surface is GAP + R below the clamp's axis
K_QCHAIN = 1e7  # N/m per metre of tube (exponent 1)
N_SEG = 16  # qchain's segments


def _pyelastica_cantilever(n_elem, dt, T=0.6):
    """The cantilever in PyElastica 1.0.0: ``n_elem`` elements, clamped (``OneEndFixedBC``)
    at the origin along world +x, gravity along -z, ``RodPlaneContact(k = K_QCHAIN ds,
    nu = 0)``, uniform analytical damping 60 1/s (about the first mode's critical damping),
    ``PositionVerlet`` at ``dt`` (1e-5 s at 64 elements, where 2e-5 s diverges) for ``T`` s.
    The shear modulus is 10 E (PyElastica's default is E / 3) so that shear, which a
    Kirchhoff rod and qchain's segments do not have, adds ~1 um to the deflection (the
    estimate ``V L / (G A)``).

    Returns the node positions (n_elem + 1, 3), the largest node speed at the end (m/s), the
    contact force on each node (n_elem + 1, 3), N, recomputed from the settled state by
    PyElastica's own contact function, the force the clamp exerts (3,), N, the rod's mass
    (kg) and the last element's penetration (m)."""
    ea = pytest.importorskip("elastica")
    from elastica._contact_functions import _calculate_contact_forces_rod_plane

    class Sim(ea.BaseSystemCollection, ea.Constraints, ea.Forcing, ea.Damping, ea.Contact):
        pass

    sim, ds = Sim(), L / n_elem
    rod = ea.CosseratRod.straight_rod(n_elem, np.zeros(3), np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]),
                                      L, R, RHO, youngs_modulus=E, shear_modulus=10 * E)
    plane = ea.Plane(plane_origin=np.array([0.0, 0.0, -GAP - R]), plane_normal=np.array([0.0, 0.0, 1.0]))
    sim.append(rod)
    sim.append(plane)
    sim.constrain(rod).using(ea.OneEndFixedBC, constrained_position_idx=(0,), constrained_director_idx=(0,))
    # gravity is registered before the contact, so the contact's response force sees it
    sim.add_forcing_to(rod).using(ea.GravityForces, acc_gravity=np.array([0.0, 0.0, -G]))
    sim.detect_contact_between(rod, plane).using(ea.RodPlaneContact, k=K_QCHAIN * ds, nu=0.0)
    sim.dampen(rod).using(ea.AnalyticalLinearDamper, uniform_damping_constant=60.0, time_step=dt)
    sim.finalize()
    stepper, t = ea.PositionVerlet(), np.float64(0.0)
    for _ in range(round(T / dt)):
        t = stepper.step(sim, t, np.float64(dt))
    x = rod.position_collection.T.copy()
    speed = float(np.abs(rod.velocity_collection).max())
    # the forces at rest, as the contact sees them: internal, then gravity, then the contact
    rod.zeroed_out_external_forces_and_torques(t)
    rod.compute_internal_forces_and_torques(t)
    gravity = rod.mass[None, :] * np.array([0.0, 0.0, -G])[:, None]
    before = gravity.copy()
    after = gravity.copy()
    _calculate_contact_forces_rod_plane(plane.origin, plane.normal, np.float64(1e-4), np.float64(K_QCHAIN * ds),
                                        np.float64(0.0), rod.radius, rod.mass, rod.position_collection,
                                        rod.velocity_collection, rod.internal_forces, after)
    nodal_contact = after - before
    # the clamp holds node 0 against everything else on it
    clamp = -(rod.internal_forces[:, 0] + gravity[:, 0] + nodal_contact[:, 0])
    # the last element's penetration, with its own radius (PyElastica keeps each element's
    # volume, so its radius changes, by nanometres here, as it stretches)
    depth = rod.radius[-1] - (0.5 * (x[-2, 2] + x[-1, 2]) + GAP + R)
    return x, speed, nodal_contact.T, clamp, float(rod.mass.sum()), depth


def _qchain_cantilever(nodes):
    """The cantilever in qchain: ``N_SEG`` inextensible segments clamped along world +x,
    ``ContactLaw(K_QCHAIN, exponent=1)`` with ``nodes`` balls per segment, settled from
    straight for 1 s (the compiled radau5: the segments' damping is stiff). Returns the
    backbone at the arclengths of PyElastica's nodes (n_elem + 1, 3), the largest speed and
    the contacts."""
    A = np.pi * R ** 2
    segs = [Segment(length=L / N_SEG, radius=R, mass=RHO * A * L / N_SEG, chamber_area=1e-6, chamber_radius=0.005,
                    youngs_modulus=E, damping=0.02, extensible=False) for _ in range(N_SEG)]
    ch = Chain(segs, base_placement=pin.SE3(pin.utils.rotate("y", np.pi / 2), np.zeros(3)))
    env = Environment([HalfSpace([0.0, 0.0, -GAP - R])], ContactLaw(stiffness=K_QCHAIN, exponent=1.0, damping=5.0),
                      nodes=nodes)
    tr = qchain.simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, 1.0), method="radau5", env=env, rtol=1e-6,
                         atol=1e-9, t_eval=[1.0])
    assert tr.success
    q, v = tr.q[-1], tr.v[-1]
    P = nodes + 1  # the segment's ends and the element boundaries between them (inextensible)
    bb = ch.backbone(q, P).reshape(N_SEG, P, 3)
    bb = np.vstack([bb[:, :-1].reshape(-1, 3), bb[-1, -1]])
    return bb, float(np.abs(v).max()), ch.contacts(q, v, env)


def _propped_kirchhoff(s0, a, spring):
    """The support force (N) on the planar Kirchhoff rod (inextensible, unshearable) of the
    scene, clamped level at arclength ``s0`` (straight and rigid before it), resting at
    arclength ``a`` on a spring of stiffness ``spring`` (N/m) whose unloaded top is the
    ground's height plus r: ``EI theta'' = V cos(theta)`` with the shear force ``V(s) = w (L
    - s) - P [s < a]`` known given ``P``; shooting on ``theta'(s0)`` for ``theta'(L) = 0``
    and on ``P`` for ``z(a) = -(GAP + P / spring)`` (scipy, rtol 1e-12): the independent
    reference for each code's own discretisation of the support."""
    EI, w = E * np.pi * R ** 4 / 4, RHO * np.pi * R ** 2 * G

    def tip_and_contact(kappa0, P):
        def f(s, y):
            th, kap = y[0], y[1]
            V = w * (L - s) - (P if s < a else 0.0)
            return [kap, V * np.cos(th) / EI, np.cos(th), np.sin(th)]

        before = solve_ivp(f, (s0, a), [0.0, kappa0, s0, 0.0], rtol=1e-12, atol=1e-14).y[:, -1]
        after = solve_ivp(f, (a, L), before, rtol=1e-12, atol=1e-14).y[:, -1]
        return before, after

    def z_at_contact(P):
        k0 = brentq(lambda k: tip_and_contact(k, P)[1][1], -5.0, 5.0, xtol=1e-14)
        return tip_and_contact(k0, P)[0][3]

    return brentq(lambda P: z_at_contact(P) + GAP + P / spring, 0.0, 0.2, xtol=1e-14)


@pytest.mark.slow
def test_a_cantilever_on_the_ground_settles_as_in_pyelastica():
    """The settled cantilever in both codes, at two resolutions: 64 and 128 PyElastica
    elements against 16 qchain segments of 4 and 8 balls (the last ball where the last
    element's centre is, ``L - ds / 2``: only it touches, in both codes).

    PyElastica's clamp holds the whole first element (``OneEndFixedBC`` fixes node 0 and the
    first element's directors) and its curvatures live between elements, so its rod bends
    from ``ds / 2`` on: it is too stiff by O(ds) (free, in a separate run without the ground,
    it sags 16.642 mm at 64 elements against the Kirchhoff rod's 17.164 mm: 3.0 %, that of a
    cantilever ``ds / 2`` shorter, 16.634 mm).
    So the codes differ at first order in ``ds``, and the difference extrapolated to
    ``ds -> 0`` (Richardson, first order: ``2 D(128) - D(64)``) is what is left of the
    modelling: qchain's constant-curvature segments (second order in 1/n: -0.35 % of the
    force at n = 16 in tests/test_contact_physics.py's scene) and PyElastica's second-order
    error, shear (G = 10 E) and stretch.

    Measured 2026-12-04 (k 1e7 N/m^2, penetrations 0.6-5 um): total contact force
    qchain 0.075876 / PyElastica 0.069853 N at 64 elements (+8.6 %), 0.076295 / 0.073541 N
    at 128 (+3.7 %): the difference falls by 2.19, and extrapolates to -0.7 % of the force;
    the backbones at equal arclength differ by 70.6 and 30.5 um at most (ratio 2.3),
    extrapolated 9.8 um (0.08 % of the 12 mm sag). PyElastica's lone tip element carries
    4.00001 and 3.99998 times ``k ds d``: its response force adds 3/4 of the load to the
    spring's 1/4 (the last element takes ``F_{N-1} / 2 + F_N`` from its nodes; ``d`` with the
    element's own radius, which PyElastica shrinks as it stretches: with the nominal radius
    the ratio reads 4.05).

    Each code also matches the Kirchhoff rod (``_propped_kirchhoff``) that discretises the
    support as it does: qchain 0.35 % and 0.34 % below the rod clamped at 0 on its ball's
    spring (0.076139 and 0.076555 N; the segments' error), PyElastica 0.05 % and 0.07 % above
    the rod clamped at ``ds / 2`` on ``4 k ds`` (0.069817 and 0.073487 N): the difference
    between the codes is PyElastica's clamp, as stated."""
    force, shape, points = {}, {}, {}
    for n_elem, dt, T in ((64, 1e-5, 0.6), (128, 5e-6, 0.7)):
        x, speed, f_pe, clamp, mass, d_pe = _pyelastica_cantilever(n_elem, dt, T)
        bb, speed_q, c = _qchain_cantilever(n_elem // N_SEG)
        assert speed < 1e-6 and speed_q < 1e-9  # both settled
        # PyElastica: only the last element touches (its two nodes take the force), and the
        # contact carries what the clamp does not (the rod is at rest)
        assert np.array_equal(np.nonzero(np.abs(f_pe).sum(axis=1))[0], [n_elem - 1, n_elem])
        W, F_pe = mass * G, f_pe[:, 2].sum()
        assert abs(W - clamp[2] - F_pe) < 1e-4 * F_pe
        np.testing.assert_allclose(f_pe[:, :2], 0.0, atol=1e-12)  # frictionless
        # its lone element's spring carries a quarter of the load (the response force the rest)
        assert F_pe / (K_QCHAIN * (L / n_elem) * d_pe) == pytest.approx(4.0, abs=1e-3)
        # qchain: only the last ball, at the same arclength, touches, and pushes straight up
        nodes = n_elem // N_SEG
        assert np.array_equal(c.segment, [N_SEG - 1]) and c.alpha[0] == pytest.approx(1 - 0.5 / nodes)
        np.testing.assert_allclose(c.force[:, :2], 0.0, atol=1e-12)
        F_q = c.force[0, 2]
        assert F_q == pytest.approx(K_QCHAIN * (L / n_elem) * c.penetration[0], rel=1e-12)  # exponent 1
        # each against the Kirchhoff rod as it discretises the support: qchain's clamped at 0 on
        # its ball's spring; PyElastica's clamped at ds / 2 on its element's 4 k ds
        ds = L / n_elem
        assert -0.006 < F_q / _propped_kirchhoff(0.0, L - ds / 2, K_QCHAIN * ds) - 1 < 0
        assert abs(F_pe / _propped_kirchhoff(ds / 2, L - ds / 2, 4 * K_QCHAIN * ds) - 1) < 0.002
        force[n_elem] = (F_q - F_pe, F_pe)
        points[n_elem] = x[:: n_elem // 64] - bb[:: n_elem // 64]  # at the 65 arclengths both have
        shape[n_elem] = np.linalg.norm(points[n_elem], axis=1).max()
    (d64, F64), (d128, F128) = force[64], force[128]
    # PyElastica's too-stiff clamp: qchain's rod needs more support, less so as ds halves
    assert 0.05 < d64 / F64 < 0.12 and 0.02 < d128 / F128 < 0.06
    assert 1.7 < d64 / d128 < 2.7 and 1.7 < shape[64] / shape[128] < 2.7  # first order in ds
    # what is left at ds -> 0: a fraction of a percent and ~10 um
    assert abs(2 * d128 - d64) < 0.015 * F128
    assert np.linalg.norm(2 * points[128] - points[64], axis=1).max() < 2e-5


@pytest.mark.slow
def test_pyelastica_rests_a_flat_rod_anywhere_within_its_surface_tolerance():
    """What the comparison's docs say of PyElastica's wall response, measured: under a uniform
    load the response cancels the whole weight, so a straight rod lying flat rests without
    penetrating, at any height within ``surface_tol`` (0.1 mm) of the plane; dropped from
    0.2 mm, it stops as it enters that band (measured 2026-12-04: at rest 50 um above the
    plane; from 0.2 mm, at 97.6 um). qchain's law has no such band: a flat rod sinks by the
    law's ``(w / k)^(1/e)`` (tests/test_contact_physics.py, test (1)), and one 50 um above
    the ground feels no force."""
    ea = pytest.importorskip("elastica")

    class Sim(ea.BaseSystemCollection, ea.Forcing, ea.Damping, ea.Contact):
        pass

    rest = {}
    for h in (5e-5, 2e-4):  # m: the rod's surface above the plane at the start
        sim, n_elem, dt = Sim(), 20, 1e-5
        rod = ea.CosseratRod.straight_rod(n_elem, np.array([0.0, 0.0, R + h]), np.array([1.0, 0.0, 0.0]),
                                          np.array([0.0, 0.0, 1.0]), L, R, RHO, youngs_modulus=E,
                                          shear_modulus=10 * E)
        plane = ea.Plane(plane_origin=np.zeros(3), plane_normal=np.array([0.0, 0.0, 1.0]))
        sim.append(rod)
        sim.append(plane)
        sim.add_forcing_to(rod).using(ea.GravityForces, acc_gravity=np.array([0.0, 0.0, -G]))
        sim.detect_contact_between(rod, plane).using(ea.RodPlaneContact, k=K_QCHAIN * L / n_elem, nu=0.0)
        sim.dampen(rod).using(ea.AnalyticalLinearDamper, uniform_damping_constant=60.0, time_step=dt)
        sim.finalize()
        stepper, t = ea.PositionVerlet(), np.float64(0.0)
        for _ in range(round(0.2 / dt)):
            t = stepper.step(sim, t, np.float64(dt))
        assert np.abs(rod.velocity_collection).max() < 1e-5  # at rest
        gap = rod.position_collection[2] - R
        assert np.ptp(gap) < 1e-9  # flat
        rest[h] = gap.mean()
    assert rest[5e-5] == pytest.approx(5e-5, abs=1e-9)  # hovering where it was put
    assert 0 < rest[2e-4] <= 1e-4  # fell into the band and stopped there, above the plane
