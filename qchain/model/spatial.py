"""Batched spatial (6D) algebra in Pinocchio's conventions (docs/model.md section 10).

Spatial motion vectors are ``[linear; angular]`` (Pinocchio's ``Motion``), spatial
forces ``[force; torque]`` (Pinocchio's ``Force``). Every function accepts a leading
batch axis ``(..., 6)`` so that all slice nodes of all segments are processed in one
numpy call; ``tests/test_spatial.py`` holds each of them equal to Pinocchio's own
``Motion.action``, ``Motion.cross``, ``SE3.action`` and ``Inertia.matrix``.

Every public function checks its arguments where they enter (real, finite, the trailing
dimension it needs; :func:`qchain.checks.convert.as_batch`) and raises ``TypeError``/``ValueError``
naming the argument (:func:`qchain.checks.arguments.checked` makes each from its kernel); the
model's own passes call the unchecked ``_``-prefixed kernels on values they have already
validated.
"""

from __future__ import annotations

import numpy as np

from ..checks.arguments import checked
from ..checks.convert import as_batch, as_real

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


def _skew(w: np.ndarray) -> np.ndarray:
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


def _motion_cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Motion cross product ``a x b = ad(a) b`` (Pinocchio ``Motion.cross(Motion)``).

    ``a = (v, w)``, ``b = (u, x)``: ``a x b = (w x u + v x x, w x x)``; shapes ``(..., 6)``.
    """
    out = np.empty(np.broadcast_shapes(np.shape(a), np.shape(b)))
    out[..., :3] = np.cross(a[..., 3:], b[..., :3]) + np.cross(a[..., :3], b[..., 3:])
    out[..., 3:] = np.cross(a[..., 3:], b[..., 3:])
    return out


def _force_cross(a: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Force cross product ``a x* h = -ad(a)^T h`` (Pinocchio ``Motion.cross(Force)``).

    ``a = (v, w)``, ``h = (f, n)``: ``a x* h = (w x f, v x f + w x n)``; shapes ``(..., 6)``.
    """
    out = np.empty(np.broadcast_shapes(np.shape(a), np.shape(h)))
    out[..., :3] = np.cross(a[..., 3:], h[..., :3])
    out[..., 3:] = np.cross(a[..., :3], h[..., :3]) + np.cross(a[..., 3:], h[..., 3:])
    return out


def _ad_matrix(a: np.ndarray) -> np.ndarray:
    """Matrix of ``b -> a x b``: ``[[w^, v^], [0, w^]]``, ``(..., 6)`` -> ``(..., 6, 6)``."""
    a = np.asarray(a, dtype=float)
    out = np.zeros(a.shape[:-1] + (6, 6))
    wx = _skew(a[..., 3:])
    out[..., :3, :3] = wx
    out[..., 3:, 3:] = wx
    out[..., :3, 3:] = _skew(a[..., :3])
    return out


def _force_cross_bar(h: np.ndarray) -> np.ndarray:
    """Matrix of ``a -> a x* h`` for a fixed force ``h = (f, n)``: ``[[0, -f^], [-f^, -n^]]``.

    It is skew-symmetric, which is what makes ``C_xi + C_xi^T = dM_xi/dt`` hold for
    the Coriolis factorisation in :mod:`qchain.model.segment`. Shape ``(..., 6)`` -> ``(..., 6, 6)``.
    """
    h = np.asarray(h, dtype=float)
    out = np.zeros(h.shape[:-1] + (6, 6))
    fx = _skew(h[..., :3])
    out[..., :3, 3:] = -fx
    out[..., 3:, :3] = -fx
    out[..., 3:, 3:] = -_skew(h[..., 3:])
    return out


