"""Scene files: a soft arm, its inputs and a run, described in TOML.

``load_scene(path) -> Scene`` reads and validates a file; ``Scene.build()`` makes the
smallest model that represents the scene (and says what it dropped and why);
``Scene.simulate()`` runs it. ``qchain run SCENE.toml`` and ``qchain info SCENE.toml``
(:mod:`qchain.cli`) do the same from the command line. Units are SI throughout: m, kg,
s, Pa, rad, Hz.

File format
-----------
Declared once, in :mod:`qchain.scene_format` (every key's type, unit, range, default and
meaning); ``docs/scene-format.md`` is generated from it and holds an example. Vectors of
pressures, coordinates and velocities hold one entry per segment and chamber/coordinate,
flat (``3 n`` numbers) or nested (``n`` arrays of 3), ``n`` the number of segments after
``count`` is expanded.

Errors
------
:func:`load_scene` checks the whole file and raises one :class:`SceneError` listing every
problem, each as ``key: expected ..., found ...`` with the dotted key (``segments[1].radius``,
``pressure.values[2]``): unknown keys (with the closest known one), wrong types (booleans
are not numbers), numbers outside their range (:mod:`qchain.bounds`), NaN and infinities,
vectors of the wrong length, decreasing table times, unknown methods and kinds, initial
states outside the model, a fixed-step method without ``dt``, files too large or nested
too deep, and a run that would exceed its budget (:mod:`qchain.budget`: steps, samples,
memory, segments), named by the key that makes the cost.

Model reduction
---------------
``Scene.build()`` builds the smallest model that represents the scene and lists, in
``SceneModel.reductions``, what it dropped and why (``Scene.reductions`` for the scene's
own setting); ``SceneModel.kept`` says which reductions did not apply and why not.

* ``extensible = false`` (the file's choice, applied with or without ``reduce``): ``l`` is
  held at ``l0`` and the axial mode, the stiffest, is dropped.
* planar (automatic): ``uy`` is held at 0 in every segment when the scene is symmetric
  about the base's x-z plane, where the reduction is exact: every segment in curvature
  coordinates; gravity in that plane (expressed in the base frame at the start); chambers
  2 and 3 of every segment given the same pressure at all times (equal schedule
  parameters); ``uy = 0`` and ``uy' = 0`` at the start; a base motion in that plane (a
  translation along an axis with no y component, a rotation about the y axis; a floating
  base with no initial y velocity and no x or z angular velocity).
* nodes (automatic, with ``model.node_tolerance``): each segment gets the fewest Gauss
  nodes whose ``M_xi`` is within ``node_tolerance`` of a converged one
  (:func:`qchain.segment.nodes_for_tolerance`) at the largest bend the scene reaches:
  ``model.max_bend`` if given, else the estimate ``BEND_MARGIN`` (2) times the largest of
  the initial bends and the static bends (:func:`qchain.statics.equilibrium`) under the
  scene's peak pressures, plus ``sqrt(2 T0 l0 / EI)``, the bend that would store all the
  initial kinetic energy ``T0`` of the deformation rates (base held still); one angle, the
  largest over the segments, for all segments, since a moving arm carries its bends from
  segment to segment. The factor 2 is the overshoot of an undamped step response. The static shapes are solved with the base held at its start placement, for
  the pressures at the times where each segment's bending drive is largest (and
  smallest), over 65 even samples of the run and the schedule's corner times; a floating
  base is solved in zero gravity (a free-falling arm carries no gravity load); a
  translating base adds its peak acceleration to gravity in both directions, a rotating
  one is solved at both ends of its swing. Strongly driven scenes (resonance, fast base
  motion) can bend more: give ``max_bend`` there. ``qchain run`` prints the bends a run
  reached beside the one the nodes were sized for, and warns when a run went further.
  Without ``node_tolerance`` the segments keep ``nodes`` or
  :data:`qchain.segment.DEFAULT_NODES`.

``model.reduce = false`` (or ``Scene.build(reduce=False)``) turns the automatic reductions
off: same layout, all coordinates free, the default node count, for comparison.
"""

from __future__ import annotations

import functools
import math
import os
import stat
import tomllib
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pinocchio as pin

from . import scene_format as F
from .bounds import DURATION, VACUUM_GAUGE
from .budget import Budget, run_cost
from .chain import Chain
from .errors import describe_value
from .inputs import Constant, Ramp, Schedule, Sine, Step, Table
from .scene_format import (  # noqa: F401 (Problem, SceneError, _Checker, _show, _type_name re-exported)
    _MISSING, PLOTS, Problem, SceneError, _Checker, _is_number, _show, _type_name)
from .segment import CHAMBER_ANGLES, DEFAULT_NODES, Segment
from .simulate import DEFAULT_METHOD, FIXED_STEP, METHODS  # a scene may name any method, without case

__all__ = [
    "Scene",
    "SceneModel",
    "SceneError",
    "Problem",
    "SegmentSpec",
    "BaseSpec",
    "SineMotion",
    "load_scene",
    "parse_scene",
    "METHODS",
    "PLOTS",
    "BEND_MARGIN",
    "VACUUM_GAUGE",
]

#: Safety factor on the estimated static bend (the overshoot of an undamped step response).
BEND_MARGIN = 2.0
#: Even samples of the run at which the pressure schedule is scanned for the bend estimate.
BEND_SAMPLES = 65

_TOP_KEYS = F.TOP.keys()


# --------------------------------------------------------------------------------------
# parts of a scene


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


# --------------------------------------------------------------------------------------
# the built model


@dataclass(eq=False)
class SceneModel:
    """The model a scene needs, ready to simulate.

    Attributes
    ----------
    chain : Chain
    q0 : (nq,), v0 : (nv,)
        Initial state in the chain's layout.
    pressure : Schedule or None
        Chamber pressures ``t -> (3 n,)`` Pa.
    nodes : list of int
        Gauss nodes of each segment.
    max_bend : (n,) rad or None
        Bend each segment was sized for (with ``node_tolerance``).
    reductions : list of str
        What was dropped and why.
    kept : list of str
        Reductions that did not apply, and why not.
    reduced : bool
        Whether the automatic reductions were on.
    """

    chain: Chain
    q0: np.ndarray
    v0: np.ndarray
    pressure: Schedule | None
    nodes: list[int]
    max_bend: np.ndarray | None
    reductions: list[str]
    kept: list[str]
    reduced: bool


def _ranges(idx) -> str:
    """``[0, 1, 2, 5]`` -> ``"segments 0-2, 5"``."""
    idx = sorted(idx)
    parts = []
    start = prev = idx[0]
    for i in idx[1:] + [None]:
        if i is not None and i == prev + 1:
            prev = i
            continue
        parts.append(f"{start}" if start == prev else f"{start}-{prev}")
        if i is not None:
            start = prev = i
    word = "segment" if len(idx) == 1 else "segments"
    return f"{word} {', '.join(parts)}"


def _fmt(x: float) -> str:
    return f"{x:.3g}"


def _vec_str(v) -> str:
    return "(" + ", ".join(f"{x:.6g}" for x in v) + ")"


# --------------------------------------------------------------------------------------
# the scene


