"""The scene file format, declared once (:data:`TABLES`: every key's type, unit, range,
default and meaning; the ranges :mod:`qchain.checks.bounds`'), and the :class:`_Checker` that
applies it. ``docs/scene-format.md`` is generated from it (:func:`markdown`)::

    .venv/bin/python -m qchain.scene.format > docs/scene-format.md

The text is checked for size (:data:`MAX_SCENE_BYTES`) and nesting (:data:`MAX_DEPTH`) before
TOML is parsed: the parser recurses once a level (a ``RecursionError``, not a message)."""

from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass, replace
from dataclasses import fields as dataclass_fields

import numpy as np

from ..checks import bounds as B
from ..checks.bounds import Range
from ..checks.paths import has_nul, show_nul
from ..sim.budget import DEFAULT as DEFAULT_BUDGET
from ..sim.budget import RANGES as BUDGET_RANGES
from ..errors import MAX_LISTED, SceneError
from ..contact.environment import ContactLaw, Environment
from ..contact.shapes import MOTION_RANGES
from ..model.segment import DEFAULT_NODES
from ..sim.simulation import DEFAULT_METHOD, FIXED_STEP, METHODS
from .keys import Field, KeyTable
from .payload import PAYLOAD, PAYLOAD_EXAMPLE
from .tendons import TENDON_EXAMPLE, TENDONS, TENSION

__all__ = ["Field", "KeyTable", "TABLES", "OBSTACLE_TYPES", "OBSTACLE_MOTION_KEYS", "MAX_START_PENETRATION", "Problem",
           "SceneError", "PLOTS", "PRESSURE_KINDS", "MAX_DEPTH", "MAX_SCENE_BYTES", "MAX_STRETCH", "EXAMPLE",
           "CONTACT_EXAMPLE", "nesting_problem", "markdown"]

#: Plots a scene may ask for.
PLOTS = ("tip", "arm", "energy", "pressure", "momentum")
#: Deepest nesting of arrays and inline tables a scene file may have (a scene needs 3).
MAX_DEPTH = 32
#: Largest scene file (bytes).
MAX_SCENE_BYTES = 8 * 2**20
#: Largest initial stretch ``l / l0`` of a segment in a scene.
MAX_STRETCH = 10.0
#: Longest path component of ``output.folder`` (bytes, UTF-8): most file systems' limit.
MAX_NAME_BYTES = 255
#: Longest ``output.folder`` (bytes, UTF-8): Linux's ``PATH_MAX`` less its NUL.
MAX_PATH_BYTES = 4095


# --------------------------------------------------------------------------------------
# the declaration (its vocabulary, Field and KeyTable: qchain.scene.keys)


PRESSURE_KINDS = ("constant", "step", "ramp", "sine", "table")

TOP = KeyTable("", "The top level of the file.", (
    Field("name", "string", "Free text: the scene's name (plot titles, recordings).", default='""'),
    Field("description", "string", "Free text.", default='""'),
    Field("gravity", "vector", "Gravity, world frame.", B.GRAVITY, default="[0, 0, -9.81]", size=3),
    Field("model", "table", "How the model is built (below)."),
    Field("segments", "tables", "The segments, base to tip (below).", required=True),
    Field("base", "table", "The base: fixed, floating or prescribed (below)."),
    Field("pressure", "table", "Chamber pressures (below).", default="none: all chambers at 0 Pa"),
    Field("initial", "table", "The initial state (below)."),
    Field("simulation", "table", "Duration, method, tolerances (below).", required=True),
    Field("output", "table", "Samples, folder, plots (below)."),
    Field("budget", "table", "What a run may cost before it is refused (below)."),
    Field("contact", "table", "The contact law between the arm and the obstacles (below).",
          default="`qchain.contact.ContactLaw`'s"),
    Field("obstacles", "tables", "Obstacles the arm can touch (below).", default="none"),
    Field("loads", "tables", "Point loads on the arm (below).", default="none"),
    Field("payload", "table", "A rigid body at the arm's tip (below).", default="none"),
    Field("tendons", "tables", "Tendons beside the chambers (below).", default="none"),
    Field("tension", "table", "The tendons' tensions (below).", default="none: every tendon at 0 N"),
))

MODEL = KeyTable("model", "How the model is built (\"Model reduction\" in `qchain/scene/scene.py`).", (
    Field("reduce", "boolean", "Automatic reductions (planar, inextensible, node count) on.", default="true"),
    Field("node_tolerance", "number", "Relative `M_xi` accuracy the node count of each segment is sized for.",
          B.NODE_TOLERANCE, default="none: `nodes` or the default node count"),
    Field("max_bend", "number", "The bend (rad) the node count is sized for; needs `node_tolerance`.", B.MAX_BEND,
          default="estimated from the static bends under the peak pressures"),
    Field("length_tolerance", "number", "Tip change (m) the automatic inextensible reduction may make: `l` is "
          "locked at `l0` in every segment where the estimated change is within it.", B.LENGTH_TOLERANCE,
          default="1e-4"),
))

