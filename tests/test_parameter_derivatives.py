"""Exact parameter derivatives of the dynamics (qchain.arm.parameter_derivatives) against
central differences of chains rebuilt with the perturbed parameter, and against the exact
structure of the model: the accelerations are affine in Young's modulus, damping, chamber area
and gravity, the inverse dynamics linear in the segment masses, and a free-falling floating
base takes gravity whole."""

import dataclasses

import numpy as np
import pinocchio as pin
import pytest

from helpers import SEGMENT_KW
from qchain import Chain, ContactLaw, Environment, Segment, Sphere
from qchain.algorithms import parameter_derivatives as kernels
from qchain.arm.parameter_derivatives import Parameters
from test_chain import make_chain, random_state
from test_derivatives import CASES

TOL = 1e-7  # relative, per column
PER_SEGMENT = ("youngs_modulus", "damping", "mass", "length", "chamber_area")
#: a step per unit of each kind (central differences, relative to the value where it is not 0):
#: the accelerations are affine in E, damping, chamber area and gravity (no truncation error, so
#: a long step keeps the rounding error small), curved in the others
STEP = {"youngs_modulus": 1e-2, "damping": 1e-2, "mass": 1e-5, "length": 1e-6, "chamber_area": 1e-2,
        "gravity": 1e-2, "base_placement": 1e-4}


def all_params(ch):
    out = [(k, j) for j in range(ch.n) for k in PER_SEGMENT] + [("gravity", None)]
    return out + [("base_placement", None)] if ch.base == "fixed" else out


def rebuilt(ch, kind, i, value):
    """``ch`` with parameter ``kind`` (segment or component ``i``) set to ``value``."""
    segs = list(ch.segments)
    gravity = ch.gravity.copy()
    X = ch.base_placement if ch.base == "fixed" else None
    if kind in PER_SEGMENT:
        segs[i] = dataclasses.replace(segs[i], **{kind: value})
    elif kind == "gravity":
        gravity[i] = value
    else:
        delta = np.zeros(6)
        delta[i] = value
        X = X * pin.exp6(pin.Motion(delta))
    return Chain(segs, base=ch.base, gravity=gravity, base_placement=X, base_motion=ch.base_motion,
                 planar=ch.planar, payload=ch.payload)


def differences(ch, P, f, q):
    """Central differences (nv, n_theta) of ``f(chain, q)`` over the parameters ``P``; an
    inextensible segment's held length moves with its rest length."""
    cols = []
    for k, value in enumerate(P.values):
        kind = P.names[k].split()[2] if P.names[k].startswith("segment") else P.names[k].split()[0]
        i = int(P.index[k])
        h = STEP[kind] * (abs(value) if value != 0.0 else 1.0)
        # a damping of 0 has no left neighbour: one-sided there (the accelerations are affine in it)
        xs = (value + h, value - h if kind != "damping" or value > 0.0 else value)
        out = []
        for x in xs:
            c = rebuilt(ch, kind, i, x)
            qs = q.copy()
            if kind == "length" and not ch.segments[i].extensible:
                qs[ch.q_slice(i).start] = x
            out.append(f(c, qs))
        cols.append((out[0] - out[1]) / (xs[0] - xs[1]))
    return np.stack(cols, axis=1)


def assert_columns_close(exact, fd, names, tol=TOL):
    """Each column to ``tol`` relative; a column the parameter does not enter must be zero in both."""
    worst = 0.0
    for k, name in enumerate(names):
        ref = np.linalg.norm(exact[:, k])
        if ref == 0.0:
            assert np.linalg.norm(fd[:, k]) <= 1e-9 * np.abs(fd).max(), name
            continue
        err = np.linalg.norm(fd[:, k] - exact[:, k]) / ref
        worst = max(worst, err)
        assert err < tol, f"{name}: relative error {err:.3g}"
    return worst


@pytest.mark.parametrize("coords", ["curvature", "paper"])
@pytest.mark.parametrize("base", [b for b, _ in CASES])
def test_forward_dynamics_parameter_derivatives_match_rebuilt_chains(coords, base, rng):
    ch = make_chain(coords, base, **dict(CASES)[base])
    q, v = random_state(ch, rng)
    p = rng.uniform(0, 3e4, ch.nu)
    tau = rng.normal(size=ch.nv) * 0.1
    P = ch.parameters(all_params(ch))
    r = ch.forward_dynamics_parameter_derivatives(q, v, p, P, tau=tau, t=0.3)
    np.testing.assert_allclose(r.a, ch.forward_dynamics(q, v, p, tau=tau, t=0.3), rtol=1e-12, atol=1e-12)
    fd = differences(ch, P, lambda c, qs: c.forward_dynamics(qs, v, p, tau=tau, t=0.3), q)
    assert_columns_close(r.da_dtheta, fd, r.names)
    assert r.names == P.names and r.da_dtheta.shape == (ch.nv, len(P))