@dataclass(eq=False)
class Scene:
    """A validated scene file. Build the model with :meth:`build`, run it with :meth:`simulate`.

    Attributes
    ----------
    path : Path or None
        The file (None for a scene parsed from text).
    text : str
        The file's content.
    name, description : str
    segments : list of SegmentSpec
        One entry per segment, base to tip (``count`` expanded).
    base : BaseSpec
    gravity : (3,) m/s^2, world frame
    pressure : Schedule or None
        Chamber pressures ``t -> (3 n,)`` Pa.
    pressure_spec : dict
        The pressure table as parsed (``type`` and arrays of shape (3 n,) or (K, 3 n)).
    q_e0, v_e0 : (n, 3)
        Initial segment coordinates and rates (segment coordinates).
    duration : float, s
    method : str
        One of :data:`METHODS`.
    rtol, atol : float
    dt : float or None, s
    max_step : float, s (``inf`` when not given)
    reduce : bool
    node_tolerance, max_bend : float or None
    sample_rate : float, Hz
    output_folder : Path
    plots : tuple of str
    save : bool
    budget : Budget
        What a run may cost (:mod:`qchain.budget`; the file's ``[budget]`` table).
    """

    path: Path | None
    text: str
    name: str
    description: str
    segments: list[SegmentSpec]
    base: BaseSpec
    gravity: np.ndarray
    pressure: Schedule | None
    pressure_spec: dict
    q_e0: np.ndarray
    v_e0: np.ndarray
    duration: float
    method: str
    rtol: float
    atol: float
    dt: float | None
    max_step: float
    reduce: bool
    node_tolerance: float | None
    max_bend: float | None
    sample_rate: float
    output_folder: Path
    plots: tuple[str, ...]
    save: bool
    budget: Budget = field(default_factory=Budget)

    @property
    def n(self) -> int:
        """Number of segments."""
        return len(self.segments)

    # ------------------------------------------------------------------ model

    def build(self, reduce: bool | None = None, controlled: bool = False) -> SceneModel:
        """Build the model; see "Model reduction" in the module docstring.

        Parameters
        ----------
        reduce : bool, optional
            Automatic reductions (planar, node count) on or off; default the file's
            ``model.reduce``.
        controlled : bool
            The pressures will come from a controller, not from the file: the planar
            reduction, which needs chambers 2 and 3 equal at all times, is not made.
        """
        reduce = self.reduce if reduce is None else bool(reduce)
        reductions: list[str] = []
        kept: list[str] = []
        locked = [j for j, s in enumerate(self.segments) if not s.extensible]
        if locked:
            reductions.append(f"{_ranges(locked)}: l locked at l0 (extensible = false): axial mode dropped")
        if self.base.type == "fixed":
            reductions.append("fixed base: no base coordinates")
        planar = False
        why_not = "the pressures come from a controller" if controlled else self.planar_obstacle()
        if not reduce:
            kept.append("planar: not tried (reduce = false)")
        elif why_not is None:
            planar = True
            reductions.append(
                "planar: uy locked at 0 in every segment: gravity, pressures (p2 == p3), initial state and base "
                "motion symmetric about the base x-z plane"
            )
        else:
            kept.append(f"planar: not applicable: {why_not}")
        self._start_compiling(planar, controlled)
        nodes, max_bend, note = self._nodes(reduce, planar)
        (reductions if max_bend is not None else kept).append(note)  # sized from node_tolerance, or not
        segs = [s.segment(nodes=k) for s, k in zip(self.segments, nodes)]
        chain = self._chain(segs, planar)
        q0, v0 = self._initial_state(chain)
        return SceneModel(chain=chain, q0=q0, v0=v0, pressure=self.pressure, nodes=nodes, max_bend=max_bend,
                          reductions=reductions, kept=kept, reduced=reduce)

    def _start_compiling(self, planar: bool, controlled: bool) -> None:
        """On a cold cache, set the engine's compile going in worker processes while the model
        is built (the node count's static solves compile kernels of their own here)."""
        from .simulate import COMPILED

        if self.method in COMPILED and not controlled and all(s.coords == "curvature" for s in self.segments):
            from .engine import warmup

            warmup.start(self.method, planar_kernel=planar and self.base.type != "floating")

    @functools.cached_property
    def model(self) -> SceneModel:
        """The model with the file's own ``reduce`` setting (built once)."""
        return self.build()

    @property
    def reductions(self) -> list[str]:
        """What :attr:`model` dropped and why (human-readable)."""
        return self.model.reductions

    def _chain(self, segs, planar: bool) -> Chain:
        g = self.gravity
        if self.base.type == "fixed":
            return Chain(segs, base="fixed", gravity=g, base_placement=self.base.placement, planar=planar)
        if self.base.type == "floating":
            return Chain(segs, base="floating", gravity=g, planar=planar)
        return Chain(segs, base="prescribed", gravity=g, base_motion=self.base.motion, planar=planar)

    def _initial_state(self, chain: Chain) -> tuple[np.ndarray, np.ndarray]:
        q = np.empty(chain.nq)
        v = np.empty(chain.nv)
        if chain.floating:
            q[:7] = pin.SE3ToXYZQUAT(self.base.placement)
            v[:3] = self.base.velocity
            v[3:6] = self.base.angular_velocity
        o, ov = (7, 6) if chain.floating else (0, 0)
        q[o:] = self.q_e0.ravel()
        v[ov:] = self.v_e0.ravel()
        return q, v

    def planar_obstacle(self) -> str | None:
        """Why the scene is not symmetric about the base's x-z plane, or None if it is."""
        paper = [j for j, s in enumerate(self.segments) if s.coords != "curvature"]
        if paper:
            return f"{_ranges(paper)} in paper coordinates (uy is not one of their coordinates)"
        R0 = self.base.placement.rotation
        g_B = R0.T @ self.gravity
        if abs(g_B[1]) > 1e-12 * max(1.0, float(np.linalg.norm(self.gravity))):
            return f"gravity has a component {g_B[1]:.6g} m/s^2 along the base y axis"
        bad = [j for j in range(self.n) if self.q_e0[j, 2] != 0.0 or self.v_e0[j, 2] != 0.0]
        if bad:
            return f"{_ranges(bad)}: initial uy or its rate is not 0"
        why = _chambers_2_3_differ(self.pressure_spec, self.n)
        if why:
            return why
        b = self.base
        if b.type == "floating" and (b.velocity[1] != 0.0 or b.angular_velocity[0] != 0.0 or b.angular_velocity[2] != 0.0):
            return "the floating base's initial twist leaves the x-z plane (velocity y, or angular velocity x or z, not 0)"
        if b.type == "prescribed" and b.motion is not None:
            ax = b.motion.axis
            if b.motion.kind == "translation" and ax[1] != 0.0 and b.motion.amplitude != 0.0:
                return f"the base translates along {_vec_str(ax)}, out of the x-z plane"
            if b.motion.kind == "rotation" and (ax[0] != 0.0 or ax[2] != 0.0) and b.motion.amplitude != 0.0:
                return f"the base turns about {_vec_str(ax)}, not the y axis"
        return None

    def _nodes(self, reduce: bool, planar: bool):
        """Node counts, the bends they were sized for, and a note saying how."""
        explicit = [s.nodes for s in self.segments]
        if not reduce or self.node_tolerance is None:
            nodes = [DEFAULT_NODES if k is None else k for k in explicit]
            why = "reduce = false" if (reduce is False and self.node_tolerance is not None) else "no node_tolerance"
            return nodes, None, f"node count: {_list_or_one(nodes)} ({why}; default {DEFAULT_NODES})"
        from .segment import nodes_for_tolerance

        if self.max_bend is not None:
            theta = np.full(self.n, self.max_bend)
            how = f"max_bend = {_fmt(self.max_bend)} rad"
        else:
            theta, how = self.estimate_bend(planar)
        nodes = []
        for j, s in enumerate(self.segments):
            if s.nodes is not None:
                nodes.append(s.nodes)
            else:
                nodes.append(nodes_for_tolerance(s.segment(nodes=DEFAULT_NODES), float(theta[j]), self.node_tolerance))
        fixed = [j for j, s in enumerate(self.segments) if s.nodes is not None]
        extra = f"; {_ranges(fixed)} keep their own nodes" if fixed else ""
        bend = _fmt(theta[0]) if np.all(theta == theta[0]) else ", ".join(_fmt(x) for x in theta)
        note = (f"nodes: {_list_or_one(nodes)} from node_tolerance = {self.node_tolerance:g} at max bend {bend} rad "
                f"({how}){extra}")
        return nodes, theta, note

    def estimate_bend(self, planar: bool = False) -> tuple[np.ndarray, str]:
        """Largest bending angle of each segment the scene is expected to reach (rad, (n,)),
        and how it was found. See "Model reduction" in the module docstring."""
        from .statics import equilibrium

        segs = [s.segment(nodes=DEFAULT_NODES) for s in self.segments]
        conditions = self._static_conditions()
        candidates = self._pressure_candidates()
        static = np.zeros(self.n)
        failed = None
        for placement, g in conditions:
            ch = Chain(segs, base="fixed", gravity=g, base_placement=placement, planar=planar)
            q_guess = None
            for p in candidates:
                res = equilibrium(ch, p, q0=q_guess)
                if not res.success:
                    res = equilibrium(ch, p)
                if not res.success:
                    failed = (p, res.message)
                    break
                q_guess = res.q
                static = np.maximum(static, self._bends(ch, res.q))
            if failed:
                break
        initial = self._bends(None, None)
        ch0 = Chain(segs, base="fixed", gravity=np.zeros(3))  # deformation rates only: rigid motion bends nothing
        T0 = ch0.kinetic_energy(self.q_e0.ravel(), self.v_e0.ravel())
        EI = np.array([s.segment(nodes=1).bending_stiffness for s in self.segments])
        l0 = np.array([s.length for s in self.segments])
        kin = np.sqrt(2.0 * T0 * l0 / EI)
        if failed:
            r = np.array([s.radius for s in self.segments])
            p, msg = failed
            return l0 / r, (f"equilibrium failed at p = {_vec_str(p)} Pa ({msg}): sized for the largest bend the "
                            f"model allows, l0/r_s")
        theta = np.full(self.n, BEND_MARGIN * max(static.max(), initial.max()) + kin.max())
        parts = [f"{BEND_MARGIN:g} x the largest static bend under peak pressures"]
        if initial.max() > static.max():
            parts = [f"{BEND_MARGIN:g} x the largest initial bend"]
        if T0 > 0:
            parts.append(f"+ {_fmt(kin.max())} rad for the initial kinetic energy {T0:.3g} J")
        return theta, " ".join(parts) + ", any segment"

    def bends(self, chain: Chain, traj) -> np.ndarray:
        """Largest bending angle ``|kappa| l`` (rad) each segment reached in a trajectory, (n,)."""
        out = np.zeros(self.n)
        for q in traj.q:
            out = np.maximum(out, self._bends(chain, q))
        return out

    def _bends(self, chain, q) -> np.ndarray:
        """Bending angle ``kappa l`` of each segment at ``q`` (or at the initial state)."""
        out = np.empty(self.n)
        for j, s in enumerate(self.segments):
            qe = self.q_e0[j] if q is None else q[chain.q_slice(j)]
            kappa = qe[2] if s.coords == "paper" else math.hypot(qe[1], qe[2])
            out[j] = abs(kappa) * qe[0]
        return out

    def _static_conditions(self) -> list[tuple[pin.SE3, np.ndarray]]:
        """(base placement, gravity) pairs the static bend is estimated under."""
        b = self.base
        if b.type == "fixed":
            return [(b.placement, self.gravity)]
        if b.type == "floating":
            return [(b.placement, np.zeros(3))]
        m = b.motion
        if m.kind == "translation":
            a = m.peak_acceleration() * (m.mount.rotation @ m.axis)
            return [(m(0.0)[0], self.gravity), (m(0.0)[0], self.gravity + a), (m(0.0)[0], self.gravity - a)]
        return [(m(0.0)[0], self.gravity), (m.placement_at(m.amplitude), self.gravity),
                (m.placement_at(-m.amplitude), self.gravity)]

    def _pressure_candidates(self) -> list[np.ndarray]:
        """Pressure vectors at which the static bend is solved (see the module docstring)."""
        n = self.n
        if self.pressure is None:
            return [np.zeros(3 * n)]
        T = self.duration
        times = list(np.linspace(0.0, T, BEND_SAMPLES))
        spec = self.pressure_spec
        if spec["type"] == "step" and 0.0 <= spec["time"] <= T:
            times.append(spec["time"])
        elif spec["type"] == "ramp":
            times += [t for t in (spec["t0"], spec["t1"]) if 0.0 <= t <= T]
        elif spec["type"] == "table":
            times += [t for t in spec["times"] if 0.0 <= t <= T]
        elif spec["type"] == "sine":  # the extremes of every chamber's sine inside the run
            f = spec["frequency"]
            ph = spec["phase"]
            for k in range(3 * n):
                if f[k] > 0:
                    period = 1.0 / f[k]
                    for target in (0.25, 0.75):
                        t0 = ((target - ph[k] / (2 * math.pi)) % 1.0) * period
                        times += list(np.arange(t0, T, period)[:64])
        P = np.array([self.pressure(t) for t in sorted(set(times))])
        c = np.exp(1j * np.asarray(CHAMBER_ANGLES))
        drive = np.abs(P.reshape(len(P), n, 3) @ c)  # (K, n): bending drive per segment (arbitrary units)
        pick = set(int(k) for k in np.argmax(drive, axis=0))
        pick.add(int(np.argmax(drive.sum(axis=1))))
        pick.add(int(np.argmin(drive.sum(axis=1))))
        return [P[k] for k in sorted(pick)]

    # ------------------------------------------------------------------ run

    def sample_times(self, duration: float | None = None) -> np.ndarray:
        """Output times ``k / sample_rate`` from 0 up to the run's end (included), s; a
        :class:`qchain.budget.BudgetError` if there would be more than the budget allows."""
        T = self.duration if duration is None else DURATION.check("duration", duration)
        self.check_budget(T)
        k = np.arange(0, int(math.floor(T * self.sample_rate * (1 + 1e-12))) + 1)
        t = k / self.sample_rate
        t = t[t < T - 1e-9 * max(1.0, T)]
        return np.append(t, T)

    def simulate(self, *, reduce: bool | None = None, model: SceneModel | None = None,
                 duration: float | None = None, pressure=None, on_sample=None, progress: bool = False,
                 controller_rate: float | None = None):
        """Run the scene; returns a :class:`qchain.trajectory.Trajectory` sampled at
        :meth:`sample_times`.

        Parameters
        ----------
        reduce : bool, optional
            Build with or without the automatic reductions (ignored if ``model`` is given).
        model : SceneModel, optional
            A model built before (:meth:`build`); default :attr:`model` or a new build.
        duration : float, s, optional
            Override the file's duration.
        pressure : callable ``(t, q, v) -> (3 n,)`` or Schedule, optional
            Pressures instead of the file's (e.g. a controller; build the model with
            ``controlled=True`` then).
        on_sample : callable ``(t, q, v, p)``, optional
            Called at every output sample.
        progress : bool
            Progress bar on stderr.
        controller_rate : float, Hz, optional
            Sample a controller ``pressure`` at this rate and hold it (zero-order hold): the
            run stays in compiled code between samples (:func:`qchain.simulate.simulate`).
        """
        from .simulate import simulate

        T = self.duration if duration is None else DURATION.check("duration", duration)
        self.check_budget(T)
        if self.method in FIXED_STEP and self.dt > T:
            raise ValueError(f"duration must be >= the scene's step dt = {self.dt:g} s, got {T:g} s")
        if model is None:
            model = self.model if reduce is None or reduce == self.reduce else self.build(reduce)
        return simulate(
            model.chain, model.q0, model.v0, (0.0, T), pressure=model.pressure if pressure is None else pressure,
            method=self.method, dt=self.dt,
            rtol=self.rtol, atol=self.atol, t_eval=self.sample_times(T), on_sample=on_sample, progress=progress,
            max_step=self.max_step, controller_rate=controller_rate, budget=self.budget,
        )

    def cost(self, duration: float | None = None):
        """What a run of the scene (``duration`` s, default the file's) costs:
        :class:`qchain.budget.Cost`."""
        T = self.duration if duration is None else duration
        return _cost(self.n, self.base.type, self.method, self.dt, self.max_step, T, self.sample_rate,
                     _frequency(self.pressure_spec, self.base))

    def check_budget(self, duration: float | None = None) -> None:
        """Raise :class:`qchain.budget.BudgetError` if a run of ``duration`` s (default the
        file's) would exceed :attr:`budget`, naming the bound and how to raise it."""
        self.budget.check(self.cost(duration), how="raise it in the scene's [budget] table")

    def check_output(self, folder: str | os.PathLike | None = None) -> Path:
        """Make sure a run can write its outputs to ``folder`` (default ``output.folder``)
        before it starts: the folder is made, must be a writable folder (not a file, not
        read-only) on a file system with room for the trajectory; returns it.

        Raises
        ------
        SceneError
            naming ``output.folder``, the folder and what is wrong with it.
        """
        import shutil
        import tempfile

        p = Path(self.output_folder if folder is None else folder)

        def fail(expected, found):
            raise SceneError(str(self.path) if self.path else "<scene>", [Problem("output.folder", expected, found)])

        if "\0" in str(p):
            fail("a folder path without a NUL character", _show(str(p).replace("\0", "\\0")))
        for parent in [p, *p.parents]:
            if parent.exists() and not parent.is_dir():
                fail("a folder (or a path where one can be made)", f"{parent} is a file")
        try:
            p.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=p) as fh:
                fh.write(b"qchain")
        except OSError as err:
            fail("a folder qchain can write in", f"{p}: {err.strerror or err}")
        cost = self.cost()
        need = cost.samples * 8.0 * (6 + 4 * 3 * self.n) + 2**20 * (len(self.plots) + 1)
        free = shutil.disk_usage(p).free
        if free < need:
            fail(f"room for the outputs, about {need / 2**20:.3g} MiB", f"{free / 2**20:.3g} MiB free in {p}")
        return p

    # ------------------------------------------------------------------ report

    def describe(self, model: SceneModel | None = None) -> list[str]:
        """Lines describing the scene and the model it builds (``qchain info``)."""
        m = self.model if model is None else model
        ch = m.chain
        lines = [f"scene: {self.path if self.path else '<text>'}" + (f" ({self.name})" if self.name else "")]
        if self.description:
            lines.append(f"  {self.description}")
        kinds = sorted({(s.coords, s.actuation) for s in self.segments})
        lines.append(f"segments: {self.n} ({'; '.join(f'{c} coordinates, {a} actuation' for c, a in kinds)})")
        b = self.base
        if b.type == "fixed":
            lines.append(f"base: fixed at {_vec_str(b.position)} m, rpy {_vec_str(b.rpy)} rad")
        elif b.type == "floating":
            lines.append(f"base: floating, starts at {_vec_str(b.position)} m, rpy {_vec_str(b.rpy)} rad, "
                         f"velocity {_vec_str(b.velocity)} m/s, angular velocity {_vec_str(b.angular_velocity)} rad/s")
        else:
            mo = b.motion
            unit = "m" if mo.kind == "translation" else "rad"
            lines.append(f"base: prescribed {mo.kind} along/about {_vec_str(mo.axis)} (mount frame), amplitude "
                         f"{mo.amplitude:g} {unit}, {mo.frequency:g} Hz, phase {mo.phase:g} rad; mount at "
                         f"{_vec_str(b.position)} m, rpy {_vec_str(b.rpy)} rad")
        lines.append(f"gravity: {_vec_str(self.gravity)} m/s^2")
        lines.append(f"model: nq = {ch.nq}, nv = {ch.nv}, free dofs = {ch.nv_active}, pressure inputs = {ch.nu}, "
                     f"nodes = {_list_or_one(m.nodes)}")
        lines.append(f"reductions ({'on' if m.reduced else 'off'}):")
        lines += [f"  - {r}" for r in m.reductions] or ["  - none"]
        if m.kept:
            lines.append("not reduced:")
            lines += [f"  - {k}" for k in m.kept]
        lines.append(f"pressure: {_pressure_summary(self.pressure_spec)}")
        meth = f"{self.method}, dt = {self.dt:g} s" if self.method in FIXED_STEP else \
            f"{self.method}, rtol = {self.rtol:g}, atol = {self.atol:g}" + \
            (f", max_step = {self.max_step:g} s" if math.isfinite(self.max_step) else "")
        lines.append(f"simulation: {self.duration:g} s, {meth}")
        lines.append(f"output: {self.sample_rate:g} Hz to {self.output_folder}, plots: "
                     f"{', '.join(self.plots) if self.plots else 'none'}{', trajectory.npz' if self.save else ''}")
        return lines


