"""``planar_aba`` against ``recursive.aba`` (through ``Chain.forward_dynamics``) on planar chains."""

import numpy as np
import pinocchio as pin
import pytest

from helpers import SEGMENT_KW, rel
from qchain import Chain, Segment
from qchain.algorithms import recursive
from qchain.algorithms.planar import planar_aba, planar_aba_moving, planar_rnea, planar_workspace

NODES = [None, 3, 5, 2, 8]  # per segment, cycled: different node counts in one chain


def planar_chain(n, extensible=True, gravity_angle=0.0, base_angle=0.0, **kw):
    """A ``planar=True`` chain of differing segments; ``extensible`` True, False or a list.
    Gravity points at ``gravity_angle`` (rad, about y from -z) in the base's x-z plane; the
    base is turned by ``base_angle`` about its y axis (so its x-z plane stays vertical)."""
    ext = extensible if isinstance(extensible, list) else [extensible] * n
    segs = [
        Segment(**{**SEGMENT_KW, "length": 0.2 - 0.01 * j, "radius": 0.02 - 0.0005 * j, "mass": 0.3 - 0.02 * j},
                damping=0.01 * (j % 2), nodes=NODES[j % len(NODES)], extensible=ext[j])
        for j in range(n)
    ]
    g = 9.81 * np.array([-np.sin(gravity_angle), 0.0, -np.cos(gravity_angle)])
    if "base" not in kw:
        kw["base_placement"] = pin.SE3(pin.exp3(np.array([0.0, base_angle, 0.0])), np.array([0.1, -0.2, 0.3]))
    return Chain(segs, gravity=g, planar=True, **kw)


def planar_state(ch, rng, straight=None):
    """q, v (planar: uy = 0, uy_dot = 0; locked l at l0), bent both ways, and pressures p;
    ``straight`` ({segment: ux}) sets nearly or exactly straight segments."""
    straight = straight or {}
    q = ch.neutral()
    v = np.zeros(ch.nv)
    for j, s in enumerate(ch.segments):
        sl, vs = ch.q_slice(j), ch.v_slice(j)
        l = s.length * (rng.uniform(0.9, 1.1) if s.extensible else 1.0)
        ux = rng.uniform(2.0, 12.0) * (-1) ** j
        ux = straight.get(j, ux)
        q[sl] = [l, ux, 0.0]
        v[vs] = [0.05 * rng.normal() if s.extensible else 0.0, 3.0 * rng.normal(), 0.0]
    p = rng.uniform(0.0, 5e4, ch.nu)
    return q, v, p


def call_planar(ch, q, v, p, tau, V0=None):
    """``planar_aba`` on the chain's arrays and forces: qdd (n, 3)."""
    n = ch.n
    f = (ch.internal_forces(q, v, p) + tau).reshape(n, 3)
    q_c = np.ascontiguousarray(q.reshape(n, 3))
    v_c = np.ascontiguousarray(v.reshape(n, 3))
    A0 = np.zeros(6)
    A0[:3] = -ch._g_B
    ws = planar_workspace(n)
    qdd = np.full((n, 3), np.nan)
    args = (ch.kernel_arrays(), q_c, v_c, f)
    if V0 is None:
        ok = planar_aba(*args, A0, qdd, ws, ws[-1])
    else:
        ok = planar_aba_moving(*args, V0, A0, qdd, ws, ws[-1])
    assert ok
    return qdd


@pytest.mark.parametrize("n", [1, 3, 10])
@pytest.mark.parametrize("extensible", [True, False], ids=["extensible", "inextensible"])
def test_planar_aba_equals_aba(n, extensible, rng):
    for trial, (ga, ba) in enumerate([(0.0, 0.0), (0.9, -0.4), (np.pi, 1.3), (-2.2, 2.9)]):
        ch = planar_chain(n, extensible, gravity_angle=ga, base_angle=ba)
        straight = [{}, {0: 0.0, 2: 1e-12, 7: -1e-12}, {}, {0: 1e-12, 1: 0.0, 5: 0.0}][trial]
        q, v, p = planar_state(ch, rng, straight)
        tau = rng.normal(size=ch.nv) * ch.active
        a = ch.forward_dynamics(q, v, p, tau)  # recursive.aba
        qdd = call_planar(ch, q, v, p, tau)
        assert np.all(qdd[:, 2] == 0.0)
        assert np.all(qdd[ch._locked] == 0.0)
        assert rel(qdd.ravel(), a) < 1e-12, (trial, rel(qdd.ravel(), a))


