"""The parts of a scene: its segments (:class:`SegmentSpec`), its base (:class:`BaseSpec`)
and a prescribed base's motion (:class:`SineMotion`), as :func:`qchain.scene.load_scene`
reads them from a file; and how a vector of theirs reads in a message.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from .segment import Segment

__all__ = ["SegmentSpec", "SineMotion", "BaseSpec"]


@dataclass(frozen=True)
class SegmentSpec:
    """One segment of a scene (after ``count`` is expanded); ``source`` is its table's key."""

    length: float
    radius: float
    mass: float
    chamber_area: float
    chamber_radius: float
    youngs_modulus: float
    damping: float = 0.0
    coords: str = "curvature"
    actuation: str = "volume"
    extensible: bool = True
    nodes: int | None = None
    source: str = ""

    def segment(self, nodes: int | None = None) -> Segment:
        """The :class:`qchain.Segment` with ``nodes`` Gauss nodes (default: the spec's own)."""
        return Segment(
            length=self.length, radius=self.radius, mass=self.mass, chamber_area=self.chamber_area,
            chamber_radius=self.chamber_radius, youngs_modulus=self.youngs_modulus, damping=self.damping,
            coords=self.coords, actuation=self.actuation, extensible=self.extensible,
            nodes=self.nodes if nodes is None else nodes,
        )


@dataclass(frozen=True, eq=False)
class SineMotion:
    """A mount swinging sinusoidally: ``X_WB(t) = X_0 * M(s(t))``, ``s = a sin(2 pi f t + phase)``.

    ``kind = "translation"``: ``M(s) = (I, s axis)``, a shift along ``axis`` (mount frame);
    ``kind = "rotation"``: ``M(s) = (exp3(s axis), 0)``, a turn about ``axis`` through the
    mount origin. Velocities and accelerations are exact: ``V_B = s' (axis, 0)`` or
    ``s' (0, axis)`` in the base frame, ``A_B = dV_B/dt`` likewise with ``s''``.

    Calling it at ``t`` returns ``(X_WB: pinocchio.SE3, V_B (6,), A_B (6,))``, the form
    :class:`qchain.Chain` takes as ``base_motion``.
    """

    kind: str
    axis: np.ndarray
    amplitude: float
    frequency: float
    phase: float
    mount: pin.SE3

    def offset(self, t: float) -> tuple[float, float, float]:
        """``(s, s', s'')`` at ``t``: m or rad, per s, per s^2."""
        w = 2.0 * math.pi * self.frequency
        arg = w * t + self.phase
        return (self.amplitude * math.sin(arg), self.amplitude * w * math.cos(arg),
                -self.amplitude * w * w * math.sin(arg))

    def placement_at(self, s: float) -> pin.SE3:
        """``X_0 * M(s)``."""
        if self.kind == "translation":
            return self.mount * pin.SE3(np.eye(3), s * self.axis)
        return self.mount * pin.SE3(pin.exp3(s * self.axis), np.zeros(3))

    def peak_acceleration(self) -> float:
        """``max |s''| = |a| (2 pi f)^2``."""
        return abs(self.amplitude) * (2.0 * math.pi * self.frequency) ** 2

    def __call__(self, t: float):
        s, sd, sdd = self.offset(float(t))
        V = np.zeros(6)
        A = np.zeros(6)
        k = 0 if self.kind == "translation" else 3
        V[k : k + 3] = sd * self.axis
        A[k : k + 3] = sdd * self.axis
        return self.placement_at(s), V, A


@dataclass(frozen=True, eq=False)
class BaseSpec:
    """The base of a scene: ``type`` and the placement, initial twist or motion it needs."""

    type: str = "fixed"
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rpy: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    angular_velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    motion: SineMotion | None = None

    @property
    def placement(self) -> pin.SE3:
        """The mount (fixed, prescribed) or initial (floating) placement ``X_WB`` in the world."""
        return pin.SE3(pin.rpy.rpyToMatrix(*self.rpy), np.array(self.position, dtype=float))


def _vec_str(v) -> str:
    """A vector as scene messages show it: ``(1, 0.5, 0)``."""
    return "(" + ", ".join(f"{x:.6g}" for x in v) + ")"