def _list_or_one(xs) -> str:
    xs = list(xs)
    return f"{xs[0]} per segment" if all(x == xs[0] for x in xs) else ", ".join(str(x) for x in xs)


def _pressure_summary(spec: dict) -> str:
    t = spec.get("type")
    if t is None:
        return "none (all chambers at 0 Pa)"
    if t == "constant":
        return f"constant, peak {np.max(np.abs(spec['value'])):.4g} Pa"
    if t == "step":
        return f"step at {spec['time']:g} s, to peak {np.max(np.abs(spec['after'])):.4g} Pa"
    if t == "ramp":
        return f"ramp {spec['t0']:g} s -> {spec['t1']:g} s, to peak {np.max(np.abs(spec['end'])):.4g} Pa"
    if t == "sine":
        f = spec["frequency"]
        fs = f"{f[0]:g} Hz" if np.all(f == f[0]) else f"{f.min():g}-{f.max():g} Hz"
        return (f"sine, {fs}, amplitude up to {np.max(np.abs(spec['amplitude'])):.4g} Pa, segment phase "
                f"{spec['segment_phase']:g} rad")
    return f"table of {len(spec['times'])} times, {spec['times'][0]:g} s -> {spec['times'][-1]:g} s"


def _chambers_2_3_differ(spec: dict, n: int) -> str | None:
    """Why chambers 2 and 3 of some segment do not get the same pressure at all times, or None."""
    t = spec.get("type")
    if t is None:
        return None
    i2 = np.arange(n) * 3 + 1
    i3 = i2 + 1

    def differ(name):
        a = np.atleast_2d(spec[name])
        bad = np.flatnonzero(np.any(a[:, i2] != a[:, i3], axis=0))
        return None if bad.size == 0 else f"pressure.{name}: chambers 2 and 3 differ in {_ranges(bad.tolist())}"

    names = {"constant": ["value"], "step": ["before", "after"], "ramp": ["start", "end"], "table": ["values"]}
    if t in names:
        for name in names[t]:
            why = differ(name)
            if why:
                return why
        return None
    # sine: equal offsets, and equal sine terms (both zero, or equal amplitude, frequency, phase)
    why = differ("offset")
    if why:
        return why
    A, f, ph = spec["amplitude"], spec["frequency"], spec["phase"]
    bad = []
    for j in range(n):
        a, b = i2[j], i3[j]
        zero = lambda k: A[k] == 0.0 or (f[k] == 0.0 and math.sin(ph[k]) == 0.0)  # noqa: E731
        if zero(a) and zero(b):
            continue
        same_phase = abs(math.remainder(ph[a] - ph[b], 2 * math.pi)) <= 1e-12
        if not (A[a] == A[b] and f[a] == f[b] and same_phase):
            bad.append(j)
    return None if not bad else f"pressure: the sines of chambers 2 and 3 differ in {_ranges(bad)}"