SEGMENT = KeyTable("segments[]", "One table a segment, base to tip: `[[segments]]`.", (
    Field("count", "integer", "Copies of this segment; all of them count against `budget.max_segments`.",
          Range(1, None, integer=True), default="1"),
    Field("length", "number", "Rest length `l0`.", B.LENGTH, required=True),
    Field("radius", "number", "Outer radius `r_s`.", B.RADIUS, required=True),
    Field("mass", "number", "Mass, spread evenly over every cross-section.", B.MASS, required=True),
    Field("chamber_area", "number", "Cross-section of each chamber; the chambers must fit: "
          "`chamber_radius + sqrt(chamber_area / pi) <= radius`.", B.CHAMBER_AREA, required=True),
    Field("chamber_radius", "number", "Distance of the chamber centres from the axis.", B.CHAMBER_RADIUS,
          required=True),
    Field("youngs_modulus", "number", "Young's modulus `E`.", B.YOUNGS_MODULUS, required=True),
    Field("damping", "number", "Stiffness-proportional damping `beta` of `D = beta K(q0)`.", B.DAMPING, default="0"),
    Field("damping_matrix", "matrix", "The damping matrix `D` itself, replacing `beta K(q0)` (`damping` must then be "
          "0): constant, symmetric, positive semi-definite, one array a row, in the segment's curvature coordinates "
          "`(l, ux, uy)` (N s/m on `l`, N m^3 s on `ux`, `uy`, N m s between; `qchain.Segment(damping_matrix=...)`, "
          "docs/model.md section 9). Needs `coords = \"curvature\"`. Entries coupling `uy` to `l` or `ux` rule out "
          "the planar reduction; entries coupling `l` to `ux`, `uy` rule out the automatic inextensible one.",
          B.DAMPING_MATRIX, default="none: `beta K(q0)`", size=3),
    Field("drag_linear", "number", "`c_1` of the drag of a still medium on the backbone, a force per unit length "
          "`f(s) = -(c_1 + c_2 |v(s)|) v(s)` against each backbone point's world velocity (`qchain.Segment`, "
          "docs/model.md section 9). Needs `coords = \"curvature\"`; rules out the automatic inextensible "
          "reduction (the drag loads the axial mode, which the estimate does not cover).", B.DRAG_LINEAR, default="0"),
    Field("drag_quadratic", "number", "`c_2` of the same drag (`1/2 rho C_d 2 r_s` in a fluid of density `rho`).",
          B.DRAG_QUADRATIC, default="0"),
    Field("coords", "choice", "Deformation coordinates: `(l, ux, uy)` or the paper's `(l, psi, kappa)`.",
          choices=("curvature", "paper"), default='"curvature"'),
    Field("actuation", "choice", "Input matrix: chamber-volume work or the paper's tip-plate forces.",
          choices=("volume", "paper"), default='"volume"'),
    Field("extensible", "boolean", "`false` holds `l` at `l0` (the axial mode dropped).", default="true"),
    Field("nodes", "integer", "Gauss-Legendre nodes along the segment; overrides `node_tolerance`.", B.NODES,
          default=f"{DEFAULT_NODES}, or sized from `model.node_tolerance`"),
))

BASE = KeyTable("base", "The base the first segment is mounted on.", (
    Field("type", "choice", "Fixed mount, free-floating body, or a mount moved by `base.motion`.",
          choices=("fixed", "floating", "prescribed"), default='"fixed"'),
    Field("position", "vector", "World position: the mount (fixed, prescribed) or the start (floating).",
          B.POSITION, default="[0, 0, 0]", size=3),
    Field("rpy", "vector", "Roll-pitch-yaw, `R = Rz(yaw) Ry(pitch) Rx(roll)`.", B.ANGLE, default="[0, 0, 0]",
          size=3),
    Field("velocity", "vector", "Initial linear velocity, base frame.", B.VELOCITY, default="[0, 0, 0]", size=3,
          when=("floating",)),
    Field("angular_velocity", "vector", "Initial angular velocity, base frame.", B.ANGULAR_VELOCITY,
          default="[0, 0, 0]", size=3, when=("floating",)),
    Field("motion", "table", "The mount's motion (below).", required=True, when=("prescribed",)),
))

MOTION = KeyTable("base.motion", "A prescribed base's sinusoidal motion `s(t) = amplitude sin(2 pi frequency t + "
               "phase)` along or about `axis` (mount frame).", (
    Field("type", "choice", "A shift along `axis`, or a turn about it through the mount origin.",
          choices=("translation", "rotation"), required=True),
    Field("axis", "vector", "Direction, mount frame, normalised (not zero).", B.DIRECTION, required=True, size=3),
    Field("amplitude", "number", "m (translation) or rad (rotation).", B.AMPLITUDE, required=True),
    Field("frequency", "number", "Hz.", B.FREQUENCY, required=True),
    Field("phase", "number", "rad.", B.ANGLE, default="0"),
))