@pytest.mark.parametrize("coords", ["curvature", "paper"])
@pytest.mark.parametrize("base", [b for b, _ in CASES])
def test_inverse_dynamics_parameter_derivatives_match_rebuilt_chains(coords, base, rng):
    ch = make_chain(coords, base, **dict(CASES)[base])
    q, v = random_state(ch, rng)
    a = rng.normal(size=ch.nv)
    P = ch.parameters(all_params(ch))
    r = ch.inverse_dynamics_parameter_derivatives(q, v, a, P, t=0.3)
    np.testing.assert_allclose(r.tau, ch.inverse_dynamics(q, v, a, t=0.3), rtol=1e-12, atol=1e-12)
    fd = differences(ch, P, lambda c, qs: c.inverse_dynamics(qs, v, a, t=0.3), q)
    assert_columns_close(r.dtau_dtheta, fd, r.names)
    enters = np.array([n.split()[2] == "mass" if n.startswith("segment") else n.startswith("gravity")
                       or "rotation" in n for n in r.names])
    assert np.all(r.dtau_dtheta[:, ~enters] == 0.0)  # E, damping, l0 (free), A_ch: not in M a + C v + g


def _planar_payload_chain(base="fixed"):
    segs = [Segment(**{**SEGMENT_KW, "length": 0.2 - 0.03 * j, "mass": 0.3 - 0.05 * j}, damping=0.02,
                    extensible=j != 1) for j in range(3)]
    payload = pin.Inertia(0.05, np.array([0.01, 0.0, 0.02]), np.diag([1e-4, 2e-4, 1.5e-4]))
    X = pin.SE3(pin.exp3(np.array([0.0, 0.7, 0.0])), np.zeros(3)) if base == "fixed" else None
    return Chain(segs, base=base, planar=True, payload=payload, base_placement=X)


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_planar_inextensible_payload(base, rng):
    """Locked coordinates (uy everywhere, l of segment 1) have zero rows; segment 1's rest length
    is also its held length, and its column follows the arm as both move."""
    ch = _planar_payload_chain(base)
    q, v = random_state(ch, rng)
    for j in range(ch.n):
        sl = ch.q_slice(j)
        q[sl.start + 2] = 0.0
        if not ch.segments[j].extensible:
            q[sl.start] = ch.segments[j].length
    v[ch._voff:][~ch.active[ch._voff:]] = 0.0
    v[~ch.active] = 0.0
    p = rng.uniform(0, 3e4, ch.nu)
    P = ch.parameters(all_params(ch))
    r = ch.forward_dynamics_parameter_derivatives(q, v, p, P)
    assert np.all(r.da_dtheta[~ch.active] == 0.0)
    fd = differences(ch, P, lambda c, qs: c.forward_dynamics(qs, v, p), q)
    assert_columns_close(r.da_dtheta, fd, r.names)
    a = r.a
    ri = ch.inverse_dynamics_parameter_derivatives(q, v, a, P)
    fdi = differences(ch, P, lambda c, qs: c.inverse_dynamics(qs, v, a), q)
    assert_columns_close(ri.dtau_dtheta, fdi, ri.names)


def test_with_contact(rng):
    """Contact forces depend on no parameter but enter through the solved accelerations and,
    for an inextensible segment's rest length, through the configuration."""
    segs = [Segment(**SEGMENT_KW, damping=0.01, extensible=j != 2) for j in range(3)]
    ch = Chain(segs)
    q = ch.neutral()
    q[1::3] = [3.0, -2.0, 4.0]
    q[2::3] = [1.0, 2.0, -1.0]
    v = rng.normal(size=ch.nv) * 0.2
    v[6] = 0.0
    c = ch.backbone(q, 11)[2, 5]
    env = Environment([Sphere(c + [0.025, 0, 0], 0.02)], ContactLaw(damping=1.0))
    assert np.abs(ch.environment_force(q, v, env)).max() > 0
    p = rng.uniform(1e4, 3e4, ch.nu)
    params = [(k, j) for j in range(3) for k in PER_SEGMENT] + [("gravity", None)]
    P = ch.parameters(params)
    r = ch.forward_dynamics_parameter_derivatives(q, v, p, P, env=env)
    np.testing.assert_allclose(r.a, ch.forward_dynamics(q, v, p, env=env), rtol=1e-12, atol=1e-12)
    fd = differences(ch, P, lambda c, qs: c.forward_dynamics(qs, v, p, env=env), q)
    assert_columns_close(r.da_dtheta, fd, r.names)
    a = r.a + rng.normal(size=ch.nv) * 0.1
    a[~ch.active] = 0.0
    ri = ch.inverse_dynamics_parameter_derivatives(q, v, a, P, env=env)
    np.testing.assert_allclose(ri.tau, ch.inverse_dynamics(q, v, a, env=env), rtol=1e-12, atol=1e-12)
    fdi = differences(ch, P, lambda c, qs: c.inverse_dynamics(qs, v, a, env=env), q)
    assert_columns_close(ri.dtau_dtheta, fdi, ri.names)
    for call in (ch.forward_dynamics_parameter_derivatives, ch.inverse_dynamics_parameter_derivatives):
        with pytest.raises(ValueError, match="base_placement derivatives with env are not supported"):
            call(q, v, p, [("base_placement", None)], env=env)


