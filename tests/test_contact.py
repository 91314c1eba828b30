"""Contact and point loads (qchain.contact): the obstacles' signed distances against
independent geometry, the generalised forces against the virtual work of the forces, the law
against its formula, the engine against scipy's steppers, and every bad input refused where
it enters."""

import numpy as np
import pinocchio as pin
import pytest

import qchain
from qchain import Chain, Segment
from qchain.contact import Box, Capsule, ContactLaw, Cylinder, Environment, HalfSpace, PointLoad, Sphere
from qchain.contact import hunt_crossley_damping
from qchain.contact.distance import signed_distance
from support import SEGMENT

RNG = np.random.default_rng(7)


def _bent_arm(n=3, base="fixed", seed=1):
    ch = Chain([Segment(**SEGMENT) for _ in range(n)], base=base)
    rng = np.random.default_rng(seed)
    q = ch.neutral()
    for j in range(n):
        q[ch.q_slice(j)] = [0.1, *rng.uniform(-8, 8, 2)]
    return ch, q, rng.normal(size=ch.nv)


def _rotation(seed):
    return pin.rpy.rpyToMatrix(*np.random.default_rng(seed).uniform(-3, 3, 3))


SHAPES = [
    HalfSpace([0.1, -0.2, 0.3], [1.0, 2.0, -0.5]),
    Sphere([0.1, 0.0, -0.1], 0.2),
    Capsule([0.0, 0.0, 0.0], [0.3, -0.1, 0.2], 0.05),
    Cylinder([0.0, 0.1, 0.0], [0.1, -0.2, 0.3], 0.08),
    Box([0.05, 0.0, 0.1], [0.1, 0.2, 0.05], _rotation(3)),
]


def _surface_residual(ob, y) -> float:
    """How far the point ``y`` is from ``ob``'s surface, by each shape's own definition."""
    if isinstance(ob, HalfSpace):
        return abs((y - ob.point) @ ob.normal)
    if isinstance(ob, Sphere):
        return abs(np.linalg.norm(y - ob.center) - ob.radius)
    if isinstance(ob, (Capsule, Cylinder)):
        u = ob.b - ob.a
        L = np.linalg.norm(u)
        u = u / L
        s = (y - ob.a) @ u
        rho = np.linalg.norm((y - ob.a) - s * u)
        if isinstance(ob, Capsule):
            t = np.clip(s, 0, L)
            return abs(np.linalg.norm(y - (ob.a + t * u)) - ob.radius)
        # on the side (rho = R, 0 <= s <= L) or on a cap (s = 0 or L, rho <= R)
        side = abs(rho - ob.radius) + max(0.0, -s) + max(0.0, s - L)
        cap = min(abs(s), abs(s - L)) + max(0.0, rho - ob.radius)
        return min(side, cap)
    yl = ob.rotation.T @ (y - ob.center)
    over = np.maximum(np.abs(yl) - ob.half_extents, 0.0)
    on_face = np.min(np.abs(np.abs(yl) - ob.half_extents))
    return np.linalg.norm(over) + on_face


@pytest.mark.parametrize("ob", SHAPES, ids=lambda o: type(o).__name__)
def test_signed_distance_projects_onto_the_surface_with_a_unit_gradient(ob):
    kind, prm = ob.row()
    n = np.empty(3)
    checked = 0
    for x in RNG.uniform(-0.5, 0.5, (300, 3)):
        phi = signed_distance(kind, prm, x, n)
        assert abs(np.linalg.norm(n) - 1.0) < 1e-12
        # the nearest surface point is x - phi n, and it lies on the surface
        assert _surface_residual(ob, x - phi * n) < 1e-10
        # the normal is the gradient (central differences, away from kinks)
        h = 1e-7
        g = np.array([(signed_distance(kind, prm, x + h * e, np.empty(3))
                       - signed_distance(kind, prm, x - h * e, np.empty(3))) / (2 * h) for e in np.eye(3)])
        if np.linalg.norm(g - n) < 1e-5:
            checked += 1
    assert checked > 250  # the gradient is the normal almost everywhere (the medial set is thin)