PRESSURE = KeyTable("pressure", "Gauge chamber pressures, one of five kinds (`type`). A pressure vector holds 3 "
                 "numbers a segment (chambers 1 to 3), flat or as one array of 3 a segment.", (
    Field("type", "choice", "The kind of schedule.", choices=PRESSURE_KINDS, required=True),
    Field("value", "per_segment", "`constant`: the pressures.", B.PRESSURE, required=True, when=("constant",)),
    Field("time", "number", "`step`: when the step happens.", B.TIME, required=True, when=("step",)),
    Field("after", "per_segment", "`step`: pressures from `time` on.", B.PRESSURE, required=True, when=("step",)),
    Field("before", "per_segment", "`step`: pressures before `time`.", B.PRESSURE, default="zeros",
          when=("step",)),
    Field("t0", "number", "`ramp`: start of the ramp.", B.TIME, required=True, when=("ramp",)),
    Field("t1", "number", "`ramp`: its end, `> t0`.", B.TIME, required=True, when=("ramp",)),
    Field("end", "per_segment", "`ramp`: pressures from `t1` on.", B.PRESSURE, required=True, when=("ramp",)),
    Field("start", "per_segment", "`ramp`: pressures until `t0`.", B.PRESSURE, default="zeros", when=("ramp",)),
    Field("amplitude", "per_segment", "`sine`: `offset + amplitude sin(2 pi frequency t + phase + j "
          "segment_phase)` in segment `j`; `offset - abs(amplitude)` must stay above a vacuum.", B.PRESSURE_AMPLITUDE,
          required=True, when=("sine",)),
    Field("offset", "per_segment", "`sine`: the mean pressures.", B.PRESSURE, default="zeros", when=("sine",)),
    Field("frequency", "number_or_per_segment", "`sine`: Hz, one for all chambers or one a chamber.", B.FREQUENCY,
          required=True, when=("sine",)),
    Field("phase", "number_or_per_segment", "`sine`: rad, one for all chambers or one a chamber.", B.ANGLE,
          default="0", when=("sine",)),
    Field("segment_phase", "number", "`sine`: rad added `j` times to segment `j`'s chambers.", B.ANGLE, default="0",
          when=("sine",)),
    Field("times", "times", "`table`: strictly increasing times.", B.TIME, required=True, when=("table",)),
    Field("values", "rows", "`table`: one pressure vector a time; piecewise linear between them, held outside.",
          B.PRESSURE, required=True, when=("table",)),
))

INITIAL = KeyTable("initial", "The initial state; a floating base starts at `base.position`, `base.rpy`, "
                "`base.velocity`, `base.angular_velocity`.", (
    Field("q_e", "per_segment", f"Segment coordinates, each in the segment's own `coords`: inside the model "
          f"(`l > 0`, `abs(kappa) r_s < 1`, `kappa >= 0` in paper coordinates), `l <= {MAX_STRETCH:g} l0`, "
          "`l = l0` if inextensible.", default="the straight rest pose `(l0, 0, 0)`"),
    Field("v", "per_segment", "Their rates (0 for `l` if inextensible).", B.RATE, default="zeros"),
))

SIMULATION = KeyTable("simulation", "The run.", (
    Field("duration", "number", "Length of the run.", B.DURATION, required=True),
    Field("method", "choice", "Integration method (`qchain/sim/simulation.py`), any case: the first four are "
          "compiled, the rest scipy's `solve_ivp` in Python (`radau` is scipy's Radau, not `radau5`); `qchain info` "
          "says which.", choices=METHODS, default=f'"{DEFAULT_METHOD}"'),
    Field("rtol", "number", "Relative tolerance of the adaptive methods.", B.RTOL, default="1e-6"),
    Field("atol", "number", "Absolute tolerance of the adaptive methods.", B.ATOL, default="1e-8"),
    Field("dt", "number", f"Step of the fixed-step methods ({', '.join(FIXED_STEP)}): required there, refused by "
          "the others; `<= duration`.", B.STEP),
    Field("max_step", "number", "Largest step of the adaptive methods (refused by the fixed-step ones).", B.STEP,
          default="unbounded"),
))

OUTPUT = KeyTable("output", "What a run writes (`qchain run`).", (
    Field("sample_rate", "number", "Samples of the trajectory a second.", B.SAMPLE_RATE, default="100"),
    Field("folder", "path", "Where the plots and `trajectory.npz` go, relative to the working directory: not "
          f"empty, no NUL character, no path component over {MAX_NAME_BYTES} bytes, at most {MAX_PATH_BYTES} bytes in "
          "all.", default='"out/<file stem>"'),
    Field("plots", "names", "Plots to draw (`momentum` only with a floating base).", choices=PLOTS,
          default='["tip"]'),
    Field("save", "boolean", "Write `trajectory.npz` (t, q, v, p, energies).", default="true"),
))

BUDGET = KeyTable("budget", "What a run may cost (`qchain/sim/budget.py`): a scene whose run would exceed one of these "
               "is refused before it starts, naming the bound; raise it here to allow more.", (
    Field("max_steps", "integer", "Integrator steps: `duration / dt`, `duration / max_step`, or 2 a period of the "
          "fastest sine input or base motion.", BUDGET_RANGES["max_steps"], default=str(DEFAULT_BUDGET.max_steps)),
    Field("max_samples", "integer", "Output samples, `duration * sample_rate + 1`.", BUDGET_RANGES["max_samples"],
          default=str(DEFAULT_BUDGET.max_samples)),
    Field("max_memory", "number", "Bytes of output arrays and solver matrices (an estimate).",
          BUDGET_RANGES["max_memory"], default=f"{DEFAULT_BUDGET.max_memory:.0f} (2 GiB)"),
    Field("max_segments", "integer", "Segments, `count` expanded.", BUDGET_RANGES["max_segments"],
          default=str(DEFAULT_BUDGET.max_segments)),
))

_LAW = {f.name: f.default for f in dataclass_fields(ContactLaw)}  # the defaults, ContactLaw's own
#: The obstacle types a scene may name, and the classes they make.
OBSTACLE_TYPES = ("halfspace", "sphere", "capsule", "cylinder", "box")
#: Deepest start penetration a scene may have, as a fraction of the segment's radius: an arm at
#: rest on an obstacle sinks by ``(w / k)^(1/e)`` (0.3 mm for 0.5 kg/m at the default law), a
#: few per cent of a soft arm's radius; an arm placed inside an obstacle starts with a force
#: of ``k d^e`` per metre, a launch rather than a rest.
MAX_START_PENETRATION = 0.1

