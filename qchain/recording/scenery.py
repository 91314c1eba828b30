"""What the viewers draw besides the arm: the obstacles of ``RunInfo.obstacles`` as primitive
shapes, moved by their prescribed motions, and the contact forces as arrows. Plain numpy, in
one place for both viewers (the Foxglove messages of :mod:`qchain.recording.mcap_sink`, the
Rerun view of :mod:`qchain.recording.rerun_sink`)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = [
    "CONTACT_COLOR",
    "HALFSPACE_THICKNESS",
    "OBSTACLE_COLOR",
    "Shape",
    "force_scale",
    "motion_law",
    "motion_offset",
    "obstacle_shapes",
    "quat_between",
    "quat_from_matrix",
    "quat_mul",
    "quat_rotate",
    "TENDON_COLOR",
    "tendon_strips",
]

#: RGB of the obstacles (grey, drawn half transparent in Foxglove) and of the contact forces
OBSTACLE_COLOR = (150, 150, 160)
CONTACT_COLOR = (220, 30, 160)
#: RGB of the tendons (dark amber)
TENDON_COLOR = (200, 130, 20)
#: Thickness of the slab that draws a half-space, as a fraction of its width
HALFSPACE_THICKNESS = 1e-3


def tendon_strips(tendons: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tendons' paths of a batch (K, nt, M, 3), NaN-padded, as the strips a viewer draws:
    ``(points (sum of lengths, 3), lengths (K nt,))``, each path's finite points only."""
    K, nt, M, _ = tendons.shape
    ok = np.isfinite(tendons).all(axis=3)  # (K, nt, M)
    return tendons[ok], ok.sum(axis=2).reshape(K * nt)


class Shape(NamedTuple):
    """One obstacle as a primitive: ``kind`` "box", "sphere", "cylinder" or "capsule";
    ``center`` (3,) m (a capsule's: the midpoint of its axis); ``quaternion`` (4,) x, y, z, w
    turning the primitive's own axes into the world's (a cylinder's and a capsule's axis is
    its own z); ``size`` (3,) m, the full extents (a sphere's: its diameter thrice; a
    cylinder's and a capsule's: diameter, diameter, axis length without the caps); ``index``
    the obstacle's index in ``RunInfo.obstacles``."""

    kind: str
    center: np.ndarray
    quaternion: np.ndarray
    size: np.ndarray
    index: int = -1


def quat_from_matrix(R: np.ndarray) -> np.ndarray:
    """The unit quaternion (x, y, z, w) of a rotation matrix (3, 3) (Shepperd's method: the
    largest of the four candidates, so no division by a small number)."""
    R = np.asarray(R, dtype=float)
    tr = np.trace(R)
    cands = np.array([tr, R[0, 0], R[1, 1], R[2, 2]])
    i = int(np.argmax(cands))
    if i == 0:
        w = 0.5 * np.sqrt(1.0 + tr)
        q = np.array([(R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w), (R[1, 0] - R[0, 1]) / (4 * w), w])
    else:
        j, k = (i % 3), (i + 1) % 3
        a = i - 1
        x = 0.5 * np.sqrt(max(0.0, 1.0 + 2.0 * R[a, a] - tr))
        q = np.zeros(4)
        q[a] = x
        q[j] = (R[j, a] + R[a, j]) / (4 * x)
        q[k] = (R[k, a] + R[a, k]) / (4 * x)
        q[3] = (R[k, j] - R[j, k]) / (4 * x)
    return q / np.linalg.norm(q)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Quaternion products (..., 4) x, y, z, w."""
    ax, ay, az, aw = np.moveaxis(np.asarray(a, dtype=float), -1, 0)
    bx, by, bz, bw = np.moveaxis(np.asarray(b, dtype=float), -1, 0)
    return np.stack([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz], axis=-1)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vectors (..., 3) rotated by unit quaternions (..., 4) x, y, z, w."""
    q = np.asarray(q, dtype=float)
    u, w = q[..., :3], q[..., 3:4]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def quat_between(a, b) -> np.ndarray:
    """The shortest rotation (x, y, z, w) taking the direction ``a`` (3,) to ``b`` (3,); a
    half turn about an axis normal to ``a`` when they are opposite."""
    a = np.asarray(a, dtype=float) / np.linalg.norm(a)
    b = np.asarray(b, dtype=float) / np.linalg.norm(b)
    c = float(np.dot(a, b))
    if c < -1.0 + 1e-12:
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        return np.append(axis / np.linalg.norm(axis), 0.0)
    q = np.append(np.cross(a, b), 1.0 + c)
    return q / np.linalg.norm(q)