def test_straight_segments_exactly_and_nearly(rng):
    """ux = 0 and ux = 1e-12 in every segment, at rest and moving, with and without gravity."""
    for ux in [0.0, 1e-12, -1e-12]:
        for moving in [False, True]:
            ch = planar_chain(4, [True, False, True, True], gravity_angle=0.3)
            q, v, p = planar_state(ch, rng)
            q.reshape(4, 3)[:, 1] = ux
            if not moving:
                v[:] = 0.0
            tau = rng.normal(size=ch.nv) * ch.active
            assert rel(call_planar(ch, q, v, p, tau).ravel(), ch.forward_dynamics(q, v, p, tau)) < 1e-12


@pytest.mark.parametrize("n", [3, 10])
def test_mixed_locks(n, rng):
    ext = [j % 3 != 1 for j in range(n)]
    ch = planar_chain(n, ext, gravity_angle=-0.7, base_angle=0.5)
    assert ch._locked[:, 0].tolist() == [not e for e in ext]
    q, v, p = planar_state(ch, rng, straight={0: 0.0, 2: 1e-12})
    tau = rng.normal(size=ch.nv) * ch.active
    qdd = call_planar(ch, q, v, p, tau)
    assert np.all(qdd[ch._locked] == 0.0)
    assert rel(qdd.ravel(), ch.forward_dynamics(q, v, p, tau)) < 1e-12


def test_out_of_plane_inputs_are_ignored(rng):
    """``tau[:, 2]`` and the odd components of ``A0`` (out-of-plane gravity) change neither
    ``aba``'s ``qdd`` nor ``planar_aba``'s: they load only the locked uy."""
    n = 3
    ch = planar_chain(n, [True, False, True], gravity_angle=0.4)
    q, v, p = planar_state(ch, rng)
    q_c, v_c = q.reshape(n, 3), v.reshape(n, 3)
    f = (ch.internal_forces(q, v, p)).reshape(n, 3)
    A0 = np.array([1.0, 0.0, 9.0, 0.0, 0.5, 0.0])
    args = (ch.kernel_arrays(), q_c, v_c)
    ws = recursive.aba_workspace(n, 3 * n)
    pw = planar_workspace(n)
    out = []
    for odd in [(0.0, 0.0, 0.0), (2.0, -3.0, 4.0)]:
        A = A0.copy()
        A[[1, 3, 5]] = odd
        fo = f.copy()
        fo[:, 2] += odd[0]
        qa, qp = np.empty((n, 3)), np.empty((n, 3))
        assert recursive.aba(*args, fo, np.zeros(6), A, False, np.zeros(6), qa, np.empty(6), ws, ws.scratch)
        assert planar_aba(*args, fo, A, qp, pw, pw.pscratch)
        assert rel(qp, qa) < 1e-12
        out.append(qp.copy())
    assert np.array_equal(out[0], out[1])


def test_moving_base_in_plane(rng):
    """A prescribed base moving in its x-z plane: ``planar_aba_moving`` with the base twist."""
    for n in [1, 3]:
        ch = planar_chain(n, [True, False, True][:n], gravity_angle=1.1)
        q, v, p = planar_state(ch, rng, straight={0: 1e-12})
        tau = rng.normal(size=ch.nv) * ch.active
        V0 = np.zeros(6)
        V0[[0, 2, 4]] = rng.normal(size=3)
        A0 = np.zeros(6)
        A0[[0, 2, 4]] = rng.normal(size=3)
        A0[:3] -= ch._g_B
        f = (ch.internal_forces(q, v, p) + tau).reshape(n, 3)
        q_c, v_c = q.reshape(n, 3), v.reshape(n, 3)
        ws = recursive.aba_workspace(n, 3 * n)
        qa = np.empty((n, 3))
        assert recursive.aba(ch.kernel_arrays(), q_c, v_c, f, V0, A0, False, np.zeros(6), qa, np.empty(6), ws, ws.scratch)
        pw = planar_workspace(n)
        qp = np.empty((n, 3))
        assert planar_aba_moving(ch.kernel_arrays(), q_c, v_c, f, V0, A0, qp, pw, pw.pscratch)
        assert rel(qp, qa) < 1e-12