@pytest.mark.parametrize("ob", SHAPES[1:], ids=lambda o: type(o).__name__)
def test_signed_distance_outside_is_the_distance_to_dense_surface_samples(ob):
    # an independent nearest point: the closest of many points of the surface, found by
    # projecting random points onto it with the shape's own residual as the judge
    kind, prm = ob.row()
    n = np.empty(3)
    pts = RNG.uniform(-0.6, 0.6, (20000, 3))
    surf = []
    for y in pts:
        phi = signed_distance(kind, prm, y, n)
        s = y - phi * n
        if _surface_residual(ob, s) < 1e-10:
            surf.append(s)
    surf = np.array(surf)
    for x in RNG.uniform(-0.6, 0.6, (40, 3)):
        phi = signed_distance(kind, prm, x, n)
        if phi <= 0:
            continue
        nearest = np.min(np.linalg.norm(surf - x, axis=1))
        assert phi <= nearest + 1e-12  # no surface point nearer than phi ...
        assert nearest - phi < 0.02  # ... and the samples come close to it


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_a_point_load_is_its_virtual_work(base):
    ch, q, v = _bent_arm(base=base)
    F, Mo = np.array([0.3, -0.2, 0.5]), np.array([0.01, 0.02, -0.03])
    for local in (False, True):
        tau = ch.environment_force(q, v, Environment(loads=[PointLoad(1, 0.5, force=F, moment=Mo, local=local)]))
        fr = ch.frames(q, points_per_segment=3)
        h = 1e-6
        work = np.empty(ch.nv)
        R = _slice_rotation(ch, q, 1, 0.5)
        Fw, Mw = (R @ F, R @ Mo) if local else (F, Mo)
        for i in range(ch.nv):
            dq = np.zeros(ch.nv)
            dq[i] = h
            qp, qm = ch.integrate(q, dq), ch.integrate(q, -dq)
            dx = (ch.backbone(qp, 3)[1, 1] - ch.backbone(qm, 3)[1, 1]) / (2 * h)
            dR = (_slice_rotation(ch, qp, 1, 0.5) - _slice_rotation(ch, qm, 1, 0.5)) / (2 * h)
            w = dR @ R.T  # [omega]x of the rotation's rate
            work[i] = Fw @ dx + Mw @ np.array([w[2, 1], w[0, 2], w[1, 0]])
        assert fr is not None
        np.testing.assert_allclose(tau, work, rtol=0, atol=1e-8 * np.abs(work).max())


def _slice_rotation(ch, q, j, alpha):
    """World rotation of slice ``alpha`` of segment ``j``, from the root placement and the arc."""
    from qchain.model.arc import arc_nodes

    X = ch.placements(q)[j]
    node = arc_nodes(np.array([alpha]), np.asarray(q[ch.q_slice(j)], dtype=float))
    return X.rotation @ node.R[0]


def test_contact_forces_are_point_loads_at_the_contacts_and_follow_the_law():
    ch, q, v = _bent_arm()
    B = ch.backbone(q, 11)
    c = B[1, 5]
    law = ContactLaw(stiffness=2e5, exponent=1.5, damping=2.0, mu_static=0.6, mu_dynamic=0.4,
                     slip_velocity=1e-3, stribeck_velocity=1e-2)
    r_s = SEGMENT["radius"]
    for ob in [Sphere(c + [0.03, 0, 0], 0.02), HalfSpace(c + [0, 0, 0.01], [0, 0, -1]),
               Capsule(c + [0.02, -0.1, 0], c + [0.02, 0.1, 0], 0.01), Cylinder(c + [0, -0.1, 0.02], c + [0, 0.1, 0.02], 0.01),
               Box(c + [0, 0, -0.03], [0.2, 0.2, 0.02])]:
        env = Environment([ob], law, nodes=8)
        C = ch.contacts(q, v, env)
        assert len(C.segment) > 0
        loads = []
        for k in range(len(C.segment)):
            xb = C.point[k] + r_s * C.normal[k]  # the backbone point behind the contact point
            loads.append(PointLoad(int(C.segment[k]), float(C.alpha[k]), force=C.force[k],
                                   moment=np.cross(C.point[k] - xb, C.force[k])))
            # the law, from the record's penetration, normal and the surface point's velocity
            kind, prm = ob.row()
            nrm = np.empty(3)
            d = r_s - signed_distance(kind, prm, xb, nrm)
            assert d == pytest.approx(C.penetration[k], abs=1e-15)
            np.testing.assert_allclose(nrm, C.normal[k], atol=1e-15)
        tl = ch.environment_force(q, v, Environment(loads=loads))
        np.testing.assert_allclose(C.tau, tl, rtol=0, atol=1e-12 * np.abs(tl).max())
        ell = SEGMENT["length"] / 8
        fn = C.force @ np.array(C.normal.T).T if False else np.einsum("ij,ij->i", C.force, C.normal)
        assert np.all(fn >= 0)
        # without damping and friction, each normal force is l k d^e exactly
        C0 = ch.contacts(q, v, Environment([ob], ContactLaw(stiffness=2e5, exponent=1.5), nodes=8))
        np.testing.assert_allclose(np.linalg.norm(C0.force, axis=1), ell * 2e5 * C0.penetration ** 1.5, rtol=1e-13)
        # friction opposes sliding and is at most mu_static times the normal force
        ft = C.force - fn[:, None] * C.normal
        assert np.all(np.linalg.norm(ft, axis=1) <= 0.6 * fn + 1e-15)