CONTACT = KeyTable("contact", "The contact law (`qchain.contact.ContactLaw`, `qchain/contact/forces.py`): at each of `nodes` "
                   "contact points a segment (a ball of the segment's radius standing for `l0 / nodes` of tube), "
                   "penetration `d`, the normal force `(l0 / nodes) k d^e max(0, 1 + c d')` and regularised Coulomb "
                   "friction. Used only with `[[obstacles]]`.", (
    Field("stiffness", "number", "`k`, per metre of tube.", B.CONTACT_STIFFNESS, default=f"{_LAW['stiffness']:g}"),
    Field("exponent", "number", "`e`: 1.5 Hertz's, 1 a linear spring.", B.CONTACT_EXPONENT,
          default=f"{_LAW['exponent']:g}"),
    Field("damping", "number", "Hunt-Crossley `c`; or `restitution` and `impact_speed` instead, not both.",
          B.CONTACT_DAMPING, default=f"{_LAW['damping']:g}"),
    Field("restitution", "number", "With `impact_speed`: `damping = hunt_crossley_damping(restitution, "
          "impact_speed)`.", B.RESTITUTION, default="none"),
    Field("impact_speed", "number", "The impact speed `restitution` holds at; only with it.", B.IMPACT_SPEED,
          default="none"),
    Field("mu_static", "number", "Static friction coefficient, `>= mu_dynamic`.", B.FRICTION,
          default=f"{_LAW['mu_static']:g}"),
    Field("mu_dynamic", "number", "Dynamic friction coefficient.", B.FRICTION, default=f"{_LAW['mu_dynamic']:g}"),
    Field("slip_velocity", "number", "Sliding speed over which friction grows to its full value.", B.SLIP_VELOCITY,
          default=f"{_LAW['slip_velocity']:g}"),
    Field("stribeck_velocity", "number", "Sliding speed over which `mu_static` falls to `mu_dynamic`.",
          B.SLIP_VELOCITY, default=f"{_LAW['stribeck_velocity']:g}"),
    Field("nodes", "integer", "Contact points a segment.", B.CONTACT_NODES,
          default="the fewest that keep the ripple of the chain of balls within a quarter of the penetration at "
          "rest (`qchain.contact.contact_nodes`, docs/contact.md)"),
))

OBSTACLE = KeyTable("obstacles[]", "One table an obstacle: `[[obstacles]]`. Fixed in the world, or carried by a "
                    "prescribed translation `u(t) = velocity t + amplitude sin(2 pi frequency t + phase)` (world frame, "
                    "`qchain.contact.Motion`) added to its placement: give `velocity`, or `amplitude` with `frequency` "
                    "(and `phase`), or both. An arm that starts inside one (where it is at t = 0) deeper than "
                    f"{MAX_START_PENETRATION:.0%} of a segment's radius is refused.", (
    Field("type", "choice", "The shape.", choices=OBSTACLE_TYPES, required=True),
    Field("name", "string", "Free text, for messages and `qchain info`.", default='"obstacles[i]"'),
    Field("point", "vector", "A point on the plane.", B.POSITION, default="[0, 0, 0]", size=3, when=("halfspace",)),
    Field("normal", "vector", "The plane's normal, out of the solid (normalised, not zero).", B.DIRECTION,
          default="[0, 0, 1]", size=3, when=("halfspace",)),
    Field("center", "vector", "The centre.", B.POSITION, required=True, size=3, when=("sphere", "box")),
    Field("radius", "number", "The radius.", B.EXTENT, required=True, when=("sphere", "capsule", "cylinder")),
    Field("a", "vector", "One end of the axis.", B.POSITION, required=True, size=3, when=("capsule", "cylinder")),
    Field("b", "vector", "The other end (not `a`).", B.POSITION, required=True, size=3,
          when=("capsule", "cylinder")),
    Field("half_extents", "vector", "Half the box's sides, along its own axes.", B.EXTENT, required=True, size=3,
          when=("box",)),
    Field("rpy", "vector", "The box's roll-pitch-yaw, `R = Rz(yaw) Ry(pitch) Rx(roll)`.", B.ANGLE,
          default="[0, 0, 0]", size=3, when=("box",)),
    Field("velocity", "vector", "The motion's drift velocity, world frame.", MOTION_RANGES["velocity"],
          default="[0, 0, 0]", size=3),
    Field("amplitude", "vector", "The motion's sine amplitude, world frame; needs `frequency`.",
          MOTION_RANGES["amplitude"], default="[0, 0, 0]", size=3),
    Field("frequency", "number", "The sine's frequency, > 0; only with `amplitude`.", MOTION_RANGES["frequency"],
          default="none"),
    Field("phase", "number", "The sine's phase at t = 0; only with `amplitude`.", MOTION_RANGES["phase"],
          default="0"),
))
#: The keys of ``[[obstacles]]`` that make its :class:`qchain.contact.Motion`.
OBSTACLE_MOTION_KEYS = ("velocity", "amplitude", "frequency", "phase")

LOAD = KeyTable("loads[]", "One table a point load (`qchain.contact.PointLoad`): `[[loads]]`.", (
    Field("segment", "integer", "The segment it acts on, from 0 at the base.", Range(0, None, integer=True),
          required=True),
    Field("alpha", "number", "Where along the segment: 0 its root, 1 its tip.", Range(0.0, 1.0), required=True),
    Field("force", "vector", "The force.", replace(B.FORCE, unit="N"), default="[0, 0, 0]", size=3),
    Field("moment", "vector", "The moment.", replace(B.FORCE, unit="N m"), default="[0, 0, 0]", size=3),
    Field("local", "boolean", "`true`: in the slice's own frame, turning with it (a follower load); `false`: world "
          "frame.", default="false"),
))