def obstacle_shapes(obstacles: list[dict] | None, extent: float) -> list[Shape]:
    """The primitives of ``RunInfo.obstacles`` (at ``t = 0``), one an obstacle, in order (each
    with its ``index``). A half-space is a square slab ``2 extent`` (m) wide whose top face is
    the plane; an obstacle of a type this qchain does not know is skipped (a newer recording).
    A moving obstacle is drawn here and translated by :func:`motion_offset` at each sample."""
    out = []
    for i, ob in enumerate(obstacles or ()):
        kind = ob.get("type")
        if kind == "halfspace":
            n = np.asarray(ob["normal"], dtype=float)
            n = n / np.linalg.norm(n)
            th = HALFSPACE_THICKNESS * 2.0 * extent
            out.append(Shape("box", np.asarray(ob["point"], dtype=float) - 0.5 * th * n,
                             quat_between([0.0, 0.0, 1.0], n), np.array([2.0 * extent, 2.0 * extent, th]), i))
        elif kind == "sphere":
            out.append(Shape("sphere", np.asarray(ob["center"], dtype=float), np.array([0.0, 0.0, 0.0, 1.0]),
                             np.full(3, 2.0 * float(ob["radius"])), i))
        elif kind in ("cylinder", "capsule"):
            a, b = np.asarray(ob["a"], dtype=float), np.asarray(ob["b"], dtype=float)
            d, r = float(ob["radius"]), b - a
            out.append(Shape(kind, 0.5 * (a + b), quat_between([0.0, 0.0, 1.0], r),
                             np.array([2.0 * d, 2.0 * d, float(np.linalg.norm(r))]), i))
        elif kind == "box":
            out.append(Shape("box", np.asarray(ob["center"], dtype=float), quat_from_matrix(ob["rotation"]),
                             2.0 * np.asarray(ob["half_extents"], dtype=float), i))
    return out


def motion_law(motion, name: str = "motion") -> tuple[np.ndarray, np.ndarray, float, float] | None:
    """An obstacle's ``"motion"`` entry of ``RunInfo.obstacles`` (as
    :meth:`qchain.contact.Environment.describe` writes it) checked and unpacked: ``velocity``
    (3,) m/s, ``amplitude`` (3,) m, ``frequency`` Hz, ``phase`` rad, all finite; None for a
    fixed obstacle (``motion`` None). A ``ValueError`` names ``name`` and what is wrong."""
    if motion is None:
        return None
    if not isinstance(motion, dict):
        raise ValueError(f"{name} must be None or a dict of velocity, amplitude, frequency and phase, got "
                         f"{type(motion).__name__}")
    out = []
    for key, shape in (("velocity", (3,)), ("amplitude", (3,)), ("frequency", ()), ("phase", ())):
        value = motion.get(key)
        try:
            x = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            x = None
        if x is None or x.shape != shape or not np.all(np.isfinite(x)) or isinstance(value, (bool, str)):
            what = "3 finite numbers" if shape else "a finite number"
            raise ValueError(f"{name}['{key}'] must be {what}, got {value!r}")
        out.append(x if shape else float(x))
    return out[0], out[1], out[2], out[3]


def motion_offset(motion, t) -> np.ndarray:
    """The translation ``u(t) = velocity t + amplitude sin(2 pi frequency t + phase)`` (K, 3) m,
    world frame, of an obstacle whose ``RunInfo.obstacles`` entry has the ``"motion"``
    ``motion`` (:func:`motion_law`; None: zeros), at the times ``t`` (K,) s. The numpy twin of
    the compiled :func:`qchain.contact.distance.move` (the writer process and a replay load no
    numba), in the same operations (``tests/test_recording_contacts.py`` holds them equal)."""
    t = np.asarray(t, dtype=float).reshape(-1)
    law = motion_law(motion)
    if law is None:
        return np.zeros((t.shape[0], 3))
    velocity, amplitude, frequency, phase = law
    w = 2.0 * np.pi * frequency
    s = np.sin(w * t + phase)
    return velocity[None, :] * t[:, None] + amplitude[None, :] * s[:, None]


def force_scale(reach: float, force_ref: float) -> float:
    """Metres of arrow a newton of contact force: ``RunInfo.force_ref`` (N) is drawn a quarter
    of the arm's reach ``reach`` (m) long."""
    return 0.25 * reach / force_ref


def reach(info, backbone0: np.ndarray) -> float:
    """The arm's reach (m): the sum of the segments' lengths in ``info.params["segments"]``
    when the run gives them, else the length of the first record's backbone ``backbone0``
    (n, P, 3), at least 8 x the sum of the radii."""
    lengths = info.params.get("segments") if isinstance(info.params, dict) else None
    if isinstance(lengths, list) and len(lengths) == backbone0.shape[0] and \
            all(isinstance(s, dict) and "length" in s for s in lengths):
        return float(sum(float(s["length"]) for s in lengths))
    drawn = np.linalg.norm(np.diff(np.nan_to_num(backbone0), axis=1), axis=2).sum() if backbone0.shape[1] > 1 else 0.0
    return max(float(drawn), 8.0 * float(np.sum(info.radii)))
