"""Building a scene's model: the smallest :class:`~qchain.arm.chain.Chain` that represents a
scene, and what it dropped and why (:class:`SceneModel`; "Model reduction" in the docstring of
:mod:`qchain.scene`). :class:`~qchain.scene.Scene` inherits the methods of :class:`ModelBuilder`."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, replace

import numpy as np
import pinocchio as pin

from ..arm.chain import Chain
from ..sim.inputs import Schedule
from ..checks.text import show_vector
from ..model.segment import CHAMBER_ANGLES, DEFAULT_NODES, nodes_for_tolerance
from .cost import _frequency
from .payload import payload_asymmetry
from .stretch import AXIAL_SEPARATION, STRETCH_MARGIN, StretchEstimate, _ranges

__all__ = ["SceneModel", "ModelBuilder", "BEND_MARGIN", "BEND_SAMPLES"]

#: Safety factor on the estimated static bend (the overshoot of an undamped step response).
BEND_MARGIN = 2.0
#: Even samples of the run at which the pressure schedule is scanned for the bend estimate.
BEND_SAMPLES = 65


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


def _fmt(x: float) -> str:
    return f"{x:.3g}"


def _list_or_one(xs) -> str:
    xs = list(xs)
    return f"{xs[0]} per segment" if all(x == xs[0] for x in xs) else ", ".join(str(x) for x in xs)


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
    for name in names.get(t, ["offset"]):
        why = differ(name)
        if why:
            return why
    if t != "sine":
        return None
    # sine: equal offsets (above), and equal sine terms (both zero, or equal amplitude, frequency, phase)
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


class ModelBuilder(StretchEstimate):
    """Model building and reduction of :class:`~qchain.scene.Scene` (its base class; see the
    module docstring)."""

    def build(self, reduce: bool | None = None, controlled: bool = False) -> SceneModel:
        """Build the model ("Model reduction" in :mod:`qchain.scene`): ``reduce`` default the file's
        ``model.reduce``; ``controlled``: the pressures will come from a controller, so no planar
        reduction (it needs chambers 2 and 3 equal at all times)."""
        reduce = self.reduce if reduce is None else bool(reduce)
        reductions: list[str] = []
        kept: list[str] = []
        locked = [j for j, s in enumerate(self.segments) if not s.extensible]
        if locked:
            reductions.append(f"{_ranges(locked)}: l locked at l0 (extensible = false): axial mode dropped")
            coupled = [j for j in locked if self.segments[j].axial_damping_coupling]
            if coupled:  # the file's choice, said: with l' = 0 the coupling entries act on nothing
                reductions.append(f"{_ranges(coupled)}: damping_matrix's entries coupling l to ux, uy dropped with "
                                  "the axial mode (extensible = false)")
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
                "motion" + (", obstacles and loads" if self.surroundings.environment is not None else "")
                + (", tip payload" if self.payload is not None else "") + " symmetric about the base x-z plane"
            )
        else:
            kept.append(f"planar: not applicable: {why_not}")
        self._start_compiling(planar, controlled)
        lock, note = self._inextensible(reduce, planar, controlled)
        if note:
            (reductions if lock else kept).append(note)
        nodes, max_bend, note = self._nodes(reduce, planar)
        (reductions if max_bend is not None else kept).append(note)  # sized from node_tolerance, or not
        specs = [replace(s, extensible=False) if lock else s for s in self.segments]
        segs = [s.segment(nodes=k) for s, k in zip(specs, nodes)]
        chain = self._chain(segs, planar)
        q0, v0 = self._initial_state(chain)
        # the start state's energies, which a run checks first (its kernels load here, with
        # the model, not in the run's time)
        chain.kinetic_energy(q0, v0)
        chain.potential_energy(q0)
        return SceneModel(chain=chain, q0=q0, v0=v0, pressure=self.pressure, nodes=nodes, max_bend=max_bend,
                          reductions=reductions, kept=kept, reduced=reduce)

    def _inextensible(self, reduce: bool, planar: bool, controlled: bool) -> tuple[bool, str]:
        """Whether to lock every segment's ``l`` at ``l0`` (the automatic inextensible
        reduction), and the note saying why or why not ("" when every segment is locked by
        the file already)."""
        if all(not s.extensible for s in self.segments):
            return False, ""
        if not reduce:
            return False, "inextensible: not tried (reduce = false)"
        why_not = self.inextensible_obstacle(controlled)
        if why_not is not None:
            return False, f"inextensible: not applicable: {why_not}"
        est = self.estimate_stretch(planar)
        if isinstance(est, str):
            return False, f"inextensible: not applicable: the stretch could not be estimated: {est}"
        f_in = _frequency(self.pressure_spec, self.base)
        if est.axial_frequency < AXIAL_SEPARATION * f_in:
            return False, (f"inextensible: not applicable: the slowest axial mode ({_fmt(est.axial_frequency)} Hz) is "
                           f"within {AXIAL_SEPARATION:g}x of the inputs' {_fmt(f_in)} Hz")
        tol = self.length_tolerance
        how = (f"estimated tip change {_fmt(est.tip * 1e3)} mm = {STRETCH_MARGIN:g} x static "
               f"{_fmt(est.shape / STRETCH_MARGIN * 1e3)} mm + drift {_fmt(est.drift * 1e3)} mm over {self.duration:g} s "
               f"(axial strain {_fmt(est.strain)}, bend {_fmt(est.bend_frequency)} Hz, axial "
               f"{_fmt(est.axial_frequency)} Hz)")
        if est.tip > tol:
            return False, f"inextensible: not applicable: {how} > length_tolerance = {_fmt(tol * 1e3)} mm"
        return True, (f"inextensible: l locked at l0 in every segment, axial mode dropped: {how} <= length_tolerance "
                      f"= {_fmt(tol * 1e3)} mm")

    def _start_compiling(self, planar: bool, controlled: bool) -> None:
        """On a cold cache, set the engine's compile going in worker processes while the model
        is built (the node count's static solves compile kernels of their own here)."""
        from ..sim.simulation import COMPILED

        if self.method in COMPILED and not controlled and all(s.coords == "curvature" for s in self.segments):
            from ..sim.engine import warmup

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
        kind = self.base.type
        kw = ({"base_placement": self.base.placement} if kind == "fixed" else
              {"base_motion": self.base.motion} if kind == "prescribed" else {})
        return Chain(segs, base=kind, gravity=self.gravity, planar=planar, payload=self.payload, tendons=self.tendons,
                     **kw)

    def _initial_state(self, chain: Chain) -> tuple[np.ndarray, np.ndarray]:
        q_B, v_B = ((pin.SE3ToXYZQUAT(self.base.placement), [*self.base.velocity, *self.base.angular_velocity])
                    if chain.floating else ([], []))  # a floating base's pose and twist first
        return np.concatenate([q_B, self.q_e0.ravel()]), np.concatenate([v_B, self.v_e0.ravel()])

    def planar_obstacle(self) -> str | None:
        """Why the scene is not symmetric about the base's x-z plane, or None if it is."""
        paper = [j for j, s in enumerate(self.segments) if s.coords != "curvature"]
        if paper:
            return f"{_ranges(paper)} in paper coordinates (uy is not one of their coordinates)"
        if self.tendons:
            return "tendons: the planar model is not tried with tendons"
        coupled = [j for j, s in enumerate(self.segments) if s.uy_damping_coupling]
        if coupled:  # uy's damping force would follow l' or ux': uy = 0 is then not a solution
            return f"{_ranges(coupled)}: damping_matrix couples uy to l or ux"
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
                return f"the base translates along {show_vector(ax)}, out of the x-z plane"
            if b.motion.kind == "rotation" and (ax[0] != 0.0 or ax[2] != 0.0) and b.motion.amplitude != 0.0:
                return f"the base turns about {show_vector(ax)}, not the y axis"
        return payload_asymmetry(self.payload) or self.surroundings.asymmetry(self.base.placement)

    def start_problems(self) -> list:
        """Problems (:class:`qchain.scene.format.Problem`) of an arm that starts inside an
        obstacle (:meth:`qchain.scene.surroundings.Surroundings.start_problems`)."""
        env = self.surroundings.environment
        if env is None or not env.obstacles:
            return []
        segs = [s.segment(nodes=1) for s in self.segments]  # the backbone's shape alone: no mass integrals
        chain = self._chain(segs, planar=False)
        q0, v0 = self._initial_state(chain)
        return self.surroundings.start_problems(chain, q0, v0)

    def _nodes(self, reduce: bool, planar: bool):
        """Node counts, the bends they were sized for, and a note saying how."""
        explicit = [s.nodes for s in self.segments]
        if not reduce or self.node_tolerance is None:
            nodes = [DEFAULT_NODES if k is None else k for k in explicit]
            why = "reduce = false" if (reduce is False and self.node_tolerance is not None) else "no node_tolerance"
            return nodes, None, f"node count: {_list_or_one(nodes)} ({why}; default {DEFAULT_NODES})"
        if self.max_bend is not None:
            theta = np.full(self.n, self.max_bend)
            how = f"max_bend = {_fmt(self.max_bend)} rad"
        elif self.tendons:  # the static estimate knows pressures, not tensions: the model's whole range
            theta = np.array([s.length / s.radius for s in self.segments])
            how = "tendons: sized for the largest bend the model allows, l0/r_s (give max_bend to size for less)"
        else:
            theta, how = self.estimate_bend(planar)
        nodes = [s.nodes if s.nodes is not None else
                 nodes_for_tolerance(s.segment(nodes=DEFAULT_NODES), float(theta[j]), self.node_tolerance)
                 for j, s in enumerate(self.segments)]
        # the sizing measures M_xi alone; the drag is integrated on the same nodes (|v| has a kink
        # where v vanishes inside a segment): a segment with drag is not cut below the default
        drag = [j for j, s in enumerate(self.segments) if s.nodes is None and (s.drag_linear or s.drag_quadratic)]
        raised = [j for j in drag if nodes[j] < DEFAULT_NODES]
        for j in raised:
            nodes[j] = DEFAULT_NODES
        fixed = [j for j, s in enumerate(self.segments) if s.nodes is not None]
        extra = f"; {_ranges(fixed)} keep their own nodes" if fixed else ""
        if raised:
            extra += (f"; {_ranges(raised)} keep {DEFAULT_NODES} (the default): their drag is integrated on the nodes "
                      "and not part of the sizing")
        bend = _fmt(theta[0]) if np.all(theta == theta[0]) else ", ".join(_fmt(x) for x in theta)
        note = (f"nodes: {_list_or_one(nodes)} from node_tolerance = {self.node_tolerance:g} at max bend {bend} rad "
                f"({how}){extra}")
        return nodes, theta, note

    def estimate_bend(self, planar: bool = False) -> tuple[np.ndarray, str]:
        """Largest bending angle of each segment the scene is expected to reach (rad, (n,)),
        and how it was found. See "Model reduction" in the docstring of :mod:`qchain.scene`."""
        from ..arm.statics import equilibrium

        segs = [s.segment(nodes=DEFAULT_NODES) for s in self.segments]
        conditions = self._static_conditions()
        candidates = self._pressure_candidates()
        static = np.zeros(self.n)
        failed = None
        for placement, g in conditions:
            ch = Chain(segs, base="fixed", gravity=g, base_placement=placement, planar=planar, payload=self.payload)
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
        # deformation rates only (rigid motion bends nothing); the payload moves with the tip
        ch0 = Chain(segs, base="fixed", gravity=np.zeros(3), payload=self.payload)
        T0 = ch0.kinetic_energy(self.q_e0.ravel(), self.v_e0.ravel())
        EI = np.array([s.segment(nodes=1).bending_stiffness for s in self.segments])
        l0 = np.array([s.length for s in self.segments])
        kin = np.sqrt(2.0 * T0 * l0 / EI)
        if failed:
            r = np.array([s.radius for s in self.segments])
            p, msg = failed
            return l0 / r, (f"equilibrium failed at p = {show_vector(p)} Pa ({msg}): sized for the largest bend the "
                            f"model allows, l0/r_s")
        theta = np.full(self.n, BEND_MARGIN * max(static.max(), initial.max()) + kin.max())
        parts = [f"{BEND_MARGIN:g} x the largest "
                 + ("initial bend" if initial.max() > static.max() else "static bend under peak pressures")]
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
        """Pressure vectors at which the static bend is solved (see "Model reduction" in the
        docstring of :mod:`qchain.scene`)."""
        n = self.n
        if self.pressure is None:
            return [np.zeros(3 * n)]
        P = np.array([self.pressure(t) for t in self._pressure_times()])
        c = np.exp(1j * np.asarray(CHAMBER_ANGLES))
        drive = np.abs(P.reshape(len(P), n, 3) @ c)  # (K, n): bending drive per segment (arbitrary units)
        pick = set(int(k) for k in np.argmax(drive, axis=0))
        pick.add(int(np.argmax(drive.sum(axis=1))))
        pick.add(int(np.argmin(drive.sum(axis=1))))
        return [P[k] for k in sorted(pick)]

    def _pressure_times(self) -> list[float]:
        """Times (s) at which the pressure schedule is scanned: ``BEND_SAMPLES`` even samples
        of the run and the schedule's corner times (a sine's extremes)."""
        n = self.n
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
        return sorted(set(times))
