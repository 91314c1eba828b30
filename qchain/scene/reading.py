"""Reading a scene file: :func:`load_scene` and :func:`parse_scene` check the whole TOML text
against its declaration (:mod:`qchain.scene.format`) and the run budget, and make a
:class:`~qchain.scene.Scene` or raise one :class:`~qchain.scene.format.SceneError` listing
every problem (``docs/scene-format.md``)."""

from __future__ import annotations

import math
import os
import stat
import tomllib
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from . import format as F
from ..checks.bounds import VACUUM_GAUGE, Range
from ..sim.budget import DEFAULT, Budget
from ..checks.convert import describe_value
from ..checks.paths import file_kind
from ..sim.inputs import Constant, Ramp, Schedule, Sine, Step, Table
from .format import _MISSING, PLOTS, Problem, SceneError, _as_float, _Checker, _is_number, _show, _type_name
from .cost import _cost, _frequency
from ..checks.text import show_matrix, show_vector
from .parts import BaseSpec, SegmentSpec, SineMotion
from .payload import read_payload
from ..model.tendon import Tendon
from .tendons import TENDONS, TENSION
from .stretch import DEFAULT_LENGTH_TOLERANCE
from .surroundings import read_surroundings
from ..model.segment import Segment
from ..sim.simulation import DEFAULT_METHOD, FIXED_STEP, METHODS  # a scene may name any method, without case

if TYPE_CHECKING:
    from .scene import Scene

__all__ = ["load_scene", "parse_scene"]


def _file_problem(p: Path, what: str = "scene file") -> Problem | None:
    """Why ``p`` cannot be read as a ``what`` (missing, a folder, a FIFO or device, too
    large, a path too long or a loop of links), or None; opened without blocking, so a FIFO
    cannot hang the check."""
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        return Problem("(file)", f"an existing {what}", "no such file")
    except IsADirectoryError:
        return Problem("(file)", f"a {what}", "a folder")
    except ValueError as err:  # a NUL character
        return Problem("(file)", f"a readable {what}", str(err))
    except OSError as err:
        return Problem("(file)", f"a readable {what}", err.strerror or str(err))
    try:
        st = os.fstat(fd)
    finally:
        os.close(fd)
    if stat.S_ISDIR(st.st_mode):
        return Problem("(file)", f"a {what}", "a folder")
    if not stat.S_ISREG(st.st_mode):
        return Problem("(file)", f"a regular {what}", file_kind(st.st_mode))
    if st.st_size > F.MAX_SCENE_BYTES:
        return Problem("(file)", f"a {what} of at most {F.MAX_SCENE_BYTES} bytes", f"{st.st_size} bytes")
    return None


