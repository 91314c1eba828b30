"""The closed-form slice kernel equals Pinocchio's exp6/Jexp6/SE3.action to 1e-14, its
second derivatives equal finite differences, and it is regular at the straight pose."""

import numpy as np
import pinocchio as pin
import pytest

from helpers import assert_regular_at_straight_pose
from qchain.model.arc import arc_node_bias, arc_nodes, bend_functions, strain_twist

CASES = [
    np.array([0.2, 3.0, -4.0]),  # 1 rad
    np.array([0.25, 8.0, 1.0]),  # 2 rad
    np.array([0.3, 20.0, 15.0]),  # 7.5 rad: closed-form branch far from the series
    np.array([0.1, 0.0, 0.0]),  # straight
    np.array([0.3, 1e-9, 2e-9]),  # nearly straight
    np.array([0.2, 9.99, 0.0]),  # x just below the series/closed-form switch at 2 rad
    np.array([0.2, 10.01, 0.0]),  # just above
]
ALPHAS = np.array([0.0, 0.13, 0.5, 0.77, 1.0])


def dX_dq(q):
    d = np.zeros((6, 3))
    d[:, 0] = strain_twist(q)
    d[4, 1] = q[0]
    d[3, 2] = -q[0]
    return d


@pytest.mark.parametrize("q", CASES, ids=lambda q: f"q={q.tolist()}")
def test_kernel_equals_pinocchio(q):
    nodes = arc_nodes(ALPHAS, q)
    X = pin.Motion(q[0] * strain_twist(q))
    for k, a in enumerate(ALPHAS):
        g = pin.exp6(a * X)
        assert np.abs(g.rotation - nodes.R[k]).max() < 1e-14
        assert np.abs(g.translation - nodes.p[k]).max() < 1e-14 * q[0]
        assert np.abs(g.inverse().action - nodes.Ad_inv[k]).max() < 1e-14
        S = a * pin.Jexp6(a * X) @ dX_dq(q)
        scale = np.abs(S).max() + 1.0
        assert np.abs(S - nodes.S[k]).max() < 1e-14 * scale


@pytest.mark.parametrize("q", CASES[:5], ids=lambda q: f"q={q.tolist()}")
def test_jacobian_time_derivative_matches_finite_differences(q):
    """Sdot along qdot equals the central difference of S along qdot (and is linear in qdot)."""
    rng = np.random.default_rng(3)
    for qd in [np.array([0.05, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), rng.normal(size=3)]:
        nodes = arc_nodes(ALPHAS, q, qd)
        h = 1e-6
        fd = (arc_nodes(ALPHAS, q + h * qd).S - arc_nodes(ALPHAS, q - h * qd).S) / (2 * h)
        scale = np.abs(fd).max() + 1.0
        assert np.abs(fd - nodes.Sdot).max() < 1e-8 * scale


@pytest.mark.parametrize("q", CASES, ids=lambda q: f"q={q.tolist()}")
def test_bias_kernel_equals_the_jacobian_rate_times_the_rates(q):
    """``arc_node_bias``'s closed form of ``Sd qdot`` (written out entry by entry) equals the
    ``Sdot @ qdot`` of ``arc_nodes`` to 1e-14 of its size, with the same ``R``, ``p``, ``S``
    bit for bit, and is zero at zero rates."""
    rng = np.random.default_rng(5)
    R, p, S, sd = np.empty((3, 3)), np.empty(3), np.empty((6, 3)), np.empty(6)
    for qd in [np.array([0.05, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, -3.0]), rng.normal(size=3),
               np.zeros(3)]:
        nodes = arc_nodes(ALPHAS, q, qd)
        for k, a in enumerate(ALPHAS):
            arc_node_bias(a, *q, *qd, R, p, S, sd)
            assert np.array_equal(R, nodes.R[k]) and np.array_equal(p, nodes.p[k]) and np.array_equal(S, nodes.S[k])
            ref = nodes.Sdot[k] @ qd
            assert np.abs(sd - ref).max() <= 1e-14 * (np.abs(ref).max() + np.abs(nodes.Sdot[k]).max() * np.abs(qd).max())
            if not qd.any():
                assert not sd.any()


def test_bend_functions_series_and_closed_form_agree():
    """Both branches of f_n and g_n agree at the switch, and the series has the known values at 0."""
    f0, g0 = bend_functions(np.array([0.0]), derivatives=True)
    assert np.allclose(f0[:, 0], [1, 1 / 2, 1 / 6], rtol=1e-15)
    assert np.allclose(g0[:, 0], [-1 / 3, -1 / 12, -1 / 60], rtol=1e-15)
    x = np.array([2.0 - 1e-12, 2.0 + 1e-12, 1.7, 0.9])
    f, g = bend_functions(x, derivatives=True)
    # closed forms evaluated directly (cancellation is mild at these x)
    s, c = np.sin(x), np.cos(x)
    f_ref = [s / x, (1 - c) / x**2, (x - s) / x**3]
    g_ref = [(x * c - s) / x**3, (x * s - 2 * (1 - c)) / x**4, (x * (1 - c) - 3 * (x - s)) / x**5]
    for n in range(3):
        assert np.allclose(f[n], f_ref[n], rtol=1e-13, atol=0)
        assert np.allclose(g[n], g_ref[n], rtol=1e-11, atol=0)
    # the shorter series below 0.5 and 1.25 rad equal 24 terms of the series to 4e-16
    from math import factorial

    x = np.array([0.1, 0.49, 0.51, 0.9, 1.24, 1.26, 1.9])
    f, g = bend_functions(x, derivatives=True)
    for n in range(3):
        f_ser = sum((-1) ** k * x ** (2 * k) / factorial(2 * k + n + 1) for k in range(24))
        g_ser = sum((-1) ** k * 2 * k * x ** (2 * k - 2) / factorial(2 * k + n + 1) for k in range(1, 25))
        assert np.abs(f[n] - f_ser).max() <= 4e-16 * np.abs(f_ser).max()
        assert np.abs(g[n] - g_ser).max() <= 4e-16 * np.abs(g_ser).max()


def test_straight_pose_is_regular():
    """At kappa = 0, 1e-12 and 1e-8 the kernel is finite and equals its first-order Taylor
    expansion about the straight pose to 1e-12 relative: no division by curvature, no
    cancellation noise. (Plain agreement of the values cannot be asked at kappa = 1e-8:
    most entries change at first order in kappa l ~ 1e-9.)"""

    def kernel(q):
        n = arc_nodes(ALPHAS, q, [0.03, 1.0, -2.0])
        return np.concatenate([n.Ad_inv.ravel(), n.S.ravel(), n.Sdot.ravel()])

    assert_regular_at_straight_pose(kernel, length=0.2)