def test_a_far_obstacle_changes_nothing():
    ch, q, v = _bent_arm()
    p = np.full(ch.nu, 1e4)
    env = Environment([Sphere([5.0, 5.0, 5.0], 0.5), HalfSpace([0, 0, -3.0])])
    assert len(ch.contacts(q, v, env).segment) == 0
    np.testing.assert_array_equal(ch.forward_dynamics(q, v, p, env=env), ch.forward_dynamics(q, v, p))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_planar_contact_pass_is_the_spatial_one_in_the_plane(seed):
    """A planar chain among obstacles symmetric about its base's x-z plane (the base turned
    and raised in the world; friction, damping, an obstacle moving in the plane): the planar
    pass's generalised forces, base wrench and count equal the spatial pass's in-plane ones."""
    from qchain.contact.distance import move
    from qchain.contact.forces import RECORD, contact_forces
    from qchain.contact.planar import planar_contact_forces
    from qchain.contact.shapes import Motion
    from qchain.model.arc import SCRATCH

    rng = np.random.default_rng(seed)
    X = pin.SE3(pin.rpy.rpyToMatrix(0.3, -0.4, 0.7), np.array([0.1, -0.2, 0.3]))
    ch = Chain([Segment(**SEGMENT) for _ in range(3)], base_placement=X, planar=True)
    q = ch.neutral()
    q[1::3] += rng.uniform(-12, 12, 3)  # ux: bent in the plane
    v = np.zeros(ch.nv)
    v[0::3] = rng.normal(0, 0.05, 3)
    v[1::3] = rng.normal(0, 2.0, 3)
    st = ch._state(q, v)
    ex, ez, o = X.rotation[:, 0], X.rotation[:, 2], X.translation
    pts = ch.backbone(q, 9)  # (n, 9, 3) world points of the backbone
    pick = lambda j, k: pts[j, k]
    nrm = np.cos(0.3) * ex + np.sin(0.3) * ez
    env = Environment([HalfSpace(pick(2, 4) - 0.01 * nrm, nrm),
                       Sphere(pick(1, 3) + 0.02 * ex, 0.01),
                       Capsule(pick(0, 6) - 0.03 * ez - 0.2 * X.rotation[:, 1], pick(0, 6) - 0.03 * ez
                               + 0.2 * X.rotation[:, 1], 0.02, motion=Motion(velocity=0.1 * ex)),
                       Box(pick(2, 8), [0.02, 0.05, 0.02], rotation=X.rotation)],
                      ContactLaw(damping=2.0, mu_static=0.5, mu_dynamic=0.3), nodes=7)
    pk = env.packed()
    prm, vel = np.empty_like(pk.prm), np.empty((pk.kind.size, 3))
    move(pk.kind, pk.prm, pk.motion, 0.2, prm, vel)
    args = (ch._arrays, pk.kind, prm, vel, pk.law, pk.calpha, st.q_c, np.ascontiguousarray(st.v_c),
            np.ascontiguousarray(st.X_WB.rotation), np.ascontiguousarray(st.X_WB.translation),
            np.ascontiguousarray(st.V0))
    tau, F0 = np.zeros((ch.n, 3)), np.zeros(6)
    count = contact_forces(*args, tau, F0, np.zeros((ch.n + 1, 6)), np.zeros((0, 34)), np.zeros((2, 0, 123)),
                           np.zeros((0, RECORD)), np.empty(SCRATCH))
    tau_p, F0_p = np.zeros((ch.n, 3)), np.zeros(6)
    count_p = planar_contact_forces(*args, tau_p, F0_p, np.zeros((ch.n + 1, 6)), np.empty(SCRATCH))
    assert count_p == count >= 4
    scale = np.abs(tau[:, :2]).max()
    np.testing.assert_allclose(tau_p[:, :2], tau[:, :2], rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(F0_p[[0, 2, 4]], F0[[0, 2, 4]], rtol=0, atol=1e-12 * np.abs(F0).max())
    assert np.abs(tau[:, 2]).max() < 1e-12 * scale  # the spatial pass agrees that nothing leaves the plane


def test_forward_and_inverse_dynamics_take_the_environment():
    ch, q, v = _bent_arm()
    c = ch.backbone(q, 11)[2, 5]
    env = Environment([Sphere(c + [0.025, 0, 0], 0.02)], ContactLaw(damping=1.0, mu_static=0.3, mu_dynamic=0.2),
                      loads=[PointLoad(2, 1.0, force=[0, 0, -0.5])])
    p = np.full(ch.nu, 2e4)
    te = ch.environment_force(q, v, env)
    assert np.abs(te).max() > 0
    a = ch.forward_dynamics(q, v, p, env=env)
    np.testing.assert_allclose(a, ch.forward_dynamics(q, v, p, tau=te), rtol=0, atol=1e-12)
    # inverse dynamics: M a + C v + g - tau_env equals the arm's own forces at that acceleration
    lhs = ch.inverse_dynamics(q, v, a, env=env)
    np.testing.assert_allclose(lhs, ch.internal_forces(q, v, p), rtol=0, atol=1e-9 * np.abs(lhs).max())


def _falling_onto_the_ground(base):
    """Two segments held out sideways 5 cm above the ground, a tip load pressing down."""
    X = pin.SE3(pin.rpy.rpyToMatrix(np.pi / 2, 0, 0), np.array([0, 0, 0.05]))
    ch = Chain([Segment(**SEGMENT) for _ in range(2)], base=base, **({"base_placement": X} if base == "fixed" else {}))
    q0 = ch.neutral()
    if base == "floating":
        q0[:7] = pin.SE3ToXYZQUAT(X)
    env = Environment([HalfSpace()], ContactLaw(stiffness=1e5, damping=2.0, mu_static=0.5, mu_dynamic=0.4),
                      loads=[PointLoad(1, 1.0, force=[0.0, 0.0, -0.05])])
    return ch, q0, env


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_the_engine_runs_contact_as_scipy_does(base):
    ch, q0, env = _falling_onto_the_ground(base)
    kw = dict(env=env, rtol=1e-8, atol=1e-10, t_eval=np.linspace(0, 0.1, 3))
    a = qchain.simulate(ch, q0, np.zeros(ch.nv), (0, 0.1), method="dopri5", **kw)
    b = qchain.simulate(ch, q0, np.zeros(ch.nv), (0, 0.1), method="RK45", **kw)
    assert a.success and b.success and a.meta["engine"] != "python" and b.meta["engine"] == "python"
    assert len(ch.contacts(a.q[-1], a.v[-1], env).segment) > 0
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-6)