#: Every table of the format, in the order of the documentation.
TABLES = (TOP, MODEL, SEGMENT, BASE, MOTION, PRESSURE, INITIAL, SIMULATION, OUTPUT, BUDGET, CONTACT, OBSTACLE, LOAD,
          PAYLOAD, TENDONS, TENSION)


# --------------------------------------------------------------------------------------
# problems and the error


@dataclass(frozen=True)
class Problem:
    """One problem of a scene file: the dotted ``key``, what was ``expected``, what was ``found``."""

    key: str
    expected: str
    found: str

    def __str__(self) -> str:
        return f"{self.key}: expected {self.expected}, found {self.found}"


_MISSING = object()


def _type_name(v) -> str:
    for kind, name in ((bool, "a boolean"), (int, "an integer"), (float, "a float"), (str, "a string"),
                       (list, "an array"), (dict, "a table")):  # bool before int: a bool is an int
        if isinstance(v, kind):
            return name
    return f"a {type(v).__name__}"


def _show(v, limit: int = 60) -> str:
    """A TOML-like rendering of a value, cut at ``limit`` characters (built only that far,
    so a huge or deeply nested value costs no more than a small one)."""
    out: list[str] = []
    size = 0

    def emit(s: str) -> bool:
        nonlocal size
        out.append(s)
        size += len(s)
        return size > limit

    def walk(x, depth: int) -> bool:
        if depth > 8:
            return emit("...")
        if isinstance(x, bool):
            return emit("true" if x else "false")
        if isinstance(x, str):
            return emit('"' + x[: limit + 1] + '"')
        if isinstance(x, float):
            return emit(repr(x))
        if isinstance(x, int):
            return emit(str(x) if x.bit_length() < 200 else f"{str(x)[:limit]}...")
        if isinstance(x, list):
            if emit("["):
                return True
            for i, y in enumerate(x):
                if (i and emit(", ")) or walk(y, depth + 1):
                    return True
            return emit("]")
        if isinstance(x, dict):
            if emit("{"):
                return True
            for i, (k, y) in enumerate(x.items()):
                if (i and emit(", ")) or emit(f"{k} = ") or walk(y, depth + 1):
                    return True
            return emit("}")
        return emit(str(x)[: limit + 1])

    walk(v, 0)
    s = "".join(out)
    return s if len(s) <= limit else s[: limit - 3] + "..."


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _as_float(v) -> float | None:
    """``float(v)`` of a TOML number, None for an integer too large for a float."""
    try:
        return float(v)
    except OverflowError:
        return None


# --------------------------------------------------------------------------------------
# before parsing

_TOKENS = re.compile(r'"""[\s\S]*?"""|\'\'\'[\s\S]*?\'\'\'|"(?:[^"\\\n]|\\.)*"|\'[^\'\n]*\'|#[^\n]*|[\[\]{}]')


def nesting_problem(text: str) -> Problem | None:
    """A :class:`Problem` if ``text`` is larger than :data:`MAX_SCENE_BYTES` or nests arrays
    and inline tables deeper than :data:`MAX_DEPTH` (outside strings and comments), else None."""
    if len(text) > MAX_SCENE_BYTES:
        return Problem("(file)", f"a scene file of at most {MAX_SCENE_BYTES} bytes", f"{len(text)} characters")
    depth = 0
    for m in _TOKENS.finditer(text):
        c = m.group()
        if c == "[" or c == "{":
            depth += 1
            if depth > MAX_DEPTH:
                line = text.count("\n", 0, m.start()) + 1
                return Problem("(file)", f"arrays and inline tables nested at most {MAX_DEPTH} deep",
                               f"deeper nesting at line {line}")
        elif c == "]" or c == "}":
            depth = max(depth - 1, 0)
    return None


# --------------------------------------------------------------------------------------
# the checker


