"""Obstacles, checked where they are made: half-spaces (ground, walls), spheres, capsules,
cylinders (poles) and boxes, in the world frame (m), fixed or translated by a prescribed
:class:`Motion`.

Each is a frozen dataclass whose :meth:`row` gives the kernels' parameter row
(:mod:`qchain.contact.distance`); a bad argument raises naming the parameter, the value and
the bound (:mod:`qchain.checks.bounds`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..checks.bounds import ANGLE, EXTENT, FREQUENCY, POSITION, VELOCITY
from ..checks.convert import as_matrix, as_vector
from .distance import BOX, CAPSULE, CYLINDER, HALFSPACE, MOTION, PARAMS, SPHERE

__all__ = ["HalfSpace", "Sphere", "Capsule", "Cylinder", "Box", "Obstacle", "Motion", "MOTION_RANGES"]

#: The bounds of each :class:`Motion` field (of every component of a vector), checked where it is
#: made; scene files declare their motion keys with these (:mod:`qchain.scene.format`).
MOTION_RANGES = {"velocity": VELOCITY, "amplitude": POSITION, "frequency": FREQUENCY, "phase": ANGLE}


@dataclass(frozen=True)
class Motion:
    """A prescribed translation of an obstacle: ``u(t) = velocity t + amplitude sin(2 pi
    frequency t + phase)`` (m, world frame) added to its placement; ``velocity`` (3,) m/s,
    ``amplitude`` (3,) m, ``frequency`` Hz, ``phase`` rad. The arm's friction and damping act
    on its velocity relative to the obstacle."""

    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    amplitude: np.ndarray = field(default_factory=lambda: np.zeros(3))
    frequency: float = 0.0
    phase: float = 0.0

    def __post_init__(self):
        for name in ("velocity", "amplitude"):
            x = as_vector(f"Motion.{name}", getattr(self, name), 3)
            MOTION_RANGES[name].check_array(f"Motion.{name}", x)
            object.__setattr__(self, name, x)
        for name in ("frequency", "phase"):
            object.__setattr__(self, name, MOTION_RANGES[name].check(f"Motion.{name}", getattr(self, name)))

    def row(self) -> np.ndarray:
        """The kernels' motion row (MOTION,)."""
        out = np.zeros(MOTION)
        out[:3], out[3:6], out[6], out[7] = self.velocity, self.amplitude, self.frequency, self.phase
        return out


def _motion(owner: str, value):
    if value is not None and not isinstance(value, Motion):
        raise TypeError(f"{owner}.motion must be a qchain.contact.Motion or None, got {type(value).__name__}")
    return value


def _point(owner: str, name: str, value) -> np.ndarray:
    x = as_vector(f"{owner}.{name}", value, 3)
    POSITION.check_array(f"{owner}.{name}", x)
    return x


def _row(kind: int, *parts) -> tuple[int, np.ndarray]:
    row = np.zeros(PARAMS)
    flat = np.concatenate([np.ravel(p) for p in parts])
    row[: flat.size] = flat
    return kind, row


@dataclass(frozen=True)
class HalfSpace:
    """The solid below a plane: ``point`` (3,) on it, ``normal`` (3,) pointing out of the solid
    (normalised). ``HalfSpace()`` is the ground ``z <= 0``."""

    point: np.ndarray = field(default_factory=lambda: np.zeros(3))
    normal: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))

    motion: Motion | None = None

    def __post_init__(self):
        object.__setattr__(self, "motion", _motion("HalfSpace", self.motion))
        object.__setattr__(self, "point", _point("HalfSpace", "point", self.point))
        nrm = as_vector("HalfSpace.normal", self.normal, 3)
        size = float(np.linalg.norm(nrm))
        if not size > 1e-12:
            raise ValueError(f"HalfSpace.normal must be a nonzero direction, got {nrm.tolist()} (norm {size:g})")
        object.__setattr__(self, "normal", nrm / size)

    def row(self):
        return _row(HALFSPACE, self.point, self.normal)


@dataclass(frozen=True)
class Sphere:
    """A ball: ``center`` (3,) m, ``radius`` m."""

    center: np.ndarray
    radius: float

    motion: Motion | None = None

    def __post_init__(self):
        object.__setattr__(self, "motion", _motion("Sphere", self.motion))
        object.__setattr__(self, "center", _point("Sphere", "center", self.center))
        object.__setattr__(self, "radius", EXTENT.check("Sphere.radius", self.radius))

    def row(self):
        return _row(SPHERE, self.center, [self.radius])


def _axis(owner: str, a, b) -> tuple[np.ndarray, np.ndarray]:
    a = _point(owner, "a", a)
    b = _point(owner, "b", b)
    L = float(np.linalg.norm(b - a))
    if not L >= 1e-9:
        raise ValueError(f"{owner}: the axis end points a and b must differ (>= 1e-09 m apart), got |b - a| = {L:g} m "
                         f"(a = {a.tolist()}, b = {b.tolist()})")
    return a, b


@dataclass(frozen=True)
class _Axial:
    """A shape around the segment from ``a`` to ``b`` (3,) (m) of radius ``radius`` (m)."""

    a: np.ndarray
    b: np.ndarray
    radius: float

    motion: Motion | None = None
    _KIND = -1

    def __post_init__(self):
        name = type(self).__name__
        object.__setattr__(self, "motion", _motion(name, self.motion))
        a, b = _axis(name, self.a, self.b)
        object.__setattr__(self, "a", a)
        object.__setattr__(self, "b", b)
        object.__setattr__(self, "radius", EXTENT.check(f"{name}.radius", self.radius))

    def row(self):
        return _row(self._KIND, self.a, self.b, [self.radius])


@dataclass(frozen=True)
class Capsule(_Axial):
    """The points within ``radius`` (m) of the segment from ``a`` to ``b`` (3,) (m)."""

    _KIND = CAPSULE


@dataclass(frozen=True)
class Cylinder(_Axial):
    """A solid cylinder (a pole) with flat ends: axis from ``a`` to ``b`` (3,) (m), ``radius`` (m)."""

    _KIND = CYLINDER


@dataclass(frozen=True)
class Box:
    """A box: ``center`` (3,) m, ``half_extents`` (3,) m, ``rotation`` (3, 3) box-to-world
    (orthonormal, det +1; identity by default)."""

    center: np.ndarray
    half_extents: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))

    motion: Motion | None = None

    def __post_init__(self):
        object.__setattr__(self, "motion", _motion("Box", self.motion))
        object.__setattr__(self, "center", _point("Box", "center", self.center))
        h = as_vector("Box.half_extents", self.half_extents, 3)
        EXTENT.check_array("Box.half_extents", h)
        object.__setattr__(self, "half_extents", h)
        R = as_matrix("Box.rotation", self.rotation, (3, 3))
        err = float(np.abs(R.T @ R - np.eye(3)).max())
        if err > 1e-9 or np.linalg.det(R) < 0.0:
            raise ValueError(f"Box.rotation must be a rotation matrix (R^T R = I within 1e-09, det +1), got "
                             f"|R^T R - I| = {err:.3g}, det = {np.linalg.det(R):.6g}")
        object.__setattr__(self, "rotation", R)

    def row(self):
        return _row(BOX, self.center, self.half_extents, self.rotation)


Obstacle = HalfSpace | Sphere | Capsule | Cylinder | Box