# --------------------------------------------------------------------------------------
# reading


def _file_problem(p: Path) -> Problem | None:
    """Why ``p`` cannot be read as a scene file (missing, a folder, a FIFO or device, too
    large), or None; opened without blocking, so a FIFO cannot hang the check."""
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        return Problem("(file)", "an existing scene file", "no such file")
    except IsADirectoryError:
        return Problem("(file)", "a scene file", "a folder")
    except (OSError, ValueError) as err:
        return Problem("(file)", "a readable scene file", str(err))
    try:
        st = os.fstat(fd)
    finally:
        os.close(fd)
    if stat.S_ISDIR(st.st_mode):
        return Problem("(file)", "a scene file", "a folder")
    if not stat.S_ISREG(st.st_mode):
        kind = ("a FIFO" if stat.S_ISFIFO(st.st_mode) else "a device" if stat.S_ISCHR(st.st_mode) or
                stat.S_ISBLK(st.st_mode) else "a socket" if stat.S_ISSOCK(st.st_mode) else "not a regular file")
        return Problem("(file)", "a regular scene file", kind)
    if st.st_size > F.MAX_SCENE_BYTES:
        return Problem("(file)", f"a scene file of at most {F.MAX_SCENE_BYTES} bytes", f"{st.st_size} bytes")
    return None