class _Checker:
    """Walks the parsed TOML, collecting :class:`Problem` s instead of stopping at the first."""

    def __init__(self):
        self.problems: list[Problem] = []

    def add(self, key: str, expected: str, found: str) -> None:
        self.problems.append(Problem(key, expected, found))

    def keys(self, d: dict, path: str, allowed) -> None:
        allowed = list(allowed)
        for k in d:
            if k not in allowed:
                close = (difflib.get_close_matches(k, allowed, n=1, cutoff=0.7)
                         if len(k) < 100 and len(self.problems) < MAX_LISTED else [])  # hints where they are shown
                hint = f" (did you mean {close[0]!r}?)" if close else ""
                self.add(f"{path}.{k}" if path else k, f"one of the keys {', '.join(allowed)}{hint}",
                         f"the unknown key {_show(k)}" if len(k) > 40 else f"the unknown key {k!r}")

    def section(self, d: dict, key: str, allowed) -> dict:
        """The optional table ``d[key]`` (``{}`` if missing or wrong), its keys checked against ``allowed``."""
        t = self.table(d, key, key) or {}
        self.keys(t, key, allowed)
        return t

    def table(self, d: dict, key: str, path: str, required: bool = False) -> dict | None:
        if required and key not in d:
            self.add(path, "a table", "nothing")
        return self._typed(d, key, path, None, dict, "a table")

    def field(self, d: dict, f: Field, path: str, default=None):
        """The value of the declared field ``f`` of table ``d`` (scalar kinds), checked
        against its declaration; ``default`` when it is missing (or wrong)."""
        if f.kind == "number":
            return self.number(d, f.key, path, f.range.unit if f.range else "", default=default, required=f.required,
                               bounds=f.range)
        if f.kind == "integer":
            r = f.range or Range(1, None, integer=True)
            return self.integer(d, f.key, path, default=default, minimum=int(r.low),
                                maximum=None if r.high is None else int(r.high))
        if f.kind == "boolean":
            return self.boolean(d, f.key, path, default)
        if f.kind == "string":
            return self.string(d, f.key, path, default)
        if f.kind == "choice":
            return self.choice(d, f.key, path, f.choices, default=default, required=f.required)
        if f.kind == "vector":
            if f.key not in d and f.required:
                self.add(path, f"an array of {f.size} numbers", "nothing (the key is required)")
                return None
            return self.vector(d, f.key, path, f.size, f.range.unit if f.range else "", default=default, bounds=f.range)
        if f.kind == "matrix":
            return self.matrix(d, f.key, path, f.size, f.range, default=default)
        raise ValueError(f"field {f.key}: kind {f.kind!r} is not a scalar kind")  # pragma: no cover

    def number(self, d: dict, key: str, path: str, unit: str = "", *, default=None, required: bool = False,
               bounds: Range):
        """A finite real number inside ``bounds``."""
        v = d.get(key, _MISSING)
        what = replace(bounds, unit="", integer=False).what() + (f" ({unit})" if unit else "")
        if v is _MISSING:
            if required:
                self.add(path, what, "nothing (the key is required)")
            return default
        if not _is_number(v):
            self.add(path, what, f"{_type_name(v)} {_show(v)}")
            return default
        x = _as_float(v)
        if x is None:
            self.add(path, what, f"an integer too large for a float, {_show(v)}")
            return default
        if not math.isfinite(x):
            self.add(path, what.replace("a number", "a finite number", 1), _show(v))
            return default
        if not bounds.contains(x):
            self.add(path, what, _show(v))
            return default
        return x + 0.0  # -0.0 is 0 (no "-0" in messages and descriptions)

    def integer(self, d: dict, key: str, path: str, *, default=None, minimum: int = 1, maximum: int | None = None):
        v = d.get(key, _MISSING)
        if v is _MISSING:
            return default
        what = f"an integer >= {minimum}" + (f" and <= {maximum}" if maximum is not None else "")
        if not isinstance(v, int) or isinstance(v, bool):
            self.add(path, what, f"{_type_name(v)} {_show(v)}")
            return default
        if v < minimum or (maximum is not None and v > maximum):
            self.add(path, what, _show(v))
            return default
        return int(v)

    def boolean(self, d: dict, key: str, path: str, default: bool) -> bool:
        return self._typed(d, key, path, default, bool, "true or false")

    def string(self, d: dict, key: str, path: str, default: str | None = None) -> str | None:
        return self._typed(d, key, path, default, str, "a string")

    def _typed(self, d: dict, key: str, path: str, default, kind: type, what: str):
        """``d[key]`` if it is a ``kind`` (``what`` in the problem otherwise), ``default`` if missing or not."""
        v = d.get(key, _MISSING)
        if v is _MISSING:
            return default
        if not isinstance(v, kind):
            self.add(path, what, f"{_type_name(v)} {_show(v)}")
            return default
        return v

    def path(self, d: dict, key: str, path: str, default: str) -> str | None:
        """A folder path: a non-empty string with no NUL and no component over
        :data:`MAX_NAME_BYTES` bytes."""
        v = self.string(d, key, path, default)
        if v is None:
            return None
        if not v.strip():
            self.add(path, "a folder path", _show(v))
            return None
        if has_nul(v):
            self.add(path, "a folder path without a NUL character", _show(show_nul(v)))
            return None
        size = len(v.encode("utf-8", "surrogatepass"))
        if size > MAX_PATH_BYTES:
            self.add(path, f"a folder path of at most {MAX_PATH_BYTES} bytes", f"{size} bytes, {_show(v)}")
            return None
        for part in re.split(r"[/\\]", v):
            if len(part.encode("utf-8", "surrogatepass")) > MAX_NAME_BYTES:
                self.add(path, f"path components of at most {MAX_NAME_BYTES} bytes",
                         f"a component of {len(part.encode('utf-8', 'surrogatepass'))} bytes, {_show(part)}")
                return None
        return v

    def choice(self, d: dict, key: str, path: str, choices, default=None, required: bool = False,
               ignore_case: bool = False):
        v = d.get(key, _MISSING)
        options = ", ".join(f'"{c}"' for c in choices)
        if v is _MISSING:
            if required:
                self.add(path, f"one of {options}", "nothing (the key is required)")
            return default
        if isinstance(v, str):
            for c in choices:
                if v == c or (ignore_case and v.lower() == c.lower()):
                    return c
        close = difflib.get_close_matches(v, list(choices), n=1, cutoff=0.7) if isinstance(v, str) and len(v) < 100 \
            else []
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        self.add(path, f"one of {options}{hint}", f"{_type_name(v)} {_show(v)}")
        return default

    def _numbers(self, v, path: str, what: str, bounds: Range | None = None) -> np.ndarray | None:
        """A flat list of finite numbers (inside ``bounds``), or None (with a problem)."""
        if not isinstance(v, list):
            self.add(path, what, f"{_type_name(v)} {_show(v)}")
            return None
        for i, x in enumerate(v):
            fx = _as_float(x) if _is_number(x) else None
            if fx is None or not math.isfinite(fx):
                self.add(f"{path}[{i}]", "a finite number", f"{_type_name(x)} {_show(x)}")
                return None
        arr = np.array(v, dtype=float) + 0.0  # -0.0 is 0
        if bounds is not None:
            bad = bounds.outside(arr)
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                self.add(f"{path}[{i}]", bounds.what(), _show(v[i]))
                return None
        return arr

    def vector(self, d: dict, key: str, path: str, size: int, unit: str = "", default=None,
               bounds: Range | None = None):
        v = d.get(key, _MISSING)
        what = f"an array of {size} numbers{f' ({unit})' if unit else ''}"
        arr = None if v is _MISSING else self._numbers(v, path, what, bounds)
        if arr is not None and arr.size != size:
            self.add(path, what, f"{arr.size} numbers {_show(v)}")
            arr = None
        return arr if arr is not None or default is None else np.array(default, dtype=float)

    def matrix(self, d: dict, key: str, path: str, size: int, bounds: Range, default=None):
        """A (size, size) array given as ``size`` arrays (rows) of ``size`` numbers inside ``bounds``."""
        v = d.get(key, _MISSING)
        if v is _MISSING:
            return default
        what = f"{size} arrays of {size} numbers, one a row{f' ({bounds.unit})' if bounds.unit else ''}"
        if not isinstance(v, list) or len(v) != size or not all(isinstance(row, list) for row in v):
            self.add(path, what, f"{_type_name(v)} {_show(v)}")
            return None
        out = np.empty((size, size))
        for i, row in enumerate(v):
            arr = self._numbers(row, f"{path}[{i}]", f"an array of {size} numbers (row {i})", bounds)
            if arr is None:
                return None
            if arr.size != size:
                self.add(f"{path}[{i}]", f"an array of {size} numbers (row {i})", f"{arr.size} numbers {_show(row)}")
                return None
            out[i] = arr
        return out

    def per_segment(self, v, path: str, n: int | None, unit: str = "", width: int = 3,
                    bounds: Range | None = None) -> np.ndarray | None:
        """``n * width`` numbers, flat or as ``n`` lists of ``width``; shape (n, width)."""
        what = (f"{width * n} numbers ({width} a segment x {n} segment{'s' if n != 1 else ''}), flat or as {n} "
                f"arrays of {width}{f', {unit}' if unit else ''}") if n is not None else "numbers"
        if not isinstance(v, list):
            self.add(path, what, f"{_type_name(v)} {_show(v)}")
            return None
        if n is None:  # the segment count is unknown (bad segments): check the entries only
            return None
        if v and all(isinstance(x, list) for x in v):
            if len(v) != n:
                self.add(path, what, f"{len(v)} arrays {_show(v)}")
                return None
            out = np.empty((n, width))
            for j, row in enumerate(v):
                arr = self._numbers(row, f"{path}[{j}]", f"an array of {width} numbers", bounds)
                if arr is None:
                    return None
                if arr.size != width:
                    self.add(f"{path}[{j}]", f"an array of {width} numbers (segment {j})", f"{arr.size} numbers {_show(row)}")
                    return None
                out[j] = arr
            return out
        if len(v) != n * width:
            if all(_is_number(x) for x in v):
                self.add(path, what, f"{len(v)} numbers {_show(v)}")
                return None
        arr = self._numbers(v, path, what, bounds)  # (a list of numbers of another length is said above)
        return None if arr is None else arr.reshape(n, width)


