"""The batched spatial algebra equals Pinocchio's own to 1e-14."""

import numpy as np
import pinocchio as pin

from qchain.model.spatial import ad_matrix, disk_inertia, force_cross, force_cross_bar, inv_adjoint, motion_cross


def test_motion_and_force_cross_match_pinocchio(rng):
    for _ in range(20):
        a, b, h = rng.normal(size=(3, 6))
        A, B, H = pin.Motion(a), pin.Motion(b), pin.Force(h)
        assert np.allclose(motion_cross(a, b), A.cross(B).vector, rtol=0, atol=1e-14)
        assert np.allclose(force_cross(a, h), A.cross(H).vector, rtol=0, atol=1e-14)
        assert np.allclose(ad_matrix(a), A.action, rtol=0, atol=1e-15)
        assert np.allclose(force_cross_bar(h) @ a, A.cross(H).vector, rtol=0, atol=1e-14)
        assert np.allclose(force_cross_bar(h), -force_cross_bar(h).T, rtol=0, atol=0)


def test_inverse_adjoint_and_disk_inertia_match_pinocchio(rng):
    for _ in range(20):
        g = pin.SE3.Random()
        assert np.allclose(inv_adjoint(g.rotation, g.translation), g.inverse().action, rtol=0, atol=1e-14)
    m, r = 0.7, 0.03
    I = pin.Inertia(m, np.zeros(3), np.diag([m * r * r / 4, m * r * r / 4, m * r * r / 2]))
    assert np.allclose(disk_inertia(m, r), I.matrix(), rtol=0, atol=1e-16)


def test_batched_shapes(rng):
    a = rng.normal(size=(4, 5, 6))
    assert ad_matrix(a).shape == (4, 5, 6, 6)
    assert np.allclose(np.einsum("...ij,...j->...i", ad_matrix(a), a[::-1]), motion_cross(a, a[::-1]))
