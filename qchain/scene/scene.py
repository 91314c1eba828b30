"""Scene files: a soft arm, its inputs and a run, described in TOML.

``load_scene(path) -> Scene`` reads and validates a file; ``Scene.build()`` makes the
smallest model that represents the scene (and says what it dropped and why);
``Scene.simulate()`` runs it. ``qchain run SCENE.toml`` and ``qchain info SCENE.toml``
(:mod:`qchain.cli`) do the same from the command line. Units are SI throughout: m, kg,
s, Pa, rad, Hz.

This module holds :class:`Scene` (its run and its description) and re-exports the rest
(:mod:`qchain.scene.reading`, :mod:`qchain.scene.parts`, :mod:`qchain.scene.model`). The file
format, declared in :mod:`qchain.scene.format`, and the errors :func:`load_scene` raises (one
:class:`SceneError` listing every problem): ``docs/scene-format.md``.

Model reduction
---------------
``Scene.build()`` builds the smallest model that represents the scene and lists, in
``SceneModel.reductions``, what it dropped and why (``Scene.reductions`` for the scene's
own setting); ``SceneModel.kept`` says which reductions did not apply and why not.

* ``extensible = false`` (the file's choice, applied with or without ``reduce``): ``l`` is
  held at ``l0`` and the axial mode, the stiffest, is dropped (with it the entries of a
  ``damping_matrix`` coupling ``l`` to the bends, which ``SceneModel.reductions`` then says).
* inextensible (automatic, :mod:`qchain.scene.stretch`): ``l`` is held at ``l0`` in every
  segment when the estimated tip change of doing so is within ``model.length_tolerance``
  (m, default 1e-4). Not tried when the pressures actuate elongation (the mean chamber
  pressure of a segment changes during the run: the axial mode is then the motion), when
  they come from a controller, with obstacles (impacts load the axial mode), with the
  drag of a medium (``drag_linear``, ``drag_quadratic``: it loads the axial mode of a moving
  arm) or a ``damping_matrix`` coupling ``l`` to ``ux``, ``uy`` (a bending rate then loads
  ``l``; neither is in the static estimate), when a segment starts with ``l != l0`` or a
  length rate, or when the slowest axial mode lies
  within ``AXIAL_SEPARATION`` (3) times the fastest sine input. The estimate is
  ``shape + drift``: ``shape`` is ``STRETCH_MARGIN`` (2, a suddenly applied load's
  overshoot) times the largest tip distance between the extensible and the locked static
  shapes, solved under the conditions and peak pressures of the bend estimate below (point
  loads included); ``drift`` is the phase the slowest bending mode (``omega_1``, the arm at
  rest) gains over the run when the segments are ``2 e`` longer, ``A omega_1 T DRIFT_RATE
  2 e`` (``e`` the largest static axial strain, ``A`` the largest tip excursion from the
  start to a static shape, plus the arm's length times the bend the initial kinetic energy
  could store, ``T`` the file's duration; at most ``2 A``). It is an estimate, not a bound:
  ``DRIFT_RATE`` (2) is set from the cantilever release, where the two models' tips drift
  apart by about 1.8 x ``2 e`` in phase (the arm's own swinging tension shifts the
  frequency beyond the ``1.5 e`` of a longer segment); damping, which the estimate ignores,
  makes it pessimistic. tests/test_scene_stretch.py checks it against the full model's tip on
  runs of the cantilever.
* planar (automatic): ``uy`` is held at 0 in every segment when the scene is symmetric
  about the base's x-z plane, where the reduction is exact: every segment in curvature
  coordinates, its ``damping_matrix`` (if any) not coupling ``uy`` to ``l`` or ``ux`` (the
  isotropic drag is symmetric); gravity in that plane (expressed in the base frame at the start); chambers
  2 and 3 of every segment given the same pressure at all times (equal schedule
  parameters); ``uy = 0`` and ``uy' = 0`` at the start; a base motion in that plane (a
  translation along an axis with no y component, a rotation about the y axis; a floating
  base with no initial y velocity and no x or z angular velocity); every obstacle and point
  load symmetric about that plane (:meth:`qchain.scene.surroundings.Surroundings.asymmetry`);
  a tip payload symmetric about the tip frame's x-z plane
  (:func:`qchain.scene.payload.payload_asymmetry`).
* nodes (automatic, with ``model.node_tolerance``): each segment gets the fewest Gauss
  nodes whose ``M_xi`` is within ``node_tolerance`` of a converged one
  (:func:`qchain.model.segment.nodes_for_tolerance`) at the largest bend the scene reaches:
  ``model.max_bend`` if given, else the estimate ``BEND_MARGIN`` (2) times the largest of
  the initial bends and the static bends (:func:`qchain.arm.statics.equilibrium`) under the
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
  :data:`qchain.model.segment.DEFAULT_NODES`. A segment with drag is not sized below
  ``DEFAULT_NODES``: the drag is integrated on the same nodes, and the sizing measures
  ``M_xi`` alone.

``model.reduce = false`` (or ``Scene.build(reduce=False)``) turns the automatic reductions
off: same layout, all coordinates free (but those of ``extensible = false`` segments), the
default node count, for comparison.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pinocchio as pin

from . import format as F
from ..checks.bounds import DURATION, VACUUM_GAUGE
from ..checks.paths import file_in_the_way, has_nul, show_nul
from ..sim.budget import Budget, BudgetError
from ..sim.engine.driver import EXPLICIT_STABILITY_EXTENT
from ..sim.inputs import Schedule
from .format import PLOTS, Problem, SceneError, _Checker, _show, _type_name  # noqa: F401 (re-exported)
from .model import BEND_MARGIN, BEND_SAMPLES, ModelBuilder, SceneModel, _list_or_one  # noqa: F401 (re-exported)
from ..checks.text import show_vector
from .parts import BaseSpec, SegmentSpec, SineMotion
from .payload import describe_payload
from .tendons import describe_tendons
from .stretch import DEFAULT_LENGTH_TOLERANCE
from .surroundings import Surroundings
from .cost import _cost, _frequency
from ..sim.simulation import COMPILED, FIXED_STEP, METHODS, explicit_stability_limit, simulate

__all__ = ["Scene", "SceneModel", "SceneError", "Problem", "SegmentSpec", "BaseSpec", "SineMotion", "METHODS", "PLOTS",
           "BEND_MARGIN", "VACUUM_GAUGE"]

_TOP_KEYS = F.TOP.keys()


# --------------------------------------------------------------------------------------
# the scene


@dataclass(eq=False)
class Scene(ModelBuilder):
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
    length_tolerance : float, m
        Tip change the automatic inextensible reduction may make (``model.length_tolerance``).
    sample_rate : float, Hz
    output_folder : Path
    plots : tuple of str
    save : bool
    budget : Budget
        What a run may cost (:mod:`qchain.sim.budget`; the file's ``[budget]`` table).
    surroundings : Surroundings
        Obstacles, contact law and point loads (:mod:`qchain.scene.surroundings`).
    payload : pinocchio.Inertia or None
        The rigid body at the tip (``[payload]``, :mod:`qchain.scene.payload`): the model's
        ``Chain(payload=)``.
    tendons : tuple of Tendon
        The ``[[tendons]]`` (:mod:`qchain.scene.tendons`): the model's ``Chain(tendons=)``.
    tension : Schedule or None
        The ``[tension]`` schedule, (nt,) N: :func:`qchain.simulate`'s ``tension`` (None: 0 N).
    tension_spec : dict
        The tension table as parsed (``type`` and its arrays).
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
    surroundings: Surroundings = field(default_factory=Surroundings)
    payload: pin.Inertia | None = None
    length_tolerance: float = DEFAULT_LENGTH_TOLERANCE
    tendons: tuple = ()
    tension: Schedule | None = None
    tension_spec: dict = field(default_factory=dict)

    @property
    def environment(self):
        """The :class:`qchain.contact.Environment` of the file's ``[contact]``, ``[[obstacles]]``
        and ``[[loads]]`` (None without obstacles and loads): every run passes it to
        :func:`qchain.simulate` as ``env``."""
        return self.surroundings.environment

    @property
    def n(self) -> int:
        """Number of segments."""
        return len(self.segments)

    # ------------------------------------------------------------------ run

    def sample_times(self, duration: float | None = None) -> np.ndarray:
        """Output times ``k / sample_rate`` from 0 up to the run's end (included), s; a
        :class:`qchain.sim.budget.BudgetError` if there would be more than the budget allows."""
        T = self.duration if duration is None else DURATION.check("duration", duration)
        self.check_budget(T)
        k = np.arange(0, int(math.floor(T * self.sample_rate * (1 + 1e-12))) + 1)
        t = k / self.sample_rate
        t = t[t < T - 1e-9 * max(1.0, T)]
        return np.append(t, T)

    def simulate(self, *, reduce: bool | None = None, model: SceneModel | None = None,
                 duration: float | None = None, pressure=None, on_sample=None, progress: bool | str = False,
                 controller_rate: float | None = None):
        """Run the scene; returns a :class:`qchain.sim.trajectory.Trajectory` sampled at
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
        progress : bool or "lines"
            Progress on stderr (:func:`qchain.simulate`'s ``progress``).
        controller_rate : float, Hz, optional
            Sample a controller ``pressure`` at this rate and hold it (zero-order hold): the
            run stays in compiled code between samples (:func:`qchain.simulate`).
        """
        T = self.duration if duration is None else DURATION.check("duration", duration)
        self.check_budget(T)
        if self.method in FIXED_STEP and self.dt > T:
            raise ValueError(f"duration must be >= the scene's step dt = {self.dt:g} s, got {T:g} s")
        if model is None:
            model = self.model if reduce is None or reduce == self.reduce else self.build(reduce)
        try:
            return simulate(
                model.chain, model.q0, model.v0, (0.0, T), pressure=model.pressure if pressure is None else pressure,
                method=self.method, dt=self.dt,
                rtol=self.rtol, atol=self.atol, t_eval=self.sample_times(T), on_sample=on_sample, progress=progress,
                max_step=self.max_step, controller_rate=controller_rate, budget=self.budget, env=self.environment,
                tension=self.tension if model.chain.nt else None,
            )
        except BudgetError as err:  # said as a scene's budget: raised in its [budget] table
            if err.cost is None:
                raise
            self.budget.check(err.cost, how="raise it in the scene's [budget] table")
            raise

    def cost(self, duration: float | None = None, model: SceneModel | None = None):
        """What a run of the scene (``duration`` s, default the file's) costs:
        :class:`qchain.sim.budget.Cost`. With the built ``model``, an explicit adaptive method's
        steps include its stability limit at the start
        (:func:`qchain.sim.simulation.explicit_stability_limit`)."""
        T = self.duration if duration is None else duration
        stable = None
        if model is not None and self.method in EXPLICIT_STABILITY_EXTENT:
            stable = explicit_stability_limit(model.chain, self.method, model.q0, model.v0, 0.0, model.pressure)
        return _cost(self.n, self.base.type, self.method, self.dt, self.max_step, T, self.sample_rate,
                     _frequency(self.pressure_spec, self.base), stable_step=stable)

    def check_budget(self, duration: float | None = None, model: SceneModel | None = None) -> None:
        """Raise :class:`qchain.sim.budget.BudgetError` if a run of ``duration`` s (default the
        file's) would exceed :attr:`budget`, naming the bound and how to raise it; with the
        built ``model`` the steps include an explicit method's stability limit."""
        self.budget.check(self.cost(duration, model), how="raise it in the scene's [budget] table")

    def check_output(self, folder: str | os.PathLike | None = None) -> Path:
        """Make sure a run can write its outputs to ``folder`` (default ``output.folder``): made, a
        writable folder with room for them; returns it, or a :class:`SceneError` naming ``output.folder``."""
        import shutil
        import tempfile

        p = Path(self.output_folder if folder is None else folder)

        def fail(expected, found):
            raise SceneError(str(self.path) if self.path else "<scene>", [Problem("output.folder", expected, found)])

        if has_nul(str(p)):
            fail("a folder path without a NUL character", _show(show_nul(str(p))))
        try:
            blocker = file_in_the_way(p)
            if blocker is not None:
                fail("a folder (or a path where one can be made)", f"{blocker} is a file")
            p.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=p) as fh:
                fh.write(b"qchain")
        except OSError as err:  # also a path too long, a loop of links (from exists() too)
            shown = str(p) if len(str(p)) <= 120 else str(p)[:117] + "..."
            fail("a folder qchain can write in", f"{shown}: {err.strerror or err}")
        cost = self.cost()
        need = cost.samples * 8.0 * (6 + 4 * 3 * self.n) + 2**20 * (len(self.plots) + 1)
        free = shutil.disk_usage(p).free
        if free < need:
            fail(f"room for the outputs, about {need / 2**20:.3g} MiB", f"{free / 2**20:.3g} MiB free in {p}")
        return p

    # ------------------------------------------------------------------ report

    def describe(self, model: SceneModel | None = None, duration: float | None = None,
                 folder: str | os.PathLike | None = None, plots: bool = True) -> list[str]:
        """Lines describing the scene and the model it builds (``qchain info``); ``duration``,
        ``folder`` and ``plots`` (False: none written) are a run's own where it overrides
        the file's (``qchain run --duration --out --no-plots``)."""
        m = self.model if model is None else model
        ch = m.chain
        lines = [f"scene: {self.path if self.path else '<text>'}" + (f" ({self.name})" if self.name else "")]
        if self.description:
            lines.append(f"  {self.description}")
        kinds = sorted({(s.coords, s.actuation) for s in self.segments})
        lines.append(f"segments: {self.n} ({'; '.join(f'{c} coordinates, {a} actuation' for c, a in kinds)})")
        b = self.base
        if b.type == "fixed":
            lines.append(f"base: fixed at {show_vector(b.position)} m, rpy {show_vector(b.rpy)} rad")
        elif b.type == "floating":
            lines.append(f"base: floating, starts at {show_vector(b.position)} m, rpy {show_vector(b.rpy)} rad, "
                         f"velocity {show_vector(b.velocity)} m/s, angular velocity {show_vector(b.angular_velocity)} rad/s")
        else:
            mo = b.motion
            unit = "m" if mo.kind == "translation" else "rad"
            lines.append(f"base: prescribed {mo.kind} along/about {show_vector(mo.axis)} (mount frame), amplitude "
                         f"{mo.amplitude:g} {unit}, {mo.frequency:g} Hz, phase {mo.phase:g} rad; mount at "
                         f"{show_vector(b.position)} m, rpy {show_vector(b.rpy)} rad")
        lines.append(f"gravity: {show_vector(self.gravity)} m/s^2")
        lines.append(f"model: nq = {ch.nq}, nv = {ch.nv}, free dofs = {ch.nv_active}, pressure inputs = {ch.nu}, "
                     f"nodes = {_list_or_one(m.nodes)}")
        lines.append(f"reductions ({'on' if m.reduced else 'off'}):")
        lines += [f"  - {r}" for r in m.reductions] or ["  - none"]
        if m.kept:
            lines.append("not reduced:")
            lines += [f"  - {k}" for k in m.kept]
        lines.append(f"pressure: {_pressure_summary(self.pressure_spec)}")
        lines += self.surroundings.describe(ch)
        lines += describe_payload(self.payload, ch)
        lines += describe_tendons(self.tendons, self.tension_spec)
        meth = f"{self.method}, dt = {self.dt:g} s" if self.method in FIXED_STEP else \
            f"{self.method}, rtol = {self.rtol:g}, atol = {self.atol:g}" + \
            (f", max_step = {self.max_step:g} s" if math.isfinite(self.max_step) else "")
        kind = "compiled" if self.method in COMPILED else "scipy's solve_ivp in Python: radau5 and dopri5 are compiled"
        lines.append(f"simulation: {self.duration if duration is None else duration:g} s, {meth} ({kind})")
        if plots:
            lines.append(f"output: {self.sample_rate:g} Hz to {self.output_folder if folder is None else folder}, "
                         f"plots: {', '.join(self.plots) if self.plots else 'none'}"
                         f"{', trajectory.npz' if self.save else ''}")
        else:
            lines.append(f"output: {self.sample_rate:g} Hz, no plots and no trajectory.npz")
        return lines


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