@pytest.mark.parametrize("base", [b for b, _ in CASES])
def test_accelerations_are_affine_in_the_linear_parameters(base, rng):
    """``a(theta + d) - a(theta) = d da/dtheta`` exactly (no difference quotient) for E, damping,
    chamber area and gravity; the inverse dynamics, ``tau(m + d) - tau(m) = d dtau/dm``."""
    ch = make_chain("curvature", base, **dict(CASES)[base])
    q, v = random_state(ch, rng)
    p = rng.uniform(0, 3e4, ch.nu)
    a_ = rng.normal(size=ch.nv)
    for kind, j in [("youngs_modulus", 1), ("damping", 2), ("chamber_area", 0), ("chamber_area", 2)]:
        x = getattr(ch.segments[j], kind)
        d = 0.5 * x
        r = ch.forward_dynamics_parameter_derivatives(q, v, p, [(kind, j)], t=0.2)
        a1 = rebuilt(ch, kind, j, x + d).forward_dynamics(q, v, p, t=0.2)
        np.testing.assert_allclose(a1 - r.a, d * r.da_dtheta[:, 0], rtol=1e-9, atol=1e-9 * np.abs(a1 - r.a).max())
    g = ch.gravity
    r = ch.forward_dynamics_parameter_derivatives(q, v, p, [("gravity", None)], t=0.2)
    a1 = Chain(ch.segments, base=base, gravity=2 * g, **dict(CASES)[base]).forward_dynamics(q, v, p, t=0.2)
    np.testing.assert_allclose(a1 - r.a, r.da_dtheta @ g, rtol=1e-9, atol=1e-9 * np.abs(a1 - r.a).max())
    ri = ch.inverse_dynamics_parameter_derivatives(q, v, a_, [("mass", 0), ("mass", 2)], t=0.2)
    for k, j in enumerate((0, 2)):
        m = ch.segments[j].mass
        t1 = rebuilt(ch, "mass", j, 3 * m).inverse_dynamics(q, v, a_, t=0.2)
        np.testing.assert_allclose(t1 - ri.tau, 2 * m * ri.dtau_dtheta[:, k], rtol=1e-9,
                                   atol=1e-9 * np.abs(t1 - ri.tau).max())


def test_a_floating_base_takes_gravity_whole(rng):
    """``da/dg_world = (R_WB^T, 0)``: gravity changes the base's free fall, nothing else."""
    ch = make_chain("curvature", "floating")
    q, v = random_state(ch, rng)
    r = ch.forward_dynamics_parameter_derivatives(q, v, rng.uniform(0, 3e4, ch.nu), [("gravity", None)])
    R = pin.XYZQUATToSE3(q[:7]).rotation
    expect = np.zeros((ch.nv, 3))
    expect[:3] = R.T
    np.testing.assert_allclose(r.da_dtheta, expect, rtol=0, atol=1e-11)


@pytest.mark.parametrize("base", ["fixed", "floating"])
def test_gravity_columns_are_the_mass_matrix_base_columns(base, rng):
    """``dtau/dg_world = -M_b[:, :3] R_WB^T``, ``M_b`` the base columns of the mass matrix (a
    floating base's own; a fixed base's from the same chain made floating)."""
    ch = make_chain("curvature", base, **dict(CASES)[base])
    q, v = random_state(ch, rng)
    a = rng.normal(size=ch.nv)
    r = ch.inverse_dynamics_parameter_derivatives(q, v, a, [("gravity", None)])
    if base == "floating":
        Mb, R = ch.mass_matrix(q)[:, :3], pin.XYZQUATToSE3(q[:7]).rotation
    else:
        free = Chain(ch.segments, base="floating")
        qf = np.concatenate([[0, 0, 0, 0, 0, 0, 1.0], q])
        Mb, R = free.mass_matrix(qf)[6:, :3], ch.base_placement.rotation
    np.testing.assert_allclose(r.dtau_dtheta, -Mb @ R.T, rtol=1e-12, atol=1e-12 * np.abs(Mb).max())