def _read_text(p: Path, what: str, error) -> str:
    """The UTF-8 text of the file ``p`` within a scene file's limits (:func:`_file_problem`)."""
    bad = _file_problem(p, what)
    if bad is not None:
        raise error(str(p), [bad])
    try:
        with open(p, "rb") as fh:
            data = fh.read(F.MAX_SCENE_BYTES + 1)
        return data.decode("utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise error(str(p), [Problem("(file)", "a readable UTF-8 text file", str(err))]) from None


def read_toml(path: str | os.PathLike, what: str = "scene file", error=SceneError) -> tuple[str, dict]:
    """The text of the TOML file ``path`` and its table, read within a scene file's limits (a
    regular file of at most :data:`qchain.scene.format.MAX_SCENE_BYTES` bytes of UTF-8, nested at
    most :data:`qchain.scene.format.MAX_DEPTH` deep); ``error`` (a :class:`SceneError` subclass)
    names the file and the problem otherwise."""
    text = _read_text(Path(path), what, error)
    return text, _parse_toml(text, str(Path(path)), error)


def _parse_toml(text: str, where: str, error) -> dict:
    """The table of the TOML ``text`` nested at most :data:`qchain.scene.format.MAX_DEPTH` deep,
    or ``error`` (:class:`SceneError` or a subclass) naming ``where`` and the problem."""
    bad = F.nesting_problem(text)
    if bad is not None:
        raise error(where, [bad])
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as err:
        raise error(where, [Problem("(file)", "valid TOML", f"a syntax error: {err}")]) from None


def load_scene(path: str | os.PathLike) -> Scene:
    """Read and validate a scene file (TOML, ``docs/scene-format.md``): ``TypeError`` if ``path``
    is not a path, one :class:`SceneError` listing every problem of a file that cannot be read,
    is not TOML or does not describe a scene."""
    if not isinstance(path, (str, os.PathLike)):
        raise TypeError(f"load_scene: path must be a str or os.PathLike naming a scene file, got "
                        f"{describe_value(path)}")
    p = Path(path)
    return parse_scene(_read_text(p, "scene file", SceneError), p)


def parse_scene(text: str, path: str | os.PathLike | None = None) -> Scene:
    """Validate the TOML ``text`` (a ``str``, or UTF-8 ``bytes``) of a scene; ``path`` names it in
    errors and sets the default output folder (``out/<stem>``). Raises as :func:`load_scene`."""
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
    raw = _parse_toml(text, where, SceneError)
    ck = _Checker()
    ck.keys(raw, "", F.TOP.keys())
    name = ck.field(raw, F.TOP["name"], "name", "") or ""
    description = ck.field(raw, F.TOP["description"], "description", "") or ""
    gravity = ck.field(raw, F.TOP["gravity"], "gravity", default=(0.0, 0.0, -9.81))  # (the default if wrong)
    budget = _budget(ck, raw)

    # model
    mt = ck.section(raw, "model", F.MODEL.keys())
    reduce = ck.field(mt, F.MODEL["reduce"], "model.reduce", True)
    node_tol = ck.field(mt, F.MODEL["node_tolerance"], "model.node_tolerance")
    max_bend = ck.field(mt, F.MODEL["max_bend"], "model.max_bend")
    length_tol = ck.field(mt, F.MODEL["length_tolerance"], "model.length_tolerance", DEFAULT_LENGTH_TOLERANCE)
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
    surroundings = read_surroundings(ck, raw, segments, gravity)
    payload = read_payload(ck, raw)
    tendons, tension, tspec = read_tendons(ck, raw, n)

    # output
    O = F.OUTPUT
    ot = ck.section(raw, "output", O.keys())
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
    from .scene import Scene  # here: qchain.scene imports this module

    scene = Scene(
        path=Path(path) if path is not None else None, text=text, name=name, description=description,
        segments=segments, base=base, gravity=gravity, pressure=pressure, pressure_spec=pspec, q_e0=q_e0,
        v_e0=v_e0, duration=duration, method=method, rtol=rtol, atol=atol, dt=dt, max_step=max_step,
        reduce=reduce, node_tolerance=node_tol, max_bend=max_bend, sample_rate=rate, output_folder=Path(folder),
        plots=tuple(dict.fromkeys(plots)), save=save, budget=budget, surroundings=surroundings, payload=payload,
        length_tolerance=length_tol, tendons=tendons, tension=tension, tension_spec=tspec,
    )
    bad = scene.start_problems()  # the arm at its start, inside an obstacle: needs the whole scene
    if bad:
        raise SceneError(where, bad)
    return scene


def _budget(ck: _Checker, raw: dict) -> Budget:
    bt = ck.section(raw, "budget", F.BUDGET.keys())
    return Budget(**{k: ck.field(bt, F.BUDGET[k], f"budget.{k}", getattr(DEFAULT, k)) for k in F.BUDGET.keys()})


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
        least = _cost(total, "fixed", DEFAULT_METHOD, None, math.inf, 1e-300, 1.0, 0.0)  # the matrices alone
        over = [(k, e, f) for k, e, f in budget.problems(least) if k == "max_memory"]
        if over:  # said now, before thousands of segments are made only to be refused at the end
            key, expected, found = over[0]
            ck.add("segments", f"{expected} (budget.{key}; raise it in [budget] to allow more)",
                   f"{found}, with the {total} segments up to {path}")
            return None
        vals = {k: ck.field(s, T[k], f"{path}.{k}", default) for k, default in (
            ("length", None), ("radius", None), ("mass", None), ("chamber_area", None), ("chamber_radius", None),
            ("youngs_modulus", None), ("damping", 0.0), ("damping_matrix", None), ("drag_linear", 0.0),
            ("drag_quadratic", 0.0), ("coords", "curvature"), ("actuation", "volume"), ("extensible", True),
            ("nodes", None))}
        if len(ck.problems) == start:
            _damping_law(ck, vals, path)
        if len(ck.problems) == start:  # the values are good one by one: now together
            r, rc, A = vals["radius"], vals["chamber_radius"], vals["chamber_area"]
            outer = rc + math.sqrt(A / math.pi)
            if outer > r:
                ck.add(f"{path}.chamber_radius", f"chambers inside the segment: chamber_radius + sqrt(chamber_area/pi) "
                       f"<= radius = {r:g} m", f"{rc:g} + {math.sqrt(A / math.pi):.6g} = {outer:.6g} m")
            else:
                spec = SegmentSpec(**vals, source=path)
                try:
                    spec.segment(nodes=spec.nodes)
                except (ValueError, TypeError) as err:  # anything the constructor checks beyond the above
                    ck.add(path, "a valid segment", str(err))
        if len(ck.problems) > start:
            ok = False
            start = len(ck.problems)
            continue
        out += [replace(spec, source=path if count == 1 else f"{path} (copy {c + 1} of {count})")
                for c in range(count or 1)]
    return out if ok else None


def _damping_law(ck: _Checker, vals: dict, path: str) -> None:
    """Check a segment's ``damping_matrix`` (symmetric, positive semi-definite, alone, in
    curvature coordinates) and drag (curvature coordinates), each by key, value and bound;
    ``vals["damping_matrix"]`` becomes its rows as a tuple of tuples (hashable)."""
    D = vals["damping_matrix"]
    if D is not None:
        key = f"{path}.damping_matrix"
        scale = max(1.0, float(np.abs(D).max()))
        asym = np.argwhere(~np.isclose(D, D.T, rtol=1e-12, atol=0.0))  # qchain.Segment's test
        if asym.size:
            i, j = (int(x) for x in asym[0])
            ck.add(key, f"a symmetric matrix (entry [{i}][{j}] equal to [{j}][{i}] within 1e-12 relative)", f"[{i}][{j}] = {float(D[i, j])!r}, [{j}][{i}] = {float(D[j, i])!r}")
        else:
            low = float(np.linalg.eigvalsh(0.5 * (D + D.T)).min())
            if low < -1e-12 * scale:
                ck.add(key, "a positive semi-definite matrix (it dissipates: every eigenvalue >= 0 within 1e-12 "
                       "of its largest entry)", f"{show_matrix(D)}, with an eigenvalue {low:.6g}")
        if vals["damping"] != 0.0:
            ck.add(f"{path}.damping", "0 with damping_matrix (the matrix replaces beta K(q0))",
                   f"{vals['damping']!r}")
        vals["damping_matrix"] = tuple(tuple(float(x) for x in row) for row in D)
    if vals["coords"] != "curvature":
        for name in ("damping_matrix", "drag_linear", "drag_quadratic"):
            if vals[name] not in (None, 0.0):
                shown = show_matrix(np.array(vals[name])) if name == "damping_matrix" else f"{vals[name]!r}"
                ck.add(f"{path}.{name}", f'{name} only with coords = "curvature" (it is given and applied in '
                       f'curvature coordinates)', f"{name} = {shown} with coords = {vals['coords']!r}")


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
    pos, rpy, vel, ang = (ck.field(bt, T[k], f"base.{k}", default=(0.0, 0.0, 0.0))
                          for k in ("position", "rpy", "velocity", "angular_velocity"))
    motion = None
    mount = pin.SE3(pin.rpy.rpyToMatrix(*rpy), pos) if rpy is not None and pos is not None else pin.SE3.Identity()
    if kind == "prescribed":
        M = F.MOTION
        mt = ck.table(bt, "motion", "base.motion", required=True)
        if mt is not None:
            ck.keys(mt, "base.motion", M.keys())
            mkind = ck.field(mt, M["type"], "base.motion.type")
            axis = ck.field(mt, M["axis"], "base.motion.axis")
            if axis is not None and not np.any(axis):
                ck.add("base.motion.axis", "a non-zero direction", _show(mt["axis"]))
                axis = None
            amp = ck.number(mt, "amplitude", "base.motion.amplitude", "m" if mkind == "translation" else "rad",
                            required=True, bounds=M["amplitude"].range)
            freq = ck.field(mt, M["frequency"], "base.motion.frequency")
            phase = ck.field(mt, M["phase"], "base.motion.phase", 0.0)
            if len(ck.problems) == start and mkind is not None:
                unit = axis / np.max(np.abs(axis))  # scaled first: the norm of [1e-200, 0, 0] underflows to 0
                motion = SineMotion(kind=mkind, axis=unit / np.linalg.norm(unit), amplitude=amp, frequency=freq,
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
        """Pressures in the range of a chamber (:data:`qchain.checks.bounds.PRESSURE`: a vacuum to 1 GPa)."""
        if arr is not None and rng.outside(arr).any():
            k = int(np.flatnonzero(rng.outside(arr))[0])
            what = f"gauge pressures {rng.text()} (a vacuum to 1 GPa)" if rng is P else f"values {rng.text()}"
            ck.add(f"pressure.{key}", what, f"{rng.shown(arr[k])} Pa at {_where(k)}")
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
            ck.add(f"pressure.{key}", f"values {f.range.text()}", f"{f.range.shown(arr.ravel()[k])} at index {k}")
            return None
        return arr.ravel()

    spec = _schedule_spec(ck, pt, T, "pressure", kind, vec)  # a constant, step or ramp read there
    if kind == "sine":
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
        _sine_within(ck, "pressure", spec, Range(VACUUM_GAUGE, P.high, "Pa"), "in every chamber",
                     lambda k: f"at {_where(k)}", " (a vacuum)")
    elif kind == "table":
        times = pt.get("times", _MISSING)
        values = pt.get("values", _MISSING)
        t_arr = _table_times(ck, pt, "pressure", T["times"].range)
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
    cls, keys = {"constant": (Constant, ("value",)), "step": (Step, ("time", "after", "before")),
                 "ramp": (Ramp, ("t0", "t1", "end", "start")),
                 "sine": (Sine, ("amplitude", "frequency", "phase", "offset")),
                 "table": (Table, ("times", "values"))}[kind]
    try:
        sched = cls(*(spec[k] for k in keys))
    except (ValueError, TypeError) as err:  # pragma: no cover - the checks above cover the schedules' own
        ck.add("pressure", "a valid schedule", str(err))
        return None, {}
    return sched, spec


def _schedule_spec(ck: _Checker, pt: dict, T, table: str, kind: str, vec) -> dict:
    """A schedule table's ``spec`` (``type`` and, for a ``constant``, ``step`` or ``ramp``,
    their keys; the caller reads the others): times by ``T``'s fields, vectors by ``vec(key,
    required)`` (``[pressure]``, ``[tension]``), problems added naming ``table.key``."""
    spec: dict = {"type": kind}
    if kind == "constant":
        spec["value"] = vec("value", required=True)
    elif kind == "step":
        spec["time"] = ck.field(pt, T["time"], f"{table}.time")
        spec["after"] = vec("after", required=True)
        spec["before"] = vec("before")
    elif kind == "ramp":
        spec["t0"] = ck.field(pt, T["t0"], f"{table}.t0")
        spec["t1"] = ck.field(pt, T["t1"], f"{table}.t1")
        if spec["t0"] is not None and spec["t1"] is not None and not spec["t1"] > spec["t0"]:
            ck.add(f"{table}.t1", f"a time > t0 = {spec['t0']:g} s", _show(pt["t1"]))
        spec["end"] = vec("end", required=True)
        spec["start"] = vec("start")
    return spec


def _sine_within(ck: _Checker, table: str, spec: dict, rng: Range, every: str, where, why_low: str) -> None:
    """Add a problem to ``table.offset`` if a ``sine`` schedule's ``spec`` (``amplitude``,
    ``offset``, ``frequency``, ``phase``: arrays, or None where already refused) leaves
    ``rng`` at any time: ``offset -+ |amplitude|``, or the constant ``offset + amplitude
    sin(phase)`` where the frequency is 0; ``where(k)`` names entry ``k``."""
    A, off, f, ph = (spec[k] for k in ("amplitude", "offset", "frequency", "phase"))
    if any(x is None for x in (A, off, f, ph)):
        return
    low = np.where(f > 0, off - np.abs(A), off + A * np.sin(ph))
    high = np.where(f > 0, off + np.abs(A), off + A * np.sin(ph))
    u = rng.unit
    if np.any(low < rng.low):
        k = int(np.flatnonzero(low < rng.low)[0])
        ck.add(f"{table}.offset", f"offset - |amplitude| >= {rng.low:g} {u}{why_low} {every}",
               f"{rng.shown(low[k])} {u} {where(k)}")
    elif np.any(high > rng.high):
        k = int(np.flatnonzero(high > rng.high)[0])
        ck.add(f"{table}.offset", f"offset + |amplitude| <= {rng.high:g} {u} {every}", f"{rng.shown(high[k])} {u} {where(k)}")


def _table_times(ck: _Checker, pt: dict, table: str, rng) -> np.ndarray | None:
    """A ``table`` schedule's ``times`` (``[pressure]``, ``[tension]``): at least one time in
    ``rng``, strictly increasing; None (a problem added, naming the entry) otherwise."""
    if "times" not in pt:
        ck.add(f"{table}.times", "an array of times (s), strictly increasing", "nothing (the key is required)")
        return None
    t_arr = ck._numbers(pt["times"], f"{table}.times", "an array of times (s), strictly increasing", rng)
    if t_arr is not None and t_arr.size == 0:
        ck.add(f"{table}.times", "at least one time (s)", "an empty array")
        return None
    bad = np.flatnonzero(np.diff(t_arr) <= 0) if t_arr is not None else ()
    if len(bad):
        k = int(bad[0])
        ck.add(f"{table}.times[{k + 1}]", f"a time > times[{k}] = {t_arr[k]:g} s (strictly increasing)",
               f"{t_arr[k + 1]:g}")
        return None
    return t_arr


def _valid_rows(values: list, n: int | None, rng) -> list | None:
    """``values`` as a list of ``(3 n,)`` arrays if every row is a flat array of ``3 n`` finite
    numbers inside ``rng``, else None (the row-by-row check then names the first problem)."""
    if (n is None or not values or not all(type(r) is list and len(r) == 3 * n for r in values)
            or not {type(x) for r in values for x in r} <= {int, float}):
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
    it = ck.section(raw, "initial", T.keys())
    n = None if segments is None else len(segments)
    q = v = None
    if "q_e" in it:
        q = ck.per_segment(it["q_e"], "initial.q_e", n)
    if "v" in it:
        v = ck.per_segment(it["v"], "initial.v", n, bounds=T["v"].range)
    if segments is None or (q is None and "q_e" in it) or (v is None and "v" in it):  # (a problem said above)
        return None, None
    if q is None:
        q = np.array([[s.length, 0.0, 0.0] for s in segments])
    if v is None:
        v = np.zeros((n, 3))
    given = "q_e" in it
    for j, s in enumerate(segments):
        if s.coords == "paper" and q[j, 2] == 0.0:  # psi has no meaning at kappa = 0: the paper coordinates' Jacobian is singular
            ck.add(f"initial.q_e[{j}][2]", "kappa > 0 in paper coordinates (at kappa = 0, the straight pose, the bending "
                   "direction psi is undefined; use coords = \"curvature\" for segment "
                   f"{j} to start straight)", f"{show_vector(q[j])}" if given else
                   f"nothing (the default straight pose {show_vector(q[j])})")
            continue
        seg = s.segment(nodes=1)
        try:
            seg.check_configuration(q[j], name=f"segment {j}")
        except ValueError as err:
            ck.add(f"initial.q_e[{j}]", "a configuration inside the model (l > 0, |kappa| r_s < 1"
                   f"{', kappa >= 0' if s.coords == 'paper' else ''})", f"{show_vector(q[j])}: {err}")
            continue
        if q[j, 0] > F.MAX_STRETCH * s.length:
            top = F.MAX_STRETCH * s.length
            ck.add(f"initial.q_e[{j}][0]", f"l <= {F.MAX_STRETCH:g} x length = {top:g} m",
                   repr(float(q[j, 0])) if f"{q[j, 0]:g}" == f"{top:g}" else f"{q[j, 0]:g}")
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
        return f"a non-finite mass matrix at q_e = {show_vector(q)}"
    if not (math.isfinite(T) and math.isfinite(U)):
        return f"kinetic energy {T:g} J, elastic energy {U:g} J at q_e = {show_vector(q)}, v = {show_vector(v)}"
    return None


# --------------------------------------------------------------------------------------
# [[tendons]] and [tension] (declared in qchain/scene/tendons.py)


def read_tendons(ck: _Checker, raw: dict, n: int | None) -> tuple[tuple[Tendon, ...], Schedule | None, dict]:
    """The ``[[tendons]]`` and ``[tension]`` tables of the parsed scene ``raw`` on ``n``
    segments (None: unknown, the segments were refused): ``(tendons, tension schedule or None,
    the tension table as parsed)``; problems are added to ``ck``."""
    tendons: list[Tendon] = []
    ok = True
    tt = raw.get("tendons")
    if tt is not None:
        if not isinstance(tt, list) or not all(isinstance(x, dict) for x in tt):
            ck.add("tendons", "an array of tables [[tendons]]", f"{_type_name(tt)} {_show(tt)}")
            tt, ok = [], False
        for i, t in enumerate(tt):
            path = f"tendons[{i}]"
            start = len(ck.problems)
            ck.keys(t, path, TENDONS.keys())
            radius = ck.field(t, TENDONS["radius"], f"{path}.radius")
            angle = ck.field(t, TENDONS["angle"], f"{path}.angle", 0.0)
            pitch = None
            if "pitch" in t:  # the bound is on |pitch|: its sign picks the hand
                f, v = TENDONS["pitch"], t["pitch"]
                what = f"a number (m) with |pitch| {f.range.text()}"
                x = _as_float(v) if type(v) in (int, float) else None
                if type(v) not in (int, float):
                    ck.add(f"{path}.pitch", what, f"{_type_name(v)} {_show(v)}")
                elif x is None or not math.isfinite(x) or not f.range.contains(abs(x)):
                    ck.add(f"{path}.pitch", what, _show(v))
                else:
                    pitch = x
            end = ck.field(t, TENDONS["end"], f"{path}.end")
            if end is not None and n is not None and end >= n:
                ck.add(f"{path}.end", f"a segment index < {n} (the arm's segments, count expanded)", _show(t["end"]))
            if len(ck.problems) > start or radius is None:
                ok = False
                continue
            tendons.append(Tendon(radius=radius, angle=angle, pitch=pitch, end=end))
    m = len(tendons) if ok else None
    sched, spec = _tension(ck, raw, m, has_tendons=bool(raw.get("tendons")))
    return tuple(tendons) if ok else (), sched, spec


def _tension(ck: _Checker, raw: dict, m: int | None, has_tendons: bool) -> tuple[Schedule | None, dict]:
    T = TENSION
    if "tension" not in raw:
        return None, {}
    pt = ck.table(raw, "tension", "tension")
    if pt is None:
        return None, {}
    if not has_tendons:
        ck.add("tension", "no [tension] without [[tendons]] (tensions pull tendons)", "a [tension] table")
        return None, {}
    kind = ck.field(pt, T["type"], "tension.type")
    if kind is None:
        return None, {}
    ck.keys(pt, "tension", T.keys(kind))
    start = len(ck.problems)
    what = (f"an array of {m} tension{'s' if m != 1 else ''} (N), one a tendon" if m is not None
            else "an array of tensions (N), one a tendon")

    def tensions(key, v, path, what=what):
        arr = ck._numbers(v, path, what, T[key].range if key != "times" else None)
        if arr is not None and m is not None and arr.size != m:
            ck.add(path, what, f"{arr.size} numbers {_show(v)}")
            return None
        return arr

    def vec(key, required=False):
        if key not in pt:
            if required:
                ck.add(f"tension.{key}", what, "nothing (the key is required)")
            return None if required or m is None else np.zeros(m)
        return tensions(key, pt[key], f"tension.{key}")

    def scalar_or_vec(key, default):
        if key not in pt:
            return None if m is None else np.full(m, default)
        if _is_number(pt[key]):
            x = ck.number(pt, key, f"tension.{key}", T[key].range.unit, bounds=T[key].range)
            return None if x is None or m is None else np.full(m, x)
        unit = T[key].range.unit
        return tensions(key, pt[key], f"tension.{key}", f"a number ({unit}) or an array of "
                        f"{'' if m is None else f'{m} '}numbers ({unit}), one a tendon")

    spec = _schedule_spec(ck, pt, T, "tension", kind, vec)  # a constant, step or ramp read there
    if kind == "sine":
        spec["amplitude"] = vec("amplitude", required=True)
        spec["offset"] = vec("offset")
        if "frequency" not in pt:
            ck.add("tension.frequency", "a frequency (Hz), a number or one a tendon", "nothing (the key is required)")
        spec["frequency"] = scalar_or_vec("frequency", 0.0)
        spec["phase"] = scalar_or_vec("phase", 0.0)
        _sine_within(ck, "tension", spec, T["offset"].range, "for every tendon", lambda k: f"for tendon {k}",
                     " (a tendon cannot push)")
    elif kind == "table":
        values = pt.get("values")
        t_arr = _table_times(ck, pt, "tension", T["times"].range)
        rows = None
        if values is None:
            ck.add("tension.values", "an array of tension arrays (N), one a time", "nothing (the key is required)")
        elif not isinstance(values, list):
            ck.add("tension.values", "an array of tension arrays (N), one a time", f"{_type_name(values)} {_show(values)}")
        elif t_arr is not None and len(values) != t_arr.size:
            ck.add("tension.values", f"{t_arr.size} tension arrays, one for each of the {t_arr.size} times",
                   f"{len(values)} arrays")
        else:
            rows = []
            for k, row in enumerate(values):
                arr = tensions("values", row, f"tension.values[{k}]")
                if arr is None:
                    rows = None
                    break
                rows.append(arr)
        spec["times"] = t_arr
        spec["values"] = None if not rows else np.array(rows)
    if len(ck.problems) > start or m is None:
        return None, {}
    cls, keys = {"constant": (Constant, ("value",)), "step": (Step, ("time", "after", "before")),
                 "ramp": (Ramp, ("t0", "t1", "end", "start")),
                 "sine": (Sine, ("amplitude", "frequency", "phase", "offset")),
                 "table": (Table, ("times", "values"))}[kind]
    return cls(*(spec[k] for k in keys)), spec
