"""What an arm can touch and be pushed by: :class:`ContactLaw`, :class:`PointLoad` and
:class:`Environment`, the checked inputs of the contact passes (:mod:`qchain.contact.forces`).

An :class:`Environment` goes where a run's forces are computed:
``chain.forward_dynamics(q, v, p, env=env)``, ``chain.inverse_dynamics(q, v, a, env=env)``,
``chain.contacts(q, v, env)`` (what touches what), ``qchain.simulate(..., env=env)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple, Sequence

import numpy as np

from ..checks.bounds import (CONTACT_DAMPING, CONTACT_EXPONENT, CONTACT_NODES, CONTACT_STIFFNESS, FRICTION,
                             IMPACT_SPEED, RESTITUTION, SLIP_VELOCITY)
from ..checks.convert import as_bool, as_real, as_vector
from .distance import MOTION, PARAMS
from .forces import LAW, RECORD
from .shapes import Box, Capsule, Cylinder, HalfSpace, Sphere

__all__ = ["ContactLaw", "PointLoad", "Environment", "Contacts", "hunt_crossley_damping", "contact_nodes",
           "MAX_OBSTACLES", "RIPPLE"]

#: obstacles in one environment (each costs a distance per contact point near it)
MAX_OBSTACLES = 1000


def hunt_crossley_damping(restitution: float, impact_speed: float) -> float:
    """The damping ``c`` (s/m) of ``f_n = k d^e (1 + c d')`` that gives the coefficient of
    restitution ``restitution`` at the impact speed ``impact_speed`` (m/s):
    ``c = 8 (1 - e) / (5 e v)``, Flores, Machado, Silva and Martins (2011), "On the continuous
    contact force models for soft materials in multibody dynamics", Multibody System Dynamics
    25, 357-375, eq. (31): derived for the Hertz exponent 3/2, valid over ``0 < e <= 1``
    (docs/contact.md gives the rebound ratios it yields here)."""
    e = RESTITUTION.check("restitution", restitution)
    v = IMPACT_SPEED.check("impact_speed", impact_speed)
    return 8.0 * (1.0 - e) / (5.0 * e * v)


@dataclass(frozen=True)
class ContactLaw:
    """The contact law (:mod:`qchain.contact.forces`): per contact point of rest length ``l``,
    penetration ``d`` (m) and penetration rate ``d'`` (m/s),
    ``f_n = l k d^e max(0, 1 + c d')`` and the regularised Coulomb friction.

    Parameters
    ----------
    stiffness : float, N/m^(1+e) per m of tube (``k``)
        Sets the penetration at rest: an arm of weight ``w`` per metre lying on the ground
        sinks by ``(w / k)^(1/e)``. The default, 1e6 with ``e = 1.5``, sinks a 0.5 kg/m arm
        by 0.3 mm.
    exponent : float in [1, 3] (``e``)
        1.5: Hertz's for a ball; 1: a linear spring.
    damping : float, s/m (``c``)
        Hunt and Crossley's: the restitution ``r`` at impact speed ``v`` needs
        ``c = hunt_crossley_damping(r, v)``; 0 is elastic.
    mu_static, mu_dynamic : float >= 0
        Coulomb's coefficients (``mu_static >= mu_dynamic``).
    slip_velocity : float, m/s (``eps``)
        The regularisation: friction grows smoothly from 0 to its full value over about
        this sliding speed (a resting arm slides at ``eps rho / sqrt(1 - rho^2)``, ``rho``
        the ratio of the tangential load to the friction limit).
    stribeck_velocity : float, m/s (``v_s``)
        The sliding speed over which ``mu_static`` falls to ``mu_dynamic``.
    """

    stiffness: float = 1e6
    exponent: float = 1.5
    damping: float = 0.0
    mu_static: float = 0.0
    mu_dynamic: float = 0.0
    slip_velocity: float = 1e-3
    stribeck_velocity: float = 1e-2

    def __post_init__(self):
        ranges = dict(stiffness=CONTACT_STIFFNESS, exponent=CONTACT_EXPONENT, damping=CONTACT_DAMPING,
                      mu_static=FRICTION, mu_dynamic=FRICTION, slip_velocity=SLIP_VELOCITY,
                      stribeck_velocity=SLIP_VELOCITY)
        for name, rng in ranges.items():
            object.__setattr__(self, name, rng.check(f"ContactLaw.{name}", getattr(self, name)))
        if self.mu_dynamic > self.mu_static:
            raise ValueError(f"ContactLaw.mu_dynamic must be <= mu_static = {self.mu_static:g}, got "
                             f"{self.mu_dynamic:g}")

    def packed(self) -> np.ndarray:
        """The kernels' law array (LAW,); its last entry, the self-contact flag, is the
        :class:`Environment`'s."""
        out = np.zeros(LAW)
        out[:7] = (self.stiffness, self.exponent, self.damping, self.mu_static, self.mu_dynamic,
                   self.slip_velocity, self.stribeck_velocity)
        return out


@dataclass(frozen=True)
class PointLoad:
    """A wrench on the arm at backbone point ``alpha`` in [0, 1] of segment ``segment``:
    ``force`` (3,) N and ``moment`` (3,) N m, in the world frame, or in the slice's own frame
    (turning with it: a follower load) where ``local``."""

    segment: int
    alpha: float
    force: np.ndarray = field(default_factory=lambda: np.zeros(3))
    moment: np.ndarray = field(default_factory=lambda: np.zeros(3))
    local: bool = False

    def __post_init__(self):
        if isinstance(self.segment, (bool, np.bool_)) or not isinstance(self.segment, (int, np.integer)) \
                or self.segment < 0:
            raise ValueError(f"PointLoad.segment must be a segment index >= 0, got {self.segment!r}")
        a = as_real("PointLoad.alpha", self.alpha)
        if not 0.0 <= a <= 1.0:
            raise ValueError(f"PointLoad.alpha must be >= 0 and <= 1, got {a:g}")
        object.__setattr__(self, "segment", int(self.segment))
        object.__setattr__(self, "alpha", a)
        object.__setattr__(self, "force", as_vector("PointLoad.force", self.force, 3))
        object.__setattr__(self, "moment", as_vector("PointLoad.moment", self.moment, 3))
        object.__setattr__(self, "local", as_bool("PointLoad.local", self.local))


class Contacts(NamedTuple):
    """The active contacts of one state (:meth:`qchain.Chain.contacts`), ``c`` of them, and the
    generalised force they exert.

    Attributes
    ----------
    segment : (c,) int            the segment touching.
    alpha : (c,) float            its contact point's slice coordinate in (0, 1).
    obstacle : (c,) int           index into ``Environment.obstacles``.
    penetration : (c,) float      m.
    point : (c, 3) float          the contact point on the arm's surface, world frame (m).
    normal : (c, 3) float         the obstacle's outward normal there, world frame.
    force : (c, 3) float          the force on the arm, world frame (N).
    slip : (c,) float             the surface point's sliding speed (m/s).
    tau : (nv,) float             the generalised force of all of them (the chain's coordinates).
    """

    segment: np.ndarray
    alpha: np.ndarray
    obstacle: np.ndarray
    penetration: np.ndarray
    point: np.ndarray
    normal: np.ndarray
    force: np.ndarray
    slip: np.ndarray
    tau: np.ndarray

    @classmethod
    def from_records(cls, rec: np.ndarray, tau: np.ndarray) -> "Contacts":
        return cls(rec[:, 0].astype(np.int64), rec[:, 1].copy(), rec[:, 2].astype(np.int64), rec[:, 3].copy(),
                   rec[:, 4:7].copy(), rec[:, 7:10].copy(), rec[:, 10:13].copy(), rec[:, 13].copy(), tau)


#: the ripple of the chain of balls :func:`contact_nodes` allows, as a fraction of the penetration at rest
RIPPLE = 0.25
#: the weight of a weightless arm's rest load, as a fraction of Earth's gravity (m/s^2)
_MIN_GRAVITY = 1e-3


def _rest_penetration(law, mass: float, length: float, g: float) -> float:
    """m: how deep a segment of ``mass`` (kg) and rest ``length`` (m) lying on a flat obstacle
    sinks under gravity ``g`` (m/s^2): ``k d^e = m g / length``, per metre of tube."""
    return (mass * max(g, _MIN_GRAVITY) / (length * law.stiffness)) ** (1.0 / law.exponent)


def contact_nodes(segments, law, gravity, ripple: float = RIPPLE) -> int:
    """The fewest contact points a segment that draw every segment's tube within ``ripple``
    times its penetration at rest (docs/contact.md, "Which nodes").

    Between two balls ``h = l0 / nodes`` apart the chain of balls lies ``~ h^2 / (8 r_s)``
    inside the tube; over a convex obstacle of radius ``rho`` less (``h^2 / (8 (r_s + rho))``).
    Kept below ``ripple d0``, ``d0`` the depth a segment sinks lying on a flat obstacle under its
    own weight (:class:`ContactLaw` ``k d0^e = m g / l0``):
    ``nodes >= l0 / sqrt(8 ripple r_s d0)``; and the last ball covers the tube's end
    (``h / 2 <= r_s``). The largest over the segments, within ``CONTACT_NODES`` (1 to 64).

    Parameters
    ----------
    segments : sequence of qchain.Segment (or anything with ``length`` m, ``radius`` m, ``mass`` kg)
    law : ContactLaw
    gravity : (3,) m/s^2
        A weightless arm is reckoned at 1e-3 m/s^2 (a milli-g rest load), as
        :meth:`Environment.time_scale` does.
    ripple : float
        The allowed ripple over the rest penetration, in (0, 1].
    """
    if not isinstance(law, ContactLaw):
        raise TypeError(f"law must be a ContactLaw, got {type(law).__name__}")
    ripple = as_real("ripple", ripple)
    if not 0.0 < ripple <= 1.0:
        raise ValueError(f"ripple must be in (0, 1] (a fraction of the penetration at rest), got {ripple!r}")
    g = float(np.linalg.norm(as_vector("gravity", gravity, 3)))
    need = int(CONTACT_NODES.low)
    for s in segments:
        d0 = _rest_penetration(law, s.mass, s.length, g)
        h = min(np.sqrt(8.0 * ripple * s.radius * d0), 2.0 * s.radius)
        need = max(need, int(np.ceil(s.length / h * (1.0 - 1e-12))))
    return int(min(need, CONTACT_NODES.high))


_SHAPES = (HalfSpace, Sphere, Capsule, Cylinder, Box)


@dataclass(frozen=True)
class Environment:
    """Obstacles, the contact law and point loads: everything outside the arm that pushes on it.

    Parameters
    ----------
    obstacles : sequence of HalfSpace, Sphere, Capsule, Cylinder, Box
    law : ContactLaw
    loads : sequence of PointLoad
    nodes : int
        Contact points along each segment (midpoints of ``nodes`` equal pieces).
    self_contact : bool
        Contact between segments at least two apart (neighbours share a root and always
        touch), with the same law, equal and opposite.
    """

    obstacles: Sequence = ()
    law: ContactLaw = field(default_factory=ContactLaw)
    loads: Sequence = ()
    nodes: int = 16
    self_contact: bool = False

    def __post_init__(self):
        obstacles = tuple(self.obstacles)
        if len(obstacles) > MAX_OBSTACLES:
            raise ValueError(f"Environment.obstacles: at most {MAX_OBSTACLES} obstacles, got {len(obstacles)}")
        for i, ob in enumerate(obstacles):
            if not isinstance(ob, _SHAPES):
                raise TypeError(f"Environment.obstacles[{i}] must be a HalfSpace, Sphere, Capsule, Cylinder or Box, "
                                f"got {type(ob).__name__}")
        if not isinstance(self.law, ContactLaw):
            raise TypeError(f"Environment.law must be a ContactLaw, got {type(self.law).__name__}")
        loads = tuple(self.loads)
        for i, ld in enumerate(loads):
            if not isinstance(ld, PointLoad):
                raise TypeError(f"Environment.loads[{i}] must be a PointLoad, got {type(ld).__name__}")
        object.__setattr__(self, "obstacles", obstacles)
        object.__setattr__(self, "loads", loads)
        object.__setattr__(self, "nodes", CONTACT_NODES.check("Environment.nodes", self.nodes))
        object.__setattr__(self, "self_contact", as_bool("Environment.self_contact", self.self_contact))
        object.__setattr__(self, "_packed", None)

    def time_scale(self, chain) -> float | None:
        """The contact's time scale (s), the shortest over the chain's segments: the period
        ``2 pi sqrt(m / k_eff)`` of one contact point's mass ``m = mass / nodes`` on the law's
        stiffness at the penetration where it carries its own weight,
        ``k_eff = e l k d*^(e - 1)``, ``l k d*^e = m g``; None without obstacles. An explicit
        method's step cannot exceed a fraction of it in contact; an implicit one's can."""
        if not self.obstacles and not self.self_contact:
            return None
        law = self.law
        g = float(np.linalg.norm(chain.gravity))
        periods = []
        for s in chain.segments:
            m = s.mass / self.nodes
            ell = s.length / self.nodes
            d = _rest_penetration(law, s.mass, s.length, g)
            k_eff = law.exponent * ell * law.stiffness * d ** (law.exponent - 1.0)
            periods.append(2.0 * np.pi * np.sqrt(m / k_eff))
        return float(min(periods))

    def check_segments(self, n: int) -> None:
        """Refuse a load on a segment the chain of ``n`` segments does not have."""
        for i, ld in enumerate(self.loads):
            if ld.segment >= n:
                raise ValueError(f"Environment.loads[{i}].segment must be < {n} (the chain's segments), got "
                                 f"{ld.segment}")

    def describe(self) -> list[dict]:
        """The obstacles as plain JSON-like data (lists, floats, strings; no numpy), world
        frame at ``t = 0``, for a recording's ``RunInfo.obstacles``: each a dict with
        ``"type"`` and the shape's parameters in m (``"halfspace"``: ``point``, ``normal``;
        ``"sphere"``: ``center``, ``radius``; ``"capsule"``, ``"cylinder"``: ``a``, ``b``,
        ``radius``; ``"box"``: ``center``, ``half_extents``, ``rotation`` (3 x 3, rows)), and
        ``"motion"``: None for a fixed obstacle, else its ``velocity`` (m/s), ``amplitude``
        (m), ``frequency`` (Hz) and ``phase`` (rad). Index ``i`` of the list is the
        ``obstacle`` index of :class:`Contacts`."""
        fields = {HalfSpace: ("point", "normal"), Sphere: ("center", "radius"), Capsule: ("a", "b", "radius"),
                  Cylinder: ("a", "b", "radius"), Box: ("center", "half_extents", "rotation")}
        out = []
        for ob in self.obstacles:
            d = {"type": type(ob).__name__.lower()}
            for name in fields[type(ob)]:
                value = getattr(ob, name)
                d[name] = np.asarray(value, dtype=float).tolist() if np.ndim(value) else float(value)
            m = ob.motion
            d["motion"] = None if m is None else {
                "velocity": np.asarray(m.velocity, dtype=float).tolist(),
                "amplitude": np.asarray(m.amplitude, dtype=float).tolist(),
                "frequency": float(m.frequency), "phase": float(m.phase)}
            out.append(d)
        return out

    def packed(self) -> "PackedEnvironment":
        """The kernels' arrays (:class:`PackedEnvironment`), made once (the passes never write them)."""
        if self._packed is None:
            object.__setattr__(self, "_packed", self._pack())
        return self._packed

    def _pack(self) -> "PackedEnvironment":
        rows = [ob.row() for ob in self.obstacles]
        kind = np.array([k for k, _ in rows], dtype=np.int64)
        prm = np.array([r for _, r in rows]).reshape(len(rows), PARAMS)
        motion = np.array([np.zeros(MOTION) if ob.motion is None else ob.motion.row()
                           for ob in self.obstacles]).reshape(len(rows), MOTION)
        calpha = (np.arange(self.nodes) + 0.5) / self.nodes
        L = len(self.loads)
        seg = np.array([ld.segment for ld in self.loads], dtype=np.int64)
        alpha = np.array([ld.alpha for ld in self.loads], dtype=float)
        wrench = np.array([np.concatenate([ld.force, ld.moment]) for ld in self.loads]).reshape(L, 6)
        local = np.array([ld.local for ld in self.loads], dtype=np.bool_)
        law = self.law.packed()
        law[7] = 1.0 if self.self_contact else 0.0
        return PackedEnvironment(kind, prm, motion, law, calpha, seg, alpha, wrench, local)


class PackedEnvironment(NamedTuple):
    """An :class:`Environment` as the kernels take it: obstacles ``kind (m,) int64``,
    ``prm (m, PARAMS)`` at ``t = 0``, ``motion (m, MOTION)``; ``law (LAW,)``; contact points ``calpha (K,)``; loads ``seg (L,) int64``,
    ``alpha (L,)``, ``wrench (L, 6)``, ``local (L,) bool``."""

    kind: np.ndarray
    prm: np.ndarray
    motion: np.ndarray
    law: np.ndarray
    calpha: np.ndarray
    seg: np.ndarray
    alpha: np.ndarray
    wrench: np.ndarray
    local: np.ndarray