def _inv_adjoint(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """``Ad(g)^-1`` for ``g = (R, p)``: maps a twist in g's parent frame to g's frame.

    ``[[R^T, -R^T p^], [0, R^T]]`` (Pinocchio ``SE3.inverse().action``);
    ``R`` of shape ``(..., 3, 3)``, ``p`` of shape ``(..., 3)`` -> ``(..., 6, 6)``.
    """
    Rt = np.swapaxes(R, -1, -2)
    out = np.zeros(R.shape[:-2] + (6, 6))
    out[..., :3, :3] = Rt
    out[..., 3:, 3:] = Rt
    out[..., :3, 3:] = -Rt @ _skew(p)
    return out


def disk_inertia(mass: float, radius: float) -> np.ndarray:
    mass, radius = as_real("mass", mass), as_real("radius", radius)
    if mass < 0.0 or radius < 0.0:
        raise ValueError(f"disk_inertia: mass and radius must be >= 0, got mass = {mass:g} kg, radius = {radius:g} m")
    return _disk_inertia(mass, radius)


def _disk_inertia(mass: float, radius: float) -> np.ndarray:
    """Spatial inertia (6, 6) of a uniform thin disk about its centre, axis z.

    Mass ``mass`` (kg), radius ``radius`` (m); rotational inertia
    ``diag(m r^2/4, m r^2/4, m r^2/2)`` (kg m^2). Equals
    ``pinocchio.Inertia(mass, 0, diag(...)).matrix()``.
    """
    out = np.zeros((6, 6))
    out[:3, :3] = mass * np.eye(3)
    out[3:, 3:] = np.diag([0.25, 0.25, 0.5]) * mass * radius**2
    return out


def _quaternion_to_rotation(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of quaternions ``(..., 4)`` as ``(x, y, z, w)``,
    normalised here."""
    q = quat / np.linalg.norm(quat, axis=-1, keepdims=True)  # the callers' quaternions are unit within 1e-6
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


# ----------------------------------------------------------------------------- checked entry points


def _batch(size: int):
    """A converter of arrays ``(..., size)`` for :func:`~qchain.checks.arguments.checked`."""
    return lambda name, x: as_batch(name, x, size)


def _broadcasting(na: str, nb: str):
    """A joint check that two batches' shapes broadcast together."""
    return lambda a, b: _broadcast(na, a, nb, b)


skew = checked(_skew, w=_batch(3))
motion_cross = checked(_motion_cross, a=_batch(6), b=_batch(6), joint=_broadcasting("a", "b"))
force_cross = checked(_force_cross, a=_batch(6), h=_batch(6), joint=_broadcasting("a", "h"))
ad_matrix = checked(_ad_matrix, a=_batch(6))
force_cross_bar = checked(_force_cross_bar, h=_batch(6))
inv_adjoint = checked(_inv_adjoint, R=_batch(3), p=_batch(3), joint=lambda R, p: _pose_shapes(R, p))


def quaternion_to_rotation(quat) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of quaternions ``(..., 4)`` as ``(x, y, z, w)``,
    normalised here; a quaternion of norm below 1e-150 (no rotation) is a ``ValueError``."""
    q = as_batch("quat", quat, 4)
    norm = np.linalg.norm(q, axis=-1)
    if np.any(~(norm > 1e-150)):
        k = int(np.flatnonzero(~(norm.ravel() > 1e-150))[0])
        raise ValueError(f"quat must have a non-zero norm (it is normalised here), got norm {norm.ravel()[k]:g} "
                         f"at quaternion {k}")
    return _quaternion_to_rotation(q)


def _broadcast(na: str, a: np.ndarray, nb: str, b: np.ndarray) -> None:
    try:
        np.broadcast_shapes(a.shape, b.shape)
    except ValueError:
        raise ValueError(f"{na} and {nb} must have shapes that broadcast, got {a.shape} and {b.shape}") from None


def _pose_shapes(R: np.ndarray, p: np.ndarray) -> None:
    if R.ndim < 2 or R.shape[-2] != 3 or R.shape[:-2] != p.shape[:-1]:
        raise ValueError(f"inv_adjoint: R must have shape (..., 3, 3) and p (..., 3) with the same leading shape, got "
                         f"R {R.shape} and p {p.shape}")