# --------------------------------------------------------------------------------------
# the documentation

EXAMPLE = '''\
name = "three-segment wave"
gravity = [0.0, 0.0, -9.81]

[model]
node_tolerance = 1e-8

[[segments]]
count = 3
length = 0.1
radius = 0.015
mass = 0.05
chamber_area = 4.5e-5
chamber_radius = 0.0085
youngs_modulus = 1e5
damping = 0.01

[base]
type = "fixed"
position = [0.0, 0.0, 0.5]
rpy = [3.141592653589793, 0.0, 0.0]

[pressure]
type = "sine"
amplitude = [20e3, 0, 0,  20e3, 0, 0,  20e3, 0, 0]
offset = [20e3, 0, 0,  20e3, 0, 0,  20e3, 0, 0]
frequency = 0.5
segment_phase = -1.0

[initial]
q_e = [[0.1, 0.0, 0.0], [0.1, 0.0, 0.0], [0.1, 0.0, 0.0]]

[simulation]
duration = 2.0
method = "radau5"
rtol = 1e-6
atol = 1e-8

[output]
sample_rate = 100.0
folder = "out/wave"
plots = ["tip", "arm"]
'''


#: The contact tables, as :data:`EXAMPLE` would add them (a ground under the hanging arm, a
#: pole beside it, a load at its tip).
CONTACT_EXAMPLE = '''\
[contact]
stiffness = 1e6
exponent = 1.5
restitution = 0.8
impact_speed = 0.5
mu_static = 0.5
mu_dynamic = 0.4
nodes = 16

[[obstacles]]
type = "halfspace"
name = "ground"

[[obstacles]]
type = "cylinder"
name = "pole"
a = [0.1, -0.2, 0.0]
b = [0.1, 0.2, 0.0]
radius = 0.02

[[loads]]
segment = 2
alpha = 1.0
force = [0.0, 0.0, -0.5]
'''