def load_scene(path: str | os.PathLike) -> Scene:
    """Read and validate a scene file (TOML); ``docs/scene-format.md`` gives the format.

    Parameters
    ----------
    path : str or os.PathLike
        A regular file of at most :data:`qchain.scene_format.MAX_SCENE_BYTES` bytes of UTF-8.

    Raises
    ------
    TypeError
        ``path`` is not a path.
    SceneError
        listing every problem (file, dotted key, what was expected, what was found), for
        a file that cannot be read (missing, a folder, a FIFO or device, too large, not
        UTF-8), is not valid TOML, or does not describe a scene.
    """
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"load_scene: path must be a str or os.PathLike naming a scene file, got "
                        f"{describe_value(path)}")
    p = Path(path)
    bad = _file_problem(p)
    if bad is not None:
        raise SceneError(str(p), [bad])
    try:
        with open(p, "rb") as fh:
            data = fh.read(F.MAX_SCENE_BYTES + 1)
        text = data.decode("utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise SceneError(str(p), [Problem("(file)", "a readable UTF-8 text file", str(err))]) from None
    return parse_scene(text, p)


def parse_scene(text: str, path: str | os.PathLike | None = None) -> Scene:
    """Validate the TOML ``text`` of a scene; ``path`` names it in errors and sets the
    default output folder (``out/<stem>``).

    Raises
    ------
    TypeError
        ``text`` is not a ``str`` (or UTF-8 ``bytes``), or ``path`` not a path.
    SceneError
        every problem of the scene (see :func:`load_scene`).
    """
    if path is not None and not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"parse_scene: path must be None, a str or os.PathLike, got {describe_value(path)}")
    where = str(path) if path is not None else "<scene>"
    if isinstance(text, (bytes, bytearray)):
        try:
            text = bytes(text).decode("utf-8")
        except UnicodeDecodeError as err:
            raise SceneError(where, [Problem("(file)", "UTF-8 text", str(err))]) from None
    if not isinstance(text, str):
        raise TypeError(f"parse_scene: text must be the TOML text of a scene (a str), got {describe_value(text)}")
    bad = F.nesting_problem(text)
    if bad is not None:
        raise SceneError(where, [bad])
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise SceneError(where, [Problem("(file)", "valid TOML", f"a syntax error: {err}")]) from None
    ck = _Checker()
    ck.keys(raw, "", F.TOP.keys())
    name = ck.field(raw, F.TOP["name"], "name", "") or ""
    description = ck.field(raw, F.TOP["description"], "description", "") or ""
    gravity = ck.field(raw, F.TOP["gravity"], "gravity", default=(0.0, 0.0, -9.81))
    if gravity is None:
        gravity = np.array([0.0, 0.0, -9.81])
    budget = _budget(ck, raw)

    # model
    mt = ck.table(raw, "model", "model") or {}
    ck.keys(mt, "model", F.MODEL.keys())
    reduce = ck.field(mt, F.MODEL["reduce"], "model.reduce", True)
    node_tol = ck.field(mt, F.MODEL["node_tolerance"], "model.node_tolerance")
    max_bend = ck.field(mt, F.MODEL["max_bend"], "model.max_bend")
    if "max_bend" in mt and "node_tolerance" not in mt:
        ck.add("model.max_bend", "model.node_tolerance beside it (max_bend only sizes the node count)",
               "max_bend without node_tolerance")

    segments = _segments(ck, raw, budget)
    n = len(segments) if segments is not None else None
    base = _base(ck, raw)

    # simulation
    S = F.SIMULATION
    st = ck.table(raw, "simulation", "simulation", required=True)
    have_sim = st is not None
    st = st or {}
    ck.keys(st, "simulation", S.keys())
    duration = ck.number(st, "duration", "simulation.duration", "s", required=have_sim, bounds=S["duration"].range)
    method = ck.choice(st, "method", "simulation.method", METHODS, default=DEFAULT_METHOD, ignore_case=True)
    rtol = ck.field(st, S["rtol"], "simulation.rtol", 1e-6)
    atol = ck.field(st, S["atol"], "simulation.atol", 1e-8)
    dt = ck.field(st, S["dt"], "simulation.dt")
    max_step = ck.field(st, S["max_step"], "simulation.max_step", math.inf)
    if method in FIXED_STEP and "dt" not in st:
        ck.add("simulation.dt", f"a step > 0 (s): method {method!r} takes fixed steps", "nothing")
    if method not in FIXED_STEP and "dt" in st:
        ck.add("simulation.dt", f"no dt: method {method!r} chooses its own steps (use max_step to bound them, or "
               "method rk4/midpoint for fixed steps)", _show(st["dt"]))
    if method in FIXED_STEP and "max_step" in st:
        ck.add("simulation.max_step", f"no max_step: method {method!r} takes fixed steps of dt", _show(st["max_step"]))
    if dt is not None and duration is not None and dt > duration:
        ck.add("simulation.dt", f"a step <= duration = {duration:g} s", _show(st["dt"]))

    pressure, pspec = _pressure(ck, raw, n)
    q_e0, v_e0 = _initial(ck, raw, segments)

    # output
    O = F.OUTPUT
    ot = ck.table(raw, "output", "output") or {}
    ck.keys(ot, "output", O.keys())
    rate = ck.field(ot, O["sample_rate"], "output.sample_rate", 100.0)
    stem = Path(path).stem if path is not None else "scene"
    folder = ck.path(ot, "folder", "output.folder", f"out/{stem}")
    plots = ot.get("plots", ["tip"])
    if not isinstance(plots, list) or not all(isinstance(x, str) for x in plots):
        ck.add("output.plots", f"an array of names from {', '.join(PLOTS)}", f"{_type_name(plots)} {_show(plots)}")
        plots = []
    else:
        for i, x in enumerate(plots):
            if x not in PLOTS:
                ck.choice({"p": x}, "p", f"output.plots[{i}]", PLOTS)
                ck.problems[-1] = Problem(f"output.plots[{i}]", ck.problems[-1].expected.replace('"', ""), _show(x))
        if "momentum" in plots and base is not None and base.type != "floating":
            ck.add("output.plots", "'momentum' only with a floating base (a fixed or moving mount exchanges momentum)",
                   f"base.type = {base.type!r}")
    save = ck.field(ot, O["save"], "output.save", True)

    if not ck.problems:  # the run's cost, from valid values only
        cost = _cost(n, base.type, method, dt, max_step, duration, rate, _frequency(pspec, base))
        for key, expected, found in budget.problems(cost):
            ck.add(_cost_key(key, cost, method, pspec, base), f"{expected} (budget.{key}; raise it in [budget] to "
                   "allow more)", found)

    if ck.problems:
        raise SceneError(where, ck.problems)
    return Scene(
        path=Path(path) if path is not None else None, text=text, name=name, description=description,
        segments=segments, base=base, gravity=gravity, pressure=pressure, pressure_spec=pspec, q_e0=q_e0,
        v_e0=v_e0, duration=duration, method=method, rtol=rtol, atol=atol, dt=dt, max_step=max_step,
        reduce=reduce, node_tolerance=node_tol, max_bend=max_bend, sample_rate=rate, output_folder=Path(folder),
        plots=tuple(dict.fromkeys(plots)), save=save, budget=budget,
    )