# -- bad input, refused where it enters, naming the parameter, the value and the bound

@pytest.mark.parametrize("make, words", [
    (lambda: ContactLaw(stiffness=-1.0), "ContactLaw.stiffness must be > 0"),
    (lambda: ContactLaw(exponent=0.5), "ContactLaw.exponent must be >= 1"),
    (lambda: ContactLaw(damping=-0.1), "ContactLaw.damping must be >= 0"),
    (lambda: ContactLaw(mu_static=-0.2), "ContactLaw.mu_static must be >= 0"),
    (lambda: ContactLaw(mu_static=0.2, mu_dynamic=0.5), "ContactLaw.mu_dynamic must be <= mu_static = 0.2, got 0.5"),
    (lambda: ContactLaw(slip_velocity=0.0), "ContactLaw.slip_velocity must be > 0"),
    (lambda: ContactLaw(stiffness=float("nan")), "ContactLaw.stiffness"),
    (lambda: HalfSpace(normal=[0, 0, 0]), "HalfSpace.normal must be a nonzero direction"),
    (lambda: Sphere([0, 0, 0], -1.0), "Sphere.radius must be > 0"),
    (lambda: Sphere([0, 0, np.inf], 1.0), "Sphere.center"),
    (lambda: Capsule([0, 0, 0], [0, 0, 0], 0.1), "Capsule: the axis end points a and b must differ"),
    (lambda: Cylinder([0, 0, 0], [0, 0, 1], 0.0), "Cylinder.radius must be > 0"),
    (lambda: Box([0, 0, 0], [0.1, -0.1, 0.1]), "Box.half_extents[1] must be > 0"),
    (lambda: Box([0, 0, 0], [0.1, 0.1, 0.1], 2 * np.eye(3)), "Box.rotation must be a rotation matrix"),
    (lambda: Environment(["ground"]), "Environment.obstacles[0] must be a HalfSpace"),
    (lambda: Environment(nodes=0), "Environment.nodes must be an integer >= 1"),
    (lambda: Environment(loads=[3]), "Environment.loads[0] must be a PointLoad"),
    (lambda: PointLoad(0, 1.5), "PointLoad.alpha must be >= 0 and <= 1, got 1.5"),
    (lambda: PointLoad(-1, 0.5), "PointLoad.segment must be a segment index >= 0, got -1"),
    (lambda: PointLoad(0, 0.5, force=[1, 2]), "PointLoad.force must have shape (3,)"),
    (lambda: hunt_crossley_damping(0.0, 1.0), "restitution must be > 0"),
    (lambda: hunt_crossley_damping(0.5, -1.0), "impact_speed must be > 0"),
])
def test_bad_contact_input_is_refused_by_name(make, words):
    with pytest.raises((TypeError, ValueError)) as err:
        make()
    assert words in str(err.value)