def test_not_positive_definite_returns_false(rng):
    ch = planar_chain(3)
    q, v, _ = planar_state(ch, rng)
    q_c, v_c = q.reshape(3, 3), v.reshape(3, 3)
    mass = ch._mass.copy()
    mass[1] = -mass[1]
    pw = planar_workspace(3)
    ws = recursive.aba_workspace(3, 9)
    tau = np.zeros((3, 3))
    A0 = np.array([0.0, 0.0, 9.81, 0.0, 0.0, 0.0])
    args = (ch.kernel_arrays()._replace(mass=mass), q_c, v_c, tau)
    assert not recursive.aba(*args, np.zeros(6), A0, False, np.zeros(6), np.empty((3, 3)), np.empty(6), ws, ws.scratch)
    assert not planar_aba(*args, A0, np.empty((3, 3)), pw, pw.pscratch)


def test_workspace_reuse_is_clean(rng):
    """A workspace reused across chains' states gives the same answer as a fresh one."""
    ch = planar_chain(3, [False, True, True])
    pw = planar_workspace(3)
    pw[3][:] = np.nan
    pw[-1][:] = np.nan
    q, v, p = planar_state(ch, rng)
    f = ch.internal_forces(q, v, p).reshape(3, 3)
    A0 = np.array([0.0, 0.0, 9.81, 0.0, 0.0, 0.0])
    args = (ch.kernel_arrays(), q.reshape(3, 3), v.reshape(3, 3), f, A0)
    q1 = np.empty((3, 3))
    q2 = np.empty((3, 3))
    assert planar_aba(*args, q1, pw, pw.pscratch)
    fresh = planar_workspace(3)
    assert planar_aba(*args, q2, fresh, fresh[-1])
    assert np.array_equal(q1, q2) and np.all(np.isfinite(q1))


@pytest.mark.parametrize("n", [1, 3, 10])
def test_planar_rnea_equals_rnea_and_inverts_planar_aba(n, rng):
    ext = [j % 3 != 1 for j in range(n)]
    ch = planar_chain(n, ext, gravity_angle=0.8, base_angle=-0.3)
    q, v, p = planar_state(ch, rng, straight={0: 1e-12, 2: 0.0})
    q_c, v_c = q.reshape(n, 3), v.reshape(n, 3)
    a_c = rng.normal(size=(n, 3)) * ch._locked.__invert__()
    A0 = np.zeros(6)
    A0[:3] = -ch._g_B
    args = (ch.kernel_arrays(), q_c, v_c)
    ws = recursive.aba_workspace(n, 3 * n)
    tau_r, F_r = np.empty((n, 3)), np.empty(6)
    recursive.rnea(*args, a_c, np.zeros(6), A0, tau_r, F_r, ws, ws.scratch)
    pw = planar_workspace(n)
    tau_p, F_p = np.full((n, 3), np.nan), np.full(6, np.nan)
    planar_rnea(*args, a_c, A0, tau_p, F_p, pw, pw.pscratch)
    assert rel(tau_p[:, :2], tau_r[:, :2]) < 1e-12
    assert np.abs(tau_r[:, 2]).max() <= 1e-12 * np.abs(tau_r).max() and np.all(tau_p[:, 2] == 0.0)
    assert rel(F_p, F_r) < 1e-12
    # planar_aba undoes planar_rnea: the accelerations to the conditioning of M (up to 1e8
    # here: l is stiff against ux; recursive.aba(recursive.rnea) is no closer), the forces on
    # the free coordinates to rounding
    qdd = np.empty((n, 3))
    assert planar_aba(*args, tau_p, A0, qdd, pw, pw.pscratch)
    assert rel(qdd, a_c) < 1e-10
    tau2 = np.empty((n, 3))
    planar_rnea(*args, qdd, A0, tau2, F_p, pw, pw.pscratch)
    free = ~ch._locked
    assert rel(tau2[free], tau_p[free]) < 1e-13