def _budget(ck: _Checker, raw: dict) -> Budget:
    bt = ck.table(raw, "budget", "budget") or {}
    ck.keys(bt, "budget", F.BUDGET.keys())
    d = Budget()
    vals = {k: ck.field(bt, F.BUDGET[k], f"budget.{k}", getattr(d, k)) for k in F.BUDGET.keys()}
    return Budget(**vals)


def _frequency(pspec: dict, base: BaseSpec | None) -> float:
    """The fastest sine input's or base motion's frequency (Hz) whose amplitude is not zero."""
    f = 0.0
    if pspec.get("type") == "sine":
        live = pspec["frequency"][pspec["amplitude"] != 0]
        f = float(live.max()) if live.size else 0.0
    if base is not None and base.motion is not None and base.motion.amplitude != 0:
        f = max(f, base.motion.frequency)
    return f


def _samples(duration: float, rate: float) -> float:
    """How many output samples :meth:`Scene.sample_times` gives (without making them)."""
    return math.floor(duration * rate * (1 + 1e-12)) + 2.0


def _cost(n, base_type, method, dt, max_step, duration, rate, frequency):
    floating = base_type == "floating"
    nq, nv = (7 if floating else 0) + 3 * n, (6 if floating else 0) + 3 * n
    return run_cost(duration=duration, method=method, fixed_step=method in FIXED_STEP, dt=dt, max_step=max_step,
                    frequency=frequency, samples=_samples(duration, rate),
                    samples_why=f"duration {duration:g} s x sample_rate {rate:g} Hz", nq=nq, nv=nv, nu=3 * n)


def _cost_key(budget_key: str, cost, method: str, pspec: dict, base) -> str:
    """The scene key that makes a cost over budget (the one to change, beside the budget)."""
    if budget_key == "max_steps":
        if method in FIXED_STEP:
            return "simulation.dt"
        if cost.steps_why.startswith("duration"):
            return "simulation.max_step"
        f_p = _frequency(pspec, None)
        f_b = base.motion.frequency if base is not None and base.motion is not None else 0.0
        return "pressure.frequency" if f_p >= f_b else "base.motion.frequency"
    if budget_key == "max_samples":
        return "output.sample_rate"
    return "segments" if cost.matrix_memory > cost.memory / 2 else "output.sample_rate"


def _segments(ck: _Checker, raw: dict, budget: Budget) -> list[SegmentSpec] | None:
    segs = raw.get("segments", _MISSING)
    if segs is _MISSING:
        ck.add("segments", "an array of tables [[segments]], base to tip", "nothing (the key is required)")
        return None
    if not isinstance(segs, list) or not segs or not all(isinstance(s, dict) for s in segs):
        ck.add("segments", "a non-empty array of tables [[segments]]", f"{_type_name(segs)} {_show(segs)}")
        return None
    T = F.SEGMENT
    out: list[SegmentSpec] = []
    ok = True
    total = 0
    start = len(ck.problems)
    for i, s in enumerate(segs):
        path = f"segments[{i}]"
        ck.keys(s, path, T.keys())
        count = ck.field(s, T["count"], f"{path}.count", default=1)
        total += count if count is not None else 1
        if total > budget.max_segments:
            ck.add(f"{path}.count" if "count" in s else "segments",
                   f"at most budget.max_segments = {budget.max_segments} segments in all, count expanded (raise it "
                   "in [budget] to allow more)", f"{total} segments up to {path}")
            return None
        vals = {}
        for k in ("length", "radius", "mass", "chamber_area", "chamber_radius", "youngs_modulus"):
            vals[k] = ck.field(s, T[k], f"{path}.{k}")
        vals["damping"] = ck.field(s, T["damping"], f"{path}.damping", 0.0)
        vals["coords"] = ck.field(s, T["coords"], f"{path}.coords", "curvature")
        vals["actuation"] = ck.field(s, T["actuation"], f"{path}.actuation", "volume")
        vals["extensible"] = ck.field(s, T["extensible"], f"{path}.extensible", True)
        vals["nodes"] = ck.field(s, T["nodes"], f"{path}.nodes")
        if len(ck.problems) > start:
            ok = False
            start = len(ck.problems)
            continue
        r, rc, A = vals["radius"], vals["chamber_radius"], vals["chamber_area"]
        outer = rc + math.sqrt(A / math.pi)
        if outer > r:
            ck.add(f"{path}.chamber_radius", f"chambers inside the segment: chamber_radius + sqrt(chamber_area/pi) "
                   f"<= radius = {r:g} m", f"{rc:g} + {math.sqrt(A / math.pi):.6g} = {outer:.6g} m")
            ok = False
            start = len(ck.problems)
            continue
        spec = SegmentSpec(**vals, source=path)
        try:
            spec.segment(nodes=spec.nodes)
        except (ValueError, TypeError) as err:  # anything the constructor checks beyond the above
            ck.add(path, "a valid segment", str(err))
            ok = False
            start = len(ck.problems)
            continue
        for c in range(count or 1):
            out.append(replace(spec, source=path if count == 1 else f"{path} (copy {c + 1} of {count})"))
    return out if ok else None