def test_an_environment_that_does_not_fit_the_run_is_refused():
    ch, q, v = _bent_arm(n=2)
    with pytest.raises(ValueError, match=r"Environment.loads\[0\].segment must be < 2 \(the chain's segments\), got 5"):
        ch.environment_force(q, v, Environment(loads=[PointLoad(5, 0.5)]))
    with pytest.raises(TypeError, match="env must be a qchain.contact.Environment, got list"):
        ch.forward_dynamics(q, v, env=[HalfSpace()])
    with pytest.raises(TypeError, match="env must be a qchain.contact.Environment, got str"):
        qchain.simulate(ch, q, v, (0, 0.01), method="dopri5", env="ground")


def test_hunt_crossley_damping_is_the_flores_coefficient():
    assert hunt_crossley_damping(0.8, 2.0) == pytest.approx(8 * 0.2 / (5 * 0.8 * 2.0), rel=1e-15)
    assert hunt_crossley_damping(1.0, 1.0) == 0.0


def _contact_scene(base):
    ch, q, v = _bent_arm(base=base)
    if base == "floating":
        q[:7] = pin.SE3ToXYZQUAT(pin.SE3(pin.rpy.rpyToMatrix(0.3, -0.2, 0.5), np.array([0.01, 0.02, -0.03])))
    c = ch.backbone(q, 11)[1, 5]
    law = ContactLaw(stiffness=2e5, damping=2.0, mu_static=0.6, mu_dynamic=0.4, slip_velocity=0.05,
                     stribeck_velocity=0.2)
    loads = [PointLoad(1, 0.3, [0.1, 0.2, 0.3], [0.01, 0, 0.02]), PointLoad(2, 1.0, [0, 0, -1], local=True)]
    obstacles = [HalfSpace(c + [0, 0, 0.01], [0.2, 0.1, -1]), Sphere(c + [0.03, 0, 0], 0.02),
                 Capsule(c + [0.02, -0.1, 0], c + [0.02, 0.1, 0], 0.01), Cylinder(c + [0, -0.1, 0.02], c + [0, 0.1, 0.02], 0.01),
                 Box(c + [0, 0, -0.03], [0.2, 0.2, 0.02], pin.rpy.rpyToMatrix(0.1, 0.2, 0.3))]
    return ch, q, v, law, loads, obstacles


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_environment_derivatives_match_central_differences(base):
    ch, q, v, law, loads, obstacles = _contact_scene(base)
    h = 1e-7
    for ob in obstacles:
        env = Environment([ob], law, loads=loads, nodes=8)
        assert len(ch.contacts(q, v, env).segment) > 0
        dq, dv = ch.environment_force_derivatives(q, v, env)
        Fq, Fv = np.empty_like(dq), np.empty_like(dv)
        for i in range(ch.nv):
            e = np.zeros(ch.nv)
            e[i] = h
            Fq[:, i] = (ch.environment_force(ch.integrate(q, e), v, env)
                        - ch.environment_force(ch.integrate(q, -e), v, env)) / (2 * h)
            Fv[:, i] = (ch.environment_force(q, v + e, env) - ch.environment_force(q, v - e, env)) / (2 * h)
        # central differences of h = 1e-7 carry about 1e-9 relative error
        np.testing.assert_allclose(dq, Fq, rtol=0, atol=1e-8 * np.abs(Fq).max())
        np.testing.assert_allclose(dv, Fv, rtol=0, atol=1e-8 * max(np.abs(Fv).max(), 1.0))


