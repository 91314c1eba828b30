"""The parts of a scene: its segments (:class:`SegmentSpec`), its base (:class:`BaseSpec`)
and a prescribed base's motion (:class:`SineMotion`), as :func:`qchain.scene.load_scene`
reads them from a file; and how a vector of theirs reads in a message.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np
import pinocchio as pin

from ..model.segment import Segment
from ..sim.inputs import SineMotion

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
    damping_matrix: tuple | None = None  # (3, 3) as rows, hashable; None: beta K(q0)
    drag_linear: float = 0.0
    drag_quadratic: float = 0.0
    coords: str = "curvature"
    actuation: str = "volume"
    extensible: bool = True
    nodes: int | None = None
    source: str = ""

    @property
    def axial_damping_coupling(self) -> bool:
        """Whether ``damping_matrix`` couples ``l`` to ``ux`` or ``uy`` (its entries (0, 1), (0, 2))."""
        D = self.damping_matrix
        return D is not None and (D[0][1] != 0.0 or D[0][2] != 0.0)

    @property
    def uy_damping_coupling(self) -> bool:
        """Whether ``damping_matrix`` couples ``uy`` to ``l`` or ``ux`` (its entries (2, 0), (2, 1))."""
        D = self.damping_matrix
        return D is not None and (D[2][0] != 0.0 or D[2][1] != 0.0)

    def segment(self, nodes: int | None = None) -> Segment:
        """The :class:`qchain.Segment` with ``nodes`` Gauss nodes (default: the spec's own)."""
        kw = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "source"}  # Segment's own names
        if self.damping_matrix is not None:
            kw["damping_matrix"] = np.array(self.damping_matrix, dtype=float)
        return Segment(**{**kw, "nodes": self.nodes if nodes is None else nodes})


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