def _base(ck: _Checker, raw: dict) -> BaseSpec | None:
    T = F.BASE
    bt = ck.table(raw, "base", "base")
    if bt is None:
        return BaseSpec() if "base" not in raw else None
    kind = ck.field(bt, T["type"], "base.type", "fixed")
    allowed = T.keys(kind) if kind is not None else T.keys()
    for k in bt:
        if k in T.keys() and k not in allowed:
            ck.add(f"base.{k}", f"only the keys {', '.join(allowed)} with base.type = {kind!r}", f"the key {k!r}")
    ck.keys(bt, "base", T.keys())
    start = len(ck.problems)
    pos = ck.field(bt, T["position"], "base.position", default=(0.0, 0.0, 0.0))
    rpy = ck.field(bt, T["rpy"], "base.rpy", default=(0.0, 0.0, 0.0))
    vel = ck.field(bt, T["velocity"], "base.velocity", default=(0.0, 0.0, 0.0))
    ang = ck.field(bt, T["angular_velocity"], "base.angular_velocity", default=(0.0, 0.0, 0.0))
    motion = None
    mount = pin.SE3(pin.rpy.rpyToMatrix(*rpy), pos) if rpy is not None and pos is not None else pin.SE3.Identity()
    if kind == "prescribed":
        M = F.MOTION
        mt = ck.table(bt, "motion", "base.motion", required=True)
        if mt is not None:
            ck.keys(mt, "base.motion", M.keys())
            mkind = ck.field(mt, M["type"], "base.motion.type")
            axis = ck.field(mt, M["axis"], "base.motion.axis")
            if axis is not None and float(np.linalg.norm(axis)) == 0.0:
                ck.add("base.motion.axis", "a non-zero direction", _show(mt["axis"]))
                axis = None
            amp = ck.number(mt, "amplitude", "base.motion.amplitude", "m" if mkind == "translation" else "rad",
                            required=True, bounds=M["amplitude"].range)
            freq = ck.field(mt, M["frequency"], "base.motion.frequency")
            phase = ck.field(mt, M["phase"], "base.motion.phase", 0.0)
            if len(ck.problems) == start and mkind is not None:
                motion = SineMotion(kind=mkind, axis=axis / np.linalg.norm(axis), amplitude=amp, frequency=freq,
                                    phase=phase, mount=mount)
    if len(ck.problems) > start or kind is None:
        return None
    return BaseSpec(type=kind, position=pos, rpy=rpy, velocity=vel, angular_velocity=ang, motion=motion)


def _where(k: int) -> str:
    return f"index {k} (segment {k // 3}, chamber {k % 3 + 1})"


