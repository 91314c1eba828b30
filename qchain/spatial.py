"""Batched spatial (6D) algebra in Pinocchio's conventions (docs/model.md section 10).

Spatial motion vectors are ``[linear; angular]`` (Pinocchio's ``Motion``), spatial
forces ``[force; torque]`` (Pinocchio's ``Force``). Every function accepts a leading
batch axis ``(..., 6)`` so that all slice nodes of all segments are processed in one
numpy call; ``tests/test_spatial.py`` holds each of them equal to Pinocchio's own
``Motion.action``, ``Motion.cross``, ``SE3.action`` and ``Inertia.matrix``.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "skew",
    "motion_cross",
    "force_cross",
    "ad_matrix",
    "force_cross_bar",
    "inv_adjoint",
    "disk_inertia",
    "quaternion_to_rotation",
]


def skew(w: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[w x]``, shape ``(..., 3)`` -> ``(..., 3, 3)``."""
    w = np.asarray(w, dtype=float)
    out = np.zeros(w.shape[:-1] + (3, 3))
    out[..., 0, 1] = -w[..., 2]
    out[..., 0, 2] = w[..., 1]
    out[..., 1, 0] = w[..., 2]
    out[..., 1, 2] = -w[..., 0]
    out[..., 2, 0] = -w[..., 1]
    out[..., 2, 1] = w[..., 0]
    return out


def motion_cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Motion cross product ``a x b = ad(a) b`` (Pinocchio ``Motion.cross(Motion)``).

    ``a = (v, w)``, ``b = (u, x)``: ``a x b = (w x u + v x x, w x x)``; shapes ``(..., 6)``.
    """
    out = np.empty(np.broadcast_shapes(np.shape(a), np.shape(b)))
    out[..., :3] = np.cross(a[..., 3:], b[..., :3]) + np.cross(a[..., :3], b[..., 3:])
    out[..., 3:] = np.cross(a[..., 3:], b[..., 3:])
    return out


def force_cross(a: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Force cross product ``a x* h = -ad(a)^T h`` (Pinocchio ``Motion.cross(Force)``).

    ``a = (v, w)``, ``h = (f, n)``: ``a x* h = (w x f, v x f + w x n)``; shapes ``(..., 6)``.
    """
    out = np.empty(np.broadcast_shapes(np.shape(a), np.shape(h)))
    out[..., :3] = np.cross(a[..., 3:], h[..., :3])
    out[..., 3:] = np.cross(a[..., :3], h[..., :3]) + np.cross(a[..., 3:], h[..., 3:])
    return out


def ad_matrix(a: np.ndarray) -> np.ndarray:
    """Matrix of ``b -> a x b``: ``[[w^, v^], [0, w^]]``, ``(..., 6)`` -> ``(..., 6, 6)``."""
    a = np.asarray(a, dtype=float)
    out = np.zeros(a.shape[:-1] + (6, 6))
    wx = skew(a[..., 3:])
    out[..., :3, :3] = wx
    out[..., 3:, 3:] = wx
    out[..., :3, 3:] = skew(a[..., :3])
    return out


def force_cross_bar(h: np.ndarray) -> np.ndarray:
    """Matrix of ``a -> a x* h`` for a fixed force ``h = (f, n)``: ``[[0, -f^], [-f^, -n^]]``.

    It is skew-symmetric, which is what makes ``C_xi + C_xi^T = dM_xi/dt`` hold for
    the Coriolis factorisation in :mod:`qchain.segment`. Shape ``(..., 6)`` -> ``(..., 6, 6)``.
    """
    h = np.asarray(h, dtype=float)
    out = np.zeros(h.shape[:-1] + (6, 6))
    fx = skew(h[..., :3])
    out[..., :3, 3:] = -fx
    out[..., 3:, :3] = -fx
    out[..., 3:, 3:] = -skew(h[..., 3:])
    return out


def inv_adjoint(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``Ad(g)^-1`` for ``g = (R, p)``: maps a twist in g's parent frame to g's frame.

    ``[[R^T, -R^T p^], [0, R^T]]`` (Pinocchio ``SE3.inverse().action``);
    ``R`` of shape ``(..., 3, 3)``, ``p`` of shape ``(..., 3)`` -> ``(..., 6, 6)``.
    """
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros(R.shape[:-2] + (6, 6))
    out[..., :3, :3] = Rt
    out[..., 3:, 3:] = Rt
    out[..., :3, 3:] = -Rt @ skew(p)
    return out


def disk_inertia(mass: float, radius: float) -> np.ndarray:
    """Spatial inertia (6, 6) of a uniform thin disk about its centre, axis z.

    Mass ``mass`` (kg), radius ``radius`` (m); rotational inertia
    ``diag(m r^2/4, m r^2/4, m r^2/2)`` (kg m^2). Equals
    ``pinocchio.Inertia(mass, 0, diag(...)).matrix()``.
    """
    out = np.zeros((6, 6))
    out[:3, :3] = mass * np.eye(3)
    out[3:, 3:] = np.diag([0.25, 0.25, 0.5]) * mass * radius**2
    return out


def quaternion_to_rotation(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of quaternions ``(..., 4)`` as ``(x, y, z, w)``,
    normalised here."""
    q = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - z * w)
    R[..., 0, 2] = 2 * (x * z + y * w)
    R[..., 1, 0] = 2 * (x * y + z * w)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - x * w)
    R[..., 2, 0] = 2 * (x * z - y * w)
    R[..., 2, 1] = 2 * (y * z + x * w)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R