def test_forward_dynamics_derivatives_include_the_environment():
    ch, q, v, law, loads, obstacles = _contact_scene("floating")
    env = Environment([obstacles[0]], law, loads=loads, nodes=8)
    p = np.full(ch.nu, 1e4)
    d = ch.forward_dynamics_derivatives(q, v, p, env=env)
    np.testing.assert_allclose(d.a, ch.forward_dynamics(q, v, p, env=env), rtol=0, atol=1e-12 * np.abs(d.a).max())

    def fd(f, h):  # fourth-order central differences: the stiff contact's higher derivatives are large
        return (8 * (f(h) - f(-h)) - (f(2 * h) - f(-2 * h))) / (12 * h)

    # steps where truncation and round-off meet (about 1e-10 of the largest entry)
    for i in range(ch.nv):
        e = np.eye(ch.nv)[i]
        fq = fd(lambda s: ch.forward_dynamics(ch.integrate(q, s * e), v, p, env=env), 1e-5)
        fv = fd(lambda s: ch.forward_dynamics(q, v + s * e, p, env=env), 1e-4)
        np.testing.assert_allclose(d.da_dq[:, i], fq, rtol=0, atol=1e-8 * np.abs(d.da_dq).max())
        np.testing.assert_allclose(d.da_dv[:, i], fv, rtol=0, atol=1e-8 * np.abs(d.da_dv).max())


def test_environment_derivatives_refuse_paper_coordinates():
    ch = Chain([Segment(**SEGMENT, coords="paper")])
    q = np.array([0.1, 0.3, 5.0])
    with pytest.raises(ValueError, match="environment_force_derivatives needs every segment in curvature coordinates"):
        ch.environment_force_derivatives(q, np.zeros(3), Environment([HalfSpace()]))


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_implicit_methods_run_contact_with_its_exact_jacobian(base):
    ch, q0, env = _falling_onto_the_ground(base)
    ref = qchain.simulate(ch, q0, np.zeros(ch.nv), (0, 0.1), method="dopri5", env=env, rtol=1e-9, atol=1e-11,
                          t_eval=[0.1])
    r5 = qchain.simulate(ch, q0, np.zeros(ch.nv), (0, 0.1), method="radau5", env=env, rtol=1e-7, atol=1e-9,
                         t_eval=[0.1])
    mp = qchain.simulate(ch, q0, np.zeros(ch.nv), (0, 0.1), method="midpoint", env=env, dt=5e-5, t_eval=[0.1])
    assert r5.success and mp.success and r5.meta["njev"] > 0
    np.testing.assert_allclose(r5.q[-1], ref.q[-1], rtol=0, atol=1e-5)
    np.testing.assert_allclose(mp.q[-1], ref.q[-1], rtol=0, atol=1e-3)


def _contact_energy(ch, q, env):
    """``U_c = sum l k d^(e+1) / (e+1)`` over the active contacts: the potential of the
    frictionless, undamped law (computed from the penetrations, not from the forces)."""
    law = env.law
    C = ch.contacts(q, np.zeros(ch.nv), env)
    ell = np.array([s.length for s in ch.segments])[C.segment] / env.nodes
    return float(np.sum(ell * law.stiffness * C.penetration ** (law.exponent + 1) / (law.exponent + 1)))


def test_statics_on_the_ground_is_a_minimum_of_the_total_potential():
    # a cantilever drooping onto the ground: with a frictionless, undamped law the static
    # shape minimises gravity + elastic + contact energy, an independent statement of it
    X = pin.SE3(pin.rpy.rpyToMatrix(np.pi / 2, 0, 0), np.array([0, 0, 0.02]))
    ch = Chain([Segment(**dict(SEGMENT, youngs_modulus=2e4)) for _ in range(2)], base_placement=X)
    env = Environment([HalfSpace()], ContactLaw(stiffness=1e5), nodes=8)
    free = qchain.equilibrium(ch)
    assert free.success and ch.backbone(free.q, 5)[1, -1, 2] < 0  # without the ground it sinks below it
    res = qchain.equilibrium(ch, env=env)
    assert res.success, res.message
    q = res.q
    assert len(ch.contacts(q, np.zeros(ch.nv), env).segment) > 0

    def E(q):
        return ch.potential_energy(q) + _contact_energy(ch, q, env)

    h = 1e-7
    grad = np.array([(E(ch.integrate(q, h * e)) - E(ch.integrate(q, -h * e))) / (2 * h) for e in np.eye(ch.nv)])
    gscale = np.abs(ch.generalized_gravity(q)).max()
    assert np.abs(grad).max() < 1e-6 * gscale
    rng = np.random.default_rng(3)
    for _ in range(20):
        d = rng.normal(size=ch.nv) * np.array([1e-4, 0.1, 0.1] * 2)
        assert E(ch.integrate(q, d)) > E(q)