def _pressure(ck: _Checker, raw: dict, n: int | None) -> tuple[Schedule | None, dict]:
    T = F.PRESSURE
    P = T["value"].range  # every pressure vector's range
    pt = ck.table(raw, "pressure", "pressure")
    if pt is None:
        return None, {}
    kind = ck.field(pt, T["type"], "pressure.type")
    if kind is None:
        return None, {}
    ck.keys(pt, "pressure", T.keys(kind))
    start = len(ck.problems)

    def gauge(key, arr, rng=P):
        """Pressures in the range of a chamber (:data:`qchain.bounds.PRESSURE`: a vacuum to 1 GPa)."""
        if arr is not None and rng.outside(arr).any():
            k = int(np.flatnonzero(rng.outside(arr))[0])
            what = f"gauge pressures {rng.text()} (a vacuum to 1 GPa)" if rng is P else f"values {rng.text()}"
            ck.add(f"pressure.{key}", what, f"{arr[k]:g} Pa at {_where(k)}")
            return None
        return arr

    def vec(key, required=False):
        if key not in pt:
            if required:
                ck.add(f"pressure.{key}", "a pressure vector (Pa), one value a chamber", "nothing (the key is required)")
            return None if required or n is None else np.zeros(3 * n)
        arr = ck.per_segment(pt[key], f"pressure.{key}", n, "Pa")
        return None if arr is None else gauge(key, arr.ravel(), T[key].range)

    def scalar_or_vec(key, default):
        f = T[key]
        if key not in pt:
            return None if n is None else np.full(3 * n, default)
        v = pt[key]
        if _is_number(v):
            x = ck.number(pt, key, f"pressure.{key}", f.range.unit, bounds=f.range)
            return None if x is None or n is None else np.full(3 * n, x)
        arr = ck.per_segment(v, f"pressure.{key}", n, f.range.unit)
        if arr is None:
            return None
        bad = f.range.outside(arr.ravel())
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            ck.add(f"pressure.{key}", f"values {f.range.text()}", f"{arr.ravel()[k]:g} at index {k}")
            return None
        return arr.ravel()

    spec: dict = {"type": kind}
    if kind == "constant":
        spec["value"] = vec("value", required=True)
    elif kind == "step":
        spec["time"] = ck.field(pt, T["time"], "pressure.time")
        spec["after"] = vec("after", required=True)
        spec["before"] = vec("before")
    elif kind == "ramp":
        spec["t0"] = ck.field(pt, T["t0"], "pressure.t0")
        spec["t1"] = ck.field(pt, T["t1"], "pressure.t1")
        if spec["t0"] is not None and spec["t1"] is not None and not spec["t1"] > spec["t0"]:
            ck.add("pressure.t1", f"a time > t0 = {spec['t0']:g} s", _show(pt["t1"]))
        spec["end"] = vec("end", required=True)
        spec["start"] = vec("start")
    elif kind == "sine":
        spec["amplitude"] = vec("amplitude", required=True)
        spec["offset"] = vec("offset")
        spec["frequency"] = scalar_or_vec("frequency", 0.0)
        if "frequency" not in pt:
            ck.add("pressure.frequency", "a frequency (Hz), a number or one a chamber", "nothing (the key is required)")
        phase = scalar_or_vec("phase", 0.0)
        spec["segment_phase"] = ck.field(pt, T["segment_phase"], "pressure.segment_phase", 0.0)
        if phase is not None and spec["segment_phase"] is not None and n is not None:
            phase = phase + np.repeat(np.arange(n), 3) * spec["segment_phase"]
        spec["phase"] = phase
        if spec["amplitude"] is not None and spec["offset"] is not None and spec["frequency"] is not None \
                and phase is not None:
            A, off, f = spec["amplitude"], spec["offset"], spec["frequency"]
            low = np.where(f > 0, off - np.abs(A), off + A * np.sin(phase))
            high = np.where(f > 0, off + np.abs(A), off + A * np.sin(phase))
            if np.any(low < VACUUM_GAUGE):
                k = int(np.flatnonzero(low < VACUUM_GAUGE)[0])
                ck.add("pressure.offset", f"offset - |amplitude| >= {VACUUM_GAUGE:g} Pa (a vacuum) in every chamber",
                       f"{low[k]:g} Pa at {_where(k)}")
            elif np.any(high > P.high):
                k = int(np.flatnonzero(high > P.high)[0])
                ck.add("pressure.offset", f"offset + |amplitude| <= {P.high:g} Pa in every chamber",
                       f"{high[k]:g} Pa at {_where(k)}")
    else:  # table
        times = pt.get("times", _MISSING)
        values = pt.get("values", _MISSING)
        t_arr = None
        if times is _MISSING:
            ck.add("pressure.times", "an array of times (s), strictly increasing", "nothing (the key is required)")
        else:
            t_arr = ck._numbers(times, "pressure.times", "an array of times (s), strictly increasing", T["times"].range)
            if t_arr is not None:
                if t_arr.size < 1:
                    ck.add("pressure.times", "at least one time (s)", "an empty array")
                    t_arr = None
                else:
                    d = np.diff(t_arr)
                    if np.any(d <= 0):
                        k = int(np.flatnonzero(d <= 0)[0])
                        ck.add(f"pressure.times[{k + 1}]", f"a time > times[{k}] = {t_arr[k]:g} s (strictly increasing)",
                               f"{t_arr[k + 1]:g}")
                        t_arr = None
        rows = None
        if values is _MISSING:
            ck.add("pressure.values", "an array of pressure vectors (Pa), one a time", "nothing (the key is required)")
        elif not isinstance(values, list):
            ck.add("pressure.values", "an array of pressure vectors (Pa), one a time", f"{_type_name(values)} {_show(values)}")
        else:
            if isinstance(times, list) and len(values) != len(times):
                ck.add("pressure.values", f"{len(times)} pressure vectors, one for each of the {len(times)} times",
                       f"{len(values)}")
            rows = _valid_rows(values, n, P)  # a long table of good rows, at numpy speed
            for k, row in enumerate(values if rows is None else ()):
                if k == 0:
                    rows = []
                arr = ck.per_segment(row, f"pressure.values[{k}]", n, "Pa")
                if arr is None or gauge(f"values[{k}]", arr.ravel()) is None:
                    rows = None
                    break
                rows.append(arr.ravel())
        spec["times"] = t_arr
        spec["values"] = None if rows is None or not rows else np.array(rows)
    if len(ck.problems) > start or n is None:
        return None, {}
    try:
        if kind == "constant":
            sched = Constant(spec["value"])
        elif kind == "step":
            sched = Step(spec["time"], spec["after"], spec["before"])
        elif kind == "ramp":
            sched = Ramp(spec["t0"], spec["t1"], spec["end"], spec["start"])
        elif kind == "sine":
            sched = Sine(spec["amplitude"], spec["frequency"], spec["phase"], spec["offset"])
        else:
            sched = Table(spec["times"], spec["values"])
    except (ValueError, TypeError) as err:  # pragma: no cover - the checks above cover the schedules' own
        ck.add("pressure", "a valid schedule", str(err))
        return None, {}
    return sched, spec


def _valid_rows(values: list, n: int | None, rng) -> list | None:
    """``values`` as a list of ``(3 n,)`` arrays if every row is a flat array of ``3 n`` finite
    numbers inside ``rng``, else None (the row-by-row check then names the first problem)."""
    if n is None or not values:
        return None
    w = 3 * n
    if not all(type(r) is list and len(r) == w for r in values):
        return None
    if not {type(x) for r in values for x in r} <= {int, float}:
        return None
    try:
        arr = np.array(values, dtype=float)
    except (OverflowError, ValueError):
        return None
    if rng.outside(arr).any():
        return None
    return list(arr)


def _initial(ck: _Checker, raw: dict, segments: list[SegmentSpec] | None):
    T = F.INITIAL
    it = ck.table(raw, "initial", "initial") or {}
    ck.keys(it, "initial", T.keys())
    n = None if segments is None else len(segments)
    q = v = None
    if "q_e" in it:
        q = ck.per_segment(it["q_e"], "initial.q_e", n)
    if "v" in it:
        v = ck.per_segment(it["v"], "initial.v", n, bounds=T["v"].range)
    if segments is None:
        return None, None
    if q is None:
        if "q_e" in it:
            return None, None
        q = np.array([[s.length, 0.0, 0.0] for s in segments])
    if v is None:
        if "v" in it:
            return None, None
        v = np.zeros((n, 3))
    for j, s in enumerate(segments):
        seg = s.segment(nodes=1)
        try:
            seg.check_configuration(q[j], name=f"segment {j}")
        except ValueError as err:
            ck.add(f"initial.q_e[{j}]", "a configuration inside the model (l > 0, |kappa| r_s < 1"
                   f"{', kappa >= 0' if s.coords == 'paper' else ''})", f"{_vec_str(q[j])}: {err}")
            continue
        if q[j, 0] > F.MAX_STRETCH * s.length:
            ck.add(f"initial.q_e[{j}][0]", f"l <= {F.MAX_STRETCH:g} x length = {F.MAX_STRETCH * s.length:g} m",
                   f"{q[j, 0]:g}")
            continue
        why = _nonfinite_state(seg, q[j], v[j])
        if why:
            ck.add(f"initial.q_e[{j}]", "a state whose mass matrix and energies are finite", why)
            continue
        if not s.extensible:
            if abs(q[j, 0] - s.length) > 1e-12 * s.length:
                ck.add(f"initial.q_e[{j}][0]", f"l = length = {s.length:g} m (segment {j} is inextensible)",
                       f"{q[j, 0]:g}")
            if v[j, 0] != 0.0:
                ck.add(f"initial.v[{j}][0]", f"0 (segment {j} is inextensible)", f"{v[j, 0]:g}")
    return q, v


def _nonfinite_state(seg: Segment, q: np.ndarray, v: np.ndarray) -> str | None:
    """What is not finite at the segment state ``(q, v)`` (its own coordinates): the mass
    matrix, the kinetic or the elastic energy; None if all are."""
    q_c = seg.to_curvature(q)
    v_c = seg.coordinate_jacobian(q) @ v
    with np.errstate(all="ignore"):
        M = seg._mass_c(q_c)
        xi = np.concatenate([np.zeros(6), v_c])
        T = 0.5 * float(xi @ M @ xi)
        U = seg.elastic_energy(q)
    if not np.all(np.isfinite(M)):
        return f"a non-finite mass matrix at q_e = {_vec_str(q)}"
    if not (math.isfinite(T) and math.isfinite(U)):
        return f"kinetic energy {T:g} J, elastic energy {U:g} J at q_e = {_vec_str(q)}, v = {_vec_str(v)}"
    return None