def markdown() -> str:
    """``docs/scene-format.md``: the format as tables of keys, generated from :data:`TABLES`."""
    out = [
        "# Scene file format",
        "",
        "<!-- Generated from qchain/scene/format.py by `.venv/bin/python -m qchain.scene.format > docs/scene-format.md`;",
        "     tests/test_scene_values.py checks that this file is up to date. Do not edit by hand. -->",
        "",
        "A scene file is TOML describing a soft arm, its inputs and a run (`qchain run SCENE.toml`,",
        "`qchain.load_scene(path)`). Units are SI throughout: m, kg, s, Pa, rad, Hz. Every key is",
        "optional unless marked **required**; a key a table does not know, a value of the wrong type,",
        "a number outside its range, NaN or infinity, and a boolean where a number belongs are",
        "refused: `load_scene` raises one `SceneError` listing every problem as",
        "`file: key: expected ..., found ...` with the dotted key (`segments[1].radius`,",
        "`pressure.values[2]`).",
        "",
        f"A file is at most {MAX_SCENE_BYTES} bytes of UTF-8 and nests arrays and inline tables at most",
        f"{MAX_DEPTH} deep. Ranges are `qchain/checks/bounds.py`'s, the same that `qchain.Segment` and",
        "`qchain.simulate` check; they are far wider than any soft arm needs and keep every",
        "product of them finite.",
        "",
        "## Example",
        "",
        "```toml",
        EXAMPLE.rstrip("\n"),
        "```",
        "",
        "Contact with obstacles and point loads (`qchain/contact/`) is three more tables: the law,",
        "the obstacles (world frame) and the loads. Added to the example, these lay a ground and a",
        "pole across the arm's plane under it and hang 0.5 N from its tip:",
        "",
        "```toml",
        CONTACT_EXAMPLE.rstrip("\n"),
        "```",
        "",
        "A payload at the tip (a rigid body; `examples/carry_payload.py` lifts one) is one more",
        "table; this one is a 60 g ball of 20 mm radius centred 20 mm beyond the tip:",
        "",
        "```toml",
        PAYLOAD_EXAMPLE.rstrip("\n"),
        "```",
        "",
        "Tendons (`qchain.Tendon`, docs/tendons.md) are an array of tables and their tensions one",
        "schedule; these run two straight tendons on opposite sides of the example's arm, one to",
        "the tip and one to the middle segment's tip, and ramp their tensions up over a second",
        "(`examples/scenes/hanging_tendons.toml` runs a tendon-driven arm):",
        "",
        "```toml",
        TENDON_EXAMPLE.rstrip("\n"),
        "```",
        "",
    ]
    for t in TABLES:
        out += t.markdown()
    out += [
        "## Checks across keys",
        "",
        "* the chambers fit: `chamber_radius + sqrt(chamber_area / pi) <= radius`;",
        "* `max_bend` only with `node_tolerance`;",
        "* `base.velocity` and `base.angular_velocity` only with a floating base, `base.motion` only (and",
        "  always) with a prescribed one; `plots = [\"momentum\"]` only with a floating base;",
        "* pressures at or above a vacuum, -101325 Pa gauge, at all times (a sine's `offset - abs(amplitude)`);",
        "* `dt` with a fixed-step method only and `<= duration`; `max_step` with an adaptive one only;",
        "* the initial state inside the model, its mass matrix and energies finite;",
        "* `[contact]`: `damping`, or `restitution` with `impact_speed`, not both; `mu_dynamic <= mu_static`;",
        "* obstacles that are shapes: a half-space's `normal` not zero, a capsule's or cylinder's `b` at least",
        "  1e-9 m from `a`; a load's `segment` one the arm has (`count` expanded);",
        "* an obstacle's motion: `amplitude` and a `frequency > 0` together (a sine of frequency 0 is a",
        "  constant offset), `phase` only with them;",
        f"* the arm starts outside every obstacle: inside one by more than {MAX_START_PENETRATION:.0%} of a segment's "
        "radius is",
        "  refused, naming the obstacle, the segment and the depth (mm), a moving obstacle where its",
        "  motion puts it at t = 0 (`amplitude sin(phase)` from its placement). An arm resting on an obstacle",
        "  sinks by `(w / k)^(1/e)` for its weight `w` per metre (0.3 mm, 2 % of a 15 mm radius, for",
        "  0.5 kg/m at the default law), so a rest state passes and an arm placed through an obstacle does not;",
        "* the planar model (`[model]`) only when every obstacle and load is symmetric about the base's",
        "  x-z plane: half-space normals, world load forces in it, load moments normal to it; sphere and",
        "  box centres in it, box axes one normal to it; capsule and cylinder ends both in it or each",
        "  the other's mirror image; an obstacle's motion `velocity` and `amplitude` in it; follower",
        "  (`local`) loads with no slice-y force and only a slice-y moment;",
        "  and a payload symmetric about the tip frame's x-z plane (`lever[1] = 0`, `inertia[0][1] =",
        "  inertia[1][2] = 0`); otherwise `qchain info` says which one keeps the full model;",
        "* `[payload]`: `inertia` symmetric and positive semi-definite (a rigid body's), zeros when `mass = 0`;",
        "* `[tension]` only with `[[tendons]]`, one tension a tendon, each `>= 0` (a tendon pulls); a",
        "  tendon's `end` a segment the arm has (`count` expanded); a scene with tendons keeps the full",
        "  (not planar) model and every segment's `l` free (the tensions shorten the arm);",
        "* the run within its budget: `[budget]` above, whose message names the key that makes the",
        "  cost (`simulation.dt`, `simulation.max_step`, `pressure.frequency`, `base.motion.frequency`,",
        "  `output.sample_rate`, `segments[i].count`) and the bound to raise.",
        "",
    ]
    return "\n".join(out)


if __name__ == "__main__":  # pragma: no cover - the documentation's generator
    import sys

    sys.stdout.write(markdown())
