"""The batched spatial algebra, and the compiled passes' (qchain.model.spatial_kernels), equal
Pinocchio's own to 1e-14."""

import numpy as np
import pinocchio as pin

from numba import njit

from qchain.model import spatial_kernels as K
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


@njit(cache=False)
def _compiled(a, b, h, R, p, out):
    """Each compiled kernel on arrays, stored each way (put6, add6, sub6) into the rows of ``out``;
    the last row: the result written over its own argument."""
    K.put6(out[0], K.motion_cross(a, b))
    K.put6(out[1], K.force_cross(a, h))
    K.put6(out[2], K.ad_twist(R, p, a))
    K.put6(out[3], K.ad_force(R, p, h))
    K.add6(out[4], K.motion_cross(a, b))
    K.sub6(out[5], K.force_cross(a, h))
    for r in range(6):
        out[6, r] = b[r]
    K.put6(out[6], K.motion_cross(a, out[6]))


def test_the_compiled_kernels_match_pinocchio_and_read_before_they_write(rng):
    for _ in range(20):
        a, b, h = rng.normal(size=(3, 6))
        X = pin.SE3.Random()
        A, B, H = pin.Motion(a), pin.Motion(b), pin.Force(h)
        out = rng.normal(size=(7, 6))
        before = out.copy()
        _compiled(a, b, h, X.rotation, X.translation, out)
        expect = [A.cross(B).vector, A.cross(H).vector, X.act(A).vector, X.act(H).vector,
                  before[4] + A.cross(B).vector, before[5] - A.cross(H).vector, A.cross(B).vector]
        for row, e in zip(out, expect):
            assert np.allclose(row, e, rtol=0, atol=1e-14)