def test_a_run_says_when_the_contact_time_scale_limits_its_steps():
    X = pin.SE3(pin.rpy.rpyToMatrix(np.pi / 2, 0, 0), np.array([0, 0, 0.05]))
    ch = Chain([Segment(**SEGMENT) for _ in range(2)], base_placement=X)
    env = Environment([HalfSpace()], ContactLaw(stiffness=1e5, exponent=1.0), nodes=8)
    # the period of one contact point (mass m = 0.05 / 8 kg) on its stiffness l k, l = 0.1 / 8 m
    T = env.time_scale(ch)
    assert T == pytest.approx(2 * np.pi * np.sqrt((0.05 / 8) / (0.1 / 8 * 1e5)), rel=1e-12)
    q0 = ch.neutral()
    stiff = qchain.simulate(ch, q0, np.zeros(ch.nv), (0, 0.2), method="dopri5", env=env)
    assert stiff.meta["contact_time_scale"] == T and stiff.meta["step_limited_by_contact"]
    # the engine's count of active contacts covers every sample's, and no more points exist
    seen = max(len(ch.contacts(q, v, env, t).segment) for t, q, v in zip(stiff.t, stiff.q, stiff.v))
    assert seen > 0 and seen <= stiff.meta["max_active_contacts"] <= 2 * 8
    far = Environment([HalfSpace([0, 0, -1.0])], ContactLaw(stiffness=1e5, exponent=1.0), nodes=8)
    free = qchain.simulate(ch, q0, np.zeros(ch.nv), (0, 0.2), method="radau5", env=far)
    assert not free.meta["step_limited_by_contact"] and free.meta["max_active_contacts"] == 0
    assert "contact_time_scale" not in qchain.simulate(ch, q0, np.zeros(ch.nv), (0, 0.01), method="radau5").meta


def test_a_moving_obstacle_is_where_its_motion_puts_it_and_pushes_by_relative_velocity():
    from qchain.contact import Motion

    ch, q, v = _bent_arm()
    c = ch.backbone(q, 11)[1, 5]
    law = ContactLaw(stiffness=2e5, damping=3.0, mu_static=0.5, mu_dynamic=0.4, slip_velocity=0.05)
    mo = Motion(velocity=[0.1, 0.0, -0.2], amplitude=[0.0, 0.01, 0.0], frequency=2.0, phase=0.3)
    t = 0.137
    u = mo.velocity * t + mo.amplitude * np.sin(2 * np.pi * 2.0 * t + 0.3)
    udot = mo.velocity + mo.amplitude * 2 * np.pi * 2.0 * np.cos(2 * np.pi * 2.0 * t + 0.3)
    moving = Environment([Sphere(c + [0.03, 0, 0] - u, 0.02, motion=mo)], law, nodes=8)
    # the same sphere at rest where the motion has carried it, the arm moving by -u' instead:
    # the penetrations agree, and the forces too, the law acting on the relative velocity
    fixed = Environment([Sphere(c + [0.03, 0, 0], 0.02)], law, nodes=8)
    Cm = ch.contacts(q, v, moving, t=t)
    assert len(Cm.segment) > 0
    Cf = ch.contacts(q, v, fixed, t=t)
    np.testing.assert_allclose(Cm.penetration, Cf.penetration, rtol=0, atol=1e-15)
    assert np.abs(Cm.force - Cf.force).max() > 1e-3  # the obstacle's velocity matters ...
    # ... exactly as a world-frame velocity added to every contact point's would
    for k in range(len(Cm.segment)):
        vn = (Cm.force[k] @ Cm.normal[k])
        assert vn >= 0
    dq, dv = ch.environment_force_derivatives(q, v, moving, t=t)
    h = 1e-7
    Fq = np.array([(ch.environment_force(ch.integrate(q, h * e), v, moving, t)
                    - ch.environment_force(ch.integrate(q, -h * e), v, moving, t)) / (2 * h) for e in np.eye(ch.nv)]).T
    np.testing.assert_allclose(dq, Fq, rtol=0, atol=1e-8 * np.abs(Fq).max())
    with pytest.raises(TypeError, match="Sphere.motion must be a qchain.contact.Motion or None, got dict"):
        Sphere([0, 0, 0], 0.1, motion={"velocity": [1, 0, 0]})
    with pytest.raises(ValueError, match="Motion.frequency must be >= 0"):
        Motion(frequency=-1.0)