def test_compiled_first_order_entry(rng):
    """The compiled entry the trajectory sensitivities call writes ``d(v, a)/dtheta`` into a
    preallocated array: zero on top, the checked API's ``da/dtheta`` below."""
    ch = make_chain("curvature", "fixed", **dict(CASES)["fixed"])
    q, v = random_state(ch, rng)
    p = rng.uniform(0, 3e4, ch.nu)
    P = ch.parameters(all_params(ch))
    r = ch.forward_dynamics_parameter_derivatives(q, v, p, P)
    n, nv = ch.n, ch.nv
    ws, wd, wa, wq = kernels.fresh_workspaces(n, nv, len(P))
    dx = np.full((2 * nv, len(P)), np.nan)
    dID = np.empty((nv, len(P)))
    E = np.array([s.youngs_modulus for s in ch.segments])
    status = kernels.first_order_parameter_derivatives(
        ch._arrays, False, q.reshape(n, 3), v.reshape(n, 3), p.reshape(n, 3), np.zeros(nv), np.zeros(6), np.zeros(6),
        ch._g_B, np.ascontiguousarray(ch.base_placement.rotation), E, P.kinds, P.index, tuple(ws), tuple(wd),
        tuple(wa), tuple(wq), ws.scratch, dID, dx)
    assert status == 0
    assert np.all(dx[:nv] == 0.0)
    np.testing.assert_allclose(dx[nv:], r.da_dtheta, rtol=1e-13, atol=1e-13 * np.abs(r.da_dtheta).max())
    data = ch.create_data()  # the checked API in a given workspace: the same numbers
    rd = ch.forward_dynamics_parameter_derivatives(q, v, p, P, data=data)
    np.testing.assert_array_equal(rd.da_dtheta, r.da_dtheta)


def test_parameters_name_their_columns():
    ch = make_chain("curvature", "fixed")
    P = ch.parameters([("youngs_modulus", 0), ("gravity", None), ("base_placement", None)])
    assert P.names[0] == "segment 0 youngs_modulus [Pa]" and P.units[0] == "Pa"
    assert P.names[1:4] == ("gravity x [m/s^2]", "gravity y [m/s^2]", "gravity z [m/s^2]")
    assert P.names[4] == "base_placement translation x [m]" and P.names[-1] == "base_placement rotation z [rad]"
    assert len(P) == 10 and P.values[0] == ch.segments[0].youngs_modulus and P.values[3] == -9.81


@pytest.mark.parametrize("params, error, match", [
    ([("stiffness", 0)], ValueError, r"unknown parameter 'stiffness'; the parameters are \('youngs_modulus'"),
    ([("mass", 3)], ValueError, r"its segment must be an int in \[0, 2\] \(the chain has 3 segments\), got 3"),
    ([("mass", None)], ValueError, "'mass' is per segment"),
    ([("mass", True)], ValueError, "'mass' is per segment"),
    ([("base_placement", 0)], ValueError, "'base_placement' is a whole-arm parameter, its segment must be None, got 0"),
    ([("gravity", 3)], ValueError, r"the axis of 'gravity' must be None \(all three\) or an int in \[0, 2\] \(x, y, z\), got 3"),
    ([("mass", 1), ("mass", 1)], ValueError, r"\('mass', 1\) is named twice"),
    ([], ValueError, "at least one parameter"),
    (["mass"], TypeError, r"params\[0\] must be a \(kind, segment\) pair"),
    ("mass", TypeError, "params must be a list of"),
])
def test_bad_parameters_are_refused_by_name(params, error, match):
    ch = make_chain("curvature", "fixed")
    with pytest.raises(error, match=match):
        ch.parameters(params)


def test_what_the_parameters_do_not_serve(rng):
    floating = make_chain("curvature", "floating")
    with pytest.raises(ValueError, match="'base_placement' is a fixed base's placement; this chain has "
                                         "base='floating'"):
        floating.parameters([("base_placement", None)])
    fixed = make_chain("curvature", "fixed")
    q, v = random_state(fixed, rng)
    with pytest.raises(ValueError, match="params were made for a chain of 3 segments, nv = 9, base='fixed'; this "
                                         "chain has 3, nv = 15, base='floating'"):
        floating.forward_dynamics_parameter_derivatives(q, v, None, fixed.parameters([("mass", 0)]))
    linear = Chain([Segment(**SEGMENT_KW, stiffness_matrix=np.eye(3))])
    with pytest.raises(ValueError, match=r"segments\[0\] has the paper's literal linear law"):
        Parameters(linear, [("mass", 0)])
    with pytest.raises(TypeError, match="chain must be a qchain.Chain"):
        Parameters("arm", [("mass", 0)])
    with pytest.raises(ValueError, match="q"):  # the state is checked where it enters
        fixed.forward_dynamics_parameter_derivatives(np.full(fixed.nq, np.nan), v, None, [("mass", 0)])