def test_the_engine_moves_obstacles_as_the_python_path_does():
    from qchain.contact import Motion

    X = pin.SE3(pin.rpy.rpyToMatrix(np.pi / 2, 0, 0), np.array([0, 0, 0.05]))
    ch = Chain([Segment(**SEGMENT) for _ in range(2)], base_placement=X)
    env = Environment([HalfSpace([0, 0, -0.05], motion=Motion(velocity=[0.05, 0, 0.4]))],
                      ContactLaw(stiffness=1e5, damping=2.0, mu_static=0.5, mu_dynamic=0.4))
    kw = dict(env=env, rtol=1e-8, atol=1e-10, t_eval=np.linspace(0, 0.2, 11))
    a = qchain.simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.2), method="radau5", **kw)
    b = qchain.simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.2), method="Radau", **kw)
    touching = [len(ch.contacts(q, v, env, t=t).segment) for t, q, v in zip(a.t, a.q, a.v)]
    assert a.success and b.success and touching[0] == 0 and max(touching) > 0  # the rising ground meets the arm
    np.testing.assert_allclose(a.q, b.q, rtol=0, atol=1e-5)


def _curled(base="floating"):
    """Five short segments bent so that the last touches the first, 3.7 mm deep (a state
    found by a search over random bends)."""
    ch = Chain([Segment(**dict(SEGMENT, length=0.06)) for _ in range(5)], base=base)
    q = ch.neutral()
    rng = np.random.default_rng(415)
    for j in range(5):
        q[ch.q_slice(j)] = [0.06, *rng.uniform(-28, 28, 2)]
    return ch, q, np.random.default_rng(0).normal(size=ch.nv)


def test_self_contact_is_equal_and_opposite_and_its_derivatives_are_exact():
    ch, q, v = _curled()
    env = Environment(law=ContactLaw(stiffness=1e5, damping=1.0, mu_static=0.4, mu_dynamic=0.3, slip_velocity=0.05),
                      self_contact=True, nodes=6)
    C = ch.contacts(q, v, env)
    assert len(C.segment) > 0 and np.all(C.obstacle < 0)
    assert all(-1 - o - s >= 2 for s, o in zip(C.segment, C.obstacle))  # never neighbours
    # internal forces: no net force or moment on the arm (the floating base feels none)
    np.testing.assert_allclose(C.tau[:6], 0.0, atol=1e-12 * np.abs(C.tau).max())
    assert np.abs(C.tau[6:]).max() > 1e-2  # (a 3.7 mm overlap of k = 1e5 balls: about 0.1 N)
    dq, dv = ch.environment_force_derivatives(q, v, env)
    h = 1e-7
    Fq = np.array([(ch.environment_force(ch.integrate(q, h * e), v, env)
                    - ch.environment_force(ch.integrate(q, -h * e), v, env)) / (2 * h) for e in np.eye(ch.nv)]).T
    Fv = np.array([(ch.environment_force(q, v + h * e, env) - ch.environment_force(q, v - h * e, env)) / (2 * h)
                   for e in np.eye(ch.nv)]).T
    np.testing.assert_allclose(dq, Fq, rtol=0, atol=1e-8 * np.abs(Fq).max())
    np.testing.assert_allclose(dv, Fv, rtol=0, atol=1e-8 * np.abs(Fv).max())


def test_a_self_touching_arm_keeps_momentum_and_energy_in_the_engine():
    # frictionless, undamped self-contact in zero gravity: momentum (exactly, internal forces)
    # and energy (to the tolerance) are kept through the collision of the arm with itself
    ch, q0, _ = _curled()
    ch = Chain([Segment(**dict(SEGMENT, length=0.06, damping=0.0)) for _ in range(5)], base="floating",
               gravity=np.zeros(3))
    env = Environment(law=ContactLaw(stiffness=1e5), self_contact=True, nodes=6)
    v0 = np.zeros(ch.nv)
    v0[3:6] = [1.0, -2.0, 0.5]  # spinning, so that momentum is a test
    tr = qchain.simulate(ch, q0, v0, (0, 0.05), method="radau5", env=env, rtol=1e-9, atol=1e-11,
                         t_eval=np.linspace(0, 0.05, 26))
    assert tr.success, tr.message
    assert len(ch.contacts(q0, v0, env).segment) > 0  # it starts pressed into itself
    h = np.array([ch.momentum(q, v) for q, v in zip(tr.q, tr.v)])
    assert np.abs(h - h[0]).max() < 1e-6 * np.abs(h[0]).max()
    E = np.array([ch.kinetic_energy(q, v) + ch.potential_energy(q) + _self_energy(ch, q, env)
                  for q, v in zip(tr.q, tr.v)])
    assert np.abs(E - E[0]).max() < 1e-5 * E[0]


def _self_energy(ch, q, env):
    """The self-contact potential: ``sum l k d^(e+1) / (e+1)`` over the touching pairs."""
    C = ch.contacts(q, np.zeros(ch.nv), env)
    ell = 0.06 / env.nodes  # every segment is 6 cm
    law = env.law
    return float(np.sum(ell * law.stiffness * C.penetration ** (law.exponent + 1) / (law.exponent + 1)))
