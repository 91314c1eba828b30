"""The fit file of ``qchain fit FIT.toml``: which scene, which of its keys, fitted to which
measured experiments, how, and where the results go. Declared once as key tables
(:data:`TABLES`, the scene format's :class:`~qchain.scene.keys.KeyTable` and checker: unknown
keys named with the closest valid one, types, ranges); ``docs/fit.md`` shows them
(:func:`markdown`). :func:`load_fit_spec` reads and checks a file, every problem in one
:class:`~qchain.errors.FitSpecError`, and reads its experiments (a file that cannot be read
or used is a problem of its key too), so that a fit starts only from a file that can run.

Paths in the file (``scene``, each experiment's file, ``output.folder``) are relative to the
file's folder.
"""

from __future__ import annotations

import os
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from ..checks import bounds as B
from ..checks.bounds import Range
from ..checks.paths import has_nul, show_nul
from ..errors import FitSpecError
from ..scene.format import _Checker, _show, _type_name
from ..scene.keys import Field, KeyTable
from .measurements import MeasurementError, read_bag, read_csv, read_qchain
from .solve import COVARIANCES
from .statics import read_static_csv

__all__ = ["FitSpec", "FitSpecError", "load_fit_spec", "TABLES", "SOURCES", "LOSSES", "markdown"]

#: The kinds of experiment: the key that names its file.
SOURCES = ("bag", "recording", "csv", "static_csv")
#: The least-squares losses (:func:`qchain.fit.solve.least_squares_fit`).
LOSSES = ("linear", "soft_l1", "huber", "cauchy", "arctan")
_ANY = Range(None, None)
_TIME = Range(0.0, None, "s")

TOP = KeyTable("", "The top level of a fit file.", (
    Field("scene", "string", "The scene file whose keys are fitted, relative to this file; the fit starts from its "
          "values.", required=True),
    Field("parameters", "tables", "The fitted scene keys (below).", required=True),
    Field("experiments", "tables", "What is fitted to (below).", required=True),
    Field("fit", "table", "How (below)."),
    Field("output", "table", "Where the results go (below)."),
))

PARAMETER = KeyTable("parameters[]", "One table a fitted key: `[[parameters]]`.", (
    Field("key", "string", "A scene key a fit can change: `segments[i].NAME` (one `[[segments]]` table, its `count` "
          "copies sharing the value), `segments[*].NAME` (every segment), NAME one of `youngs_modulus`, `damping`, "
          "`mass`, `length`, `chamber_area`; or `gravity[k]`.", required=True),
    Field("lower", "number", "Lower bound, the key's unit (SI); within the scene format's range.", _ANY,
          default="the scene format's"),
    Field("upper", "number", "Upper bound, above `lower`.", _ANY, default="the scene format's"),
    Field("start", "number", "Start value instead of the scene's, within the bounds.", _ANY,
          default="the scene's value"),
))

EXPERIMENT = KeyTable("experiments[]", "One table an experiment: `[[experiments]]`, with exactly one of `bag`, "
                      "`recording`, `csv`, `static_csv` naming its file (relative to this file); the other keys "
                      "belong to that kind (column `with`).", (
    Field("bag", "string", "A ROS 2 bag (`.mcap`, `.db3` or a bag folder), read with `qchain.fit.read_bag`.",
          when=("bag",)),
    Field("recording", "string", "A qchain recording (`.mcap`), read with `qchain.fit.read_qchain`.",
          when=("recording",)),
    Field("csv", "string", "A CSV file of measured motion (`qchain.fit.read_csv`): a time column, points, "
          "pressures.", when=("csv",)),
    Field("static_csv", "string", "A CSV file of static poses (`qchain.fit.statics.read_static_csv`): one pose a "
          "row, the held pressures and the measured points.", when=("static_csv",)),
    Field("pressure_topic", "string", "The `sensor_msgs/msg/JointState` topic of the chamber pressures (Pa).",
          required=True, when=("bag",)),
    Field("pose_topic", "string", "A `geometry_msgs/msg/PoseStamped` topic of the measured tip (world frame, m).",
          default="none: give `tf`", when=("bag",)),
    Field("tf", "names", "`[parent, child]`: the tip as the transform from `parent` to `child` in `/tf`, instead of "
          "`pose_topic`.", default="none: give `pose_topic`", when=("bag",)),
    Field("field", "choice", "The JointState field holding the pressures.", choices=("effort", "position",
          "velocity"), default='"effort"', when=("bag",)),
    Field("joints", "names", "The pressures' joint names, in the model's chamber order.",
          default="the message's order", when=("bag",)),
    Field("measure", "choice", "What of the recording is fitted to: the last tip's position, or the full "
          "coordinates `q` (weighted by `coordinate_scale`).", choices=("tip", "coordinates"),
          default='"tip"', when=("recording",)),
    Field("time", "string", "The time column (s).", default='"t"', when=("csv",)),
    Field("points", "names", "The measured points' columns: an array of `[x, y, z]` column-name triples, one a "
          "point, in `where`'s order (a `csv` may give `coordinates` instead, or both).", when=("csv", "static_csv"),
          default="required for `static_csv`; a `csv` needs it or `coordinates`"),
    Field("coordinates", "names", "The measured coordinates' columns, one a coordinate of `q` in its order (per "
          "segment `l` m, `ux`, `uy` 1/m).", default="none", when=("csv",)),
    Field("coordinate_scale", "number_or_per_segment", "m per coordinate unit: what a coordinate's residual is "
          "multiplied by to be a length comparable to a point's (0 leaves it out; coordinates the model holds still "
          "are left out anyway).", Range(0.0, 1e3, "m"), default="1 for `l`, `l0^2/2` for `ux`, `uy`",
          when=("recording", "csv")),
    Field("pressures", "names", "The pressure columns (Pa), in the model's chamber order.", required=True,
          when=("csv", "static_csv")),
    Field("scale", "number", "Multiplies the point columns (1e-3 for mm).", Range(0.0, None, low_open=True),
          default="1", when=("csv", "static_csv")),
    Field("where", "names", "Each measured point's `[segment, alpha]` (0-based segment, -1 the last; alpha in "
          "[0, 1] along it).", default="[[-1, 1.0]]: the tip", when=("bag", "csv", "static_csv")),
    Field("start", "number", "Start of the window (s, on the pressures' clock: its first sample at 0).", _TIME,
          default="0", when=("bag", "recording", "csv")),
    Field("stop", "number", "End of the window (s), after `start`.", _TIME, default="the last pressure sample",
          when=("bag", "recording", "csv")),
))

FIT = KeyTable("fit", "How the fit runs (`qchain.fit.fit`).", (
    Field("loss", "choice", "The least-squares loss; the robust ones down-weight residuals beyond `f_scale`.",
          choices=LOSSES, default='"linear"'),
    Field("f_scale", "number", "The residual size where a robust loss starts to down-weight.",
          Range(0.0, None, "m", low_open=True), default="1e-3"),
    Field("max_nfev", "integer", "Residual evaluations at most.", Range(1, 100000, integer=True), default="50"),
    Field("start", "choice", "Where a measured motion starts: at rest under its first pressures, or at the scene's "
          "initial state.", choices=("rest", "scene"), default='"rest"'),
    Field("rtol", "number", "The runs' dopri5 relative tolerance.", B.RTOL, default="1e-7"),
    Field("reduce", "boolean", "The scene's automatic reductions (off: they are decided from the scene's own "
          "pressures, which the experiments' need not share).", default="false"),
    Field("covariance", "choice", "How the standard errors are formed: `inputs` adds the pressure sensor's noise "
          "propagated through the model to white measurement noise; `iid` independent residuals, the pressures "
          "exact; `hac` Newey-West, residuals correlated in time (docs/fit.md, \"Noisy pressures\").",
          choices=COVARIANCES, default='"inputs"'),
    Field("pressure_filter", "number", "Low-pass every measured motion's pressures at this cutoff before fitting "
          "(zero phase); below each motion's Nyquist frequency (half its pressures' sample rate).",
          Range(0.0, None, "Hz", low_open=True), default="none"),
    Field("pressure_sigma", "number_or_per_segment", "The pressure sensor's noise (standard deviation a sample), "
          "one for all chambers or one a chamber; for static poses the only source of their input-noise term.",
          Range(0.0, 1e9, "Pa"), default="estimated from each recording; static poses: none"),
    Field("input_draws", "integer", "Runs (or pose sets) with freshly drawn pressure noise behind `covariance = "
          "\"inputs\"`: the standard errors' own relative error is about `1/sqrt(2 input_draws)` of the part the "
          "inputs add.", Range(2, 100000, integer=True), default="40"),
))

OUTPUT = KeyTable("output", "What `qchain fit` writes: `fitted.toml` (the fitted scene), `fit.json` (values, "
                  "standard errors, correlation, warnings, counters, RMS residual per experiment, time) and "
                  "`fit.png` (measured against start and fitted motion, residuals).", (
    Field("folder", "path", "Where they go, relative to this file (`--out DIR`: relative to the working folder).",
          default='"<file stem>-fit" beside this file'),
    Field("plot", "boolean", "Write `fit.png`.", default="true"),
))

#: The fit file's tables, as ``docs/fit.md`` shows them.
TABLES = (TOP, PARAMETER, EXPERIMENT, FIT, OUTPUT)


@dataclass
class FitSpec:
    """A checked fit file.

    Attributes
    ----------
    path : Path
        The fit file.
    scene : Path
        The scene file fitted.
    keys : list of str
    bounds : dict
        ``{key: (lower or None, upper or None)}`` (SI units).
    values : dict
        ``{key: start}`` for keys started elsewhere than the scene's value.
    experiments : list of Measurements or StaticPoses
        Read (their readers' warnings were issued).
    options : dict
        ``qchain.fit.fit``'s keyword arguments (loss, f_scale, max_nfev, start, rtol, reduce,
        covariance, pressure_filter, pressure_sigma, input_draws).
    folder : Path
        The output folder.
    plot : bool
    """

    path: Path
    scene: Path
    keys: list
    bounds: dict
    values: dict
    experiments: list
    options: dict
    folder: Path
    plot: bool = True
    sources: list = field(default_factory=list)
    read_warnings: list = field(default_factory=list)


def _file(ck: _Checker, d: dict, key: str, path: str, base: Path, what: str) -> Path | None:
    """A file named by a string relative to ``base``, existing."""
    v = ck.string(d, key, path)
    if v is None:
        return None
    if not v.strip() or has_nul(v):
        ck.add(path, f"{what} (a path relative to the fit file)", _show(show_nul(v)))
        return None
    p = Path(os.path.normpath(base / v))  # (shown in messages and outputs as the user would write it)
    if not p.exists():
        ck.add(path, f"{what} (a path relative to the fit file)", f"{_show(v)}: no such file ({p})")
        return None
    return p


def _names(ck: _Checker, d: dict, key: str, path: str, size: int | None = None) -> list | None:
    v = d.get(key)
    if v is None:
        return None
    what = f"an array of {size} strings" if size else "an array of strings"
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v) or (size and len(v) != size) or not v:
        ck.add(path, what, f"{_type_name(v)} {_show(v)}")
        return None
    return v


def _triples(ck: _Checker, d: dict, path: str) -> list | None:
    v = d.get("points")
    if v is None:
        ck.add(path, "an array of [x, y, z] column-name triples", "nothing (the key is required)")
        return None
    if not (isinstance(v, list) and v and all(isinstance(t, list) and len(t) == 3 and all(isinstance(c, str) for c in t)
                                              for t in v)):
        ck.add(path, "an array of [x, y, z] column-name triples, one a point", f"{_type_name(v)} {_show(v)}")
        return None
    return [tuple(t) for t in v]


def _where(ck: _Checker, d: dict, path: str) -> tuple | None:
    v = d.get("where", [[-1, 1.0]])
    ok = isinstance(v, list) and v and all(
        isinstance(w, list) and len(w) == 2 and isinstance(w[0], int) and not isinstance(w[0], bool)
        and isinstance(w[1], (int, float)) and not isinstance(w[1], bool) and 0.0 <= w[1] <= 1.0 for w in v)
    if not ok:
        ck.add(path, "an array of [segment, alpha] pairs: an integer segment (-1 the last) and alpha in [0, 1]",
               f"{_type_name(v)} {_show(v)}")
        return None
    return tuple((int(s), float(a)) for s, a in v)


def _coordinate_scale(ck: _Checker, e: dict, path: str, n: int | None):
    """``coordinate_scale``: a number, or 3 a segment (``n`` segments, flat or nested); None if absent."""
    if "coordinate_scale" not in e:
        return None
    f = EXPERIMENT["coordinate_scale"]
    v = e["coordinate_scale"]
    if isinstance(v, list):
        arr = ck.per_segment(v, path, n, "m", bounds=f.range)
        return None if arr is None else arr.reshape(-1)
    return ck.number(e, "coordinate_scale", path, "m", bounds=f.range)


def _experiment(ck: _Checker, e: dict, path: str, base: Path, n_segments: int | None = None):
    """One ``[[experiments]]`` table checked and read: Measurements, StaticPoses or None."""
    T = EXPERIMENT
    ck.keys(e, path, T.keys())
    given = [k for k in SOURCES if k in e]
    if len(given) != 1:
        ck.add(path, "exactly one of the keys " + ", ".join(SOURCES) + " (the experiment's file)",
               "none of them" if not given else f"{len(given)}: {', '.join(given)}")
        return None
    kind = given[0]
    for k in e:
        if k in T.keys() and k not in T.keys(kind):
            ck.add(f"{path}.{k}", f"keys of a {kind} experiment ({', '.join(T.keys(kind))})",
                   f"{k!r}, a key of {' or '.join(T[k].when)} experiments")
    start = len(ck.problems)
    src = _file(ck, e, kind, f"{path}.{kind}", base, {"bag": "a ROS 2 bag", "recording": "a qchain recording",
                                                       "csv": "a CSV file", "static_csv": "a CSV file"}[kind])
    t0 = ck.field(e, T["start"], f"{path}.start") if kind != "static_csv" else None
    t1 = ck.field(e, T["stop"], f"{path}.stop") if kind != "static_csv" else None
    if t0 is not None and t1 is not None and not t1 > t0:
        ck.add(f"{path}.stop", f"a time after start = {t0:g} s", _show(e["stop"]))
    if kind == "bag":
        topic = ck.string(e, "pressure_topic", f"{path}.pressure_topic")
        if "pressure_topic" not in e:
            ck.add(f"{path}.pressure_topic", "the JointState topic of the pressures", "nothing (the key is required)")
        pose = ck.string(e, "pose_topic", f"{path}.pose_topic")
        tf = _names(ck, e, "tf", f"{path}.tf", 2)
        if ("pose_topic" in e) == ("tf" in e):
            ck.add(path, "one of pose_topic or tf (where the measured tip is)",
                   "both" if "pose_topic" in e else "neither")
        fld = ck.field(e, T["field"], f"{path}.field", "effort")
        joints = _names(ck, e, "joints", f"{path}.joints")
        where = _where(ck, e, f"{path}.where")
        if len(ck.problems) > start:
            return None
        return _read(ck, path + f".{kind}", read_bag, src, pressure_topic=topic, pose_topic=pose,
                     tf=tuple(tf) if tf else None, pressure_field=fld, pressure_names=joints, where=where,
                     start=t0, stop=t1)
    if kind == "recording":
        measure = ck.field(e, T["measure"], f"{path}.measure", "tip")
        cscale = _coordinate_scale(ck, e, f"{path}.coordinate_scale", n_segments)
        if cscale is not None and measure != "coordinates":
            ck.add(f"{path}.coordinate_scale", 'a key of measure = "coordinates"', f"measure = {_show(measure)}")
        if len(ck.problems) > start:
            return None
        return _read(ck, path + f".{kind}", read_qchain, src, measure=measure, start=t0, stop=t1,
                     coordinate_scale=cscale)
    coords = _names(ck, e, "coordinates", f"{path}.coordinates") if kind == "csv" else None
    cscale = _coordinate_scale(ck, e, f"{path}.coordinate_scale", n_segments) if kind == "csv" else None
    if cscale is not None and coords is None:
        ck.add(f"{path}.coordinate_scale", "a key of an experiment with coordinates", "no coordinates")
    if kind == "csv" and "points" not in e and coords is not None:
        pts = None
        if "where" in e:
            ck.add(f"{path}.where", "a key of measured points", "no points (coordinates only)")
    else:
        pts = _triples(ck, e, f"{path}.points")
    pres = _names(ck, e, "pressures", f"{path}.pressures")
    if "pressures" not in e:
        ck.add(f"{path}.pressures", "an array of strings (the pressure columns)", "nothing (the key is required)")
    scale = ck.field(e, T["scale"], f"{path}.scale", 1.0)
    where = _where(ck, e, f"{path}.where")
    if where is not None and pts is not None and len(where) != len(pts):
        ck.add(f"{path}.where", f"{len(pts)} [segment, alpha] pairs, one a point of points", _show(e.get("where")))
    if len(ck.problems) > start:
        return None
    if kind == "csv":
        time = ck.string(e, "time", f"{path}.time", "t")
        return _read(ck, path + ".csv", read_csv, src, time=time, points=pts, where=where, pressures=pres,
                     scale=scale, start=t0, stop=t1, coordinates=coords, coordinate_scale=cscale)
    return _read(ck, path + ".static_csv", read_static_csv, src, points=pts, pressures=pres, where=where,
                 scale=scale)


def _read(ck: _Checker, path: str, reader, src: Path, **kw):
    """``reader(src, **kw)``; what it refuses is a problem of ``path``."""
    try:
        return reader(src, **kw)
    except MeasurementError as err:
        ck.add(path, "measurements the fit can use", str(err))
    except Exception as err:  # noqa: BLE001 - a foreign file's reader may raise anything: said as its problem
        ck.add(path, "a file its reader can read", f"{type(err).__name__}: {err}")
    return None


def load_fit_spec(path, out=None) -> FitSpec:
    """Read and check the fit file ``path`` and read its experiments; one :class:`FitSpecError`
    lists every problem. ``out`` (a folder) replaces ``[output] folder``."""
    from ..scene.reading import load_scene, read_toml
    from ..errors import SceneError
    from .parameters import fit_parameters

    path = Path(path)
    _, raw = read_toml(path, "fit file", FitSpecError)
    base = path.parent
    ck = _Checker()
    ck.keys(raw, "", TOP.keys())
    scene = _file(ck, raw, "scene", "scene", base, "the scene file")
    if "scene" not in raw:
        ck.add("scene", "the scene file (a path relative to the fit file)", "nothing (the key is required)")
    scene_raw = None
    if scene is not None:
        try:
            load_scene(scene)
            scene_raw = tomllib.loads(scene.read_text())
        except SceneError as err:
            for p in err.problems:
                ck.add(f"scene ({_show(str(scene), 120)}): {p.key}", p.expected, p.found)

    keys, bounds, values = [], {}, {}
    tabs = _table_array(ck, raw, "parameters")
    for i, t in enumerate(tabs):
        where = f"parameters[{i}]"
        ck.keys(t, where, PARAMETER.keys())
        key = ck.field(t, PARAMETER["key"], f"{where}.key")
        if "key" not in t:
            ck.add(f"{where}.key", "a scene key (segments[i].NAME, segments[*].NAME, gravity[k])",
                   "nothing (the key is required)")
        lo = ck.field(t, PARAMETER["lower"], f"{where}.lower")
        hi = ck.field(t, PARAMETER["upper"], f"{where}.upper")
        x0 = ck.field(t, PARAMETER["start"], f"{where}.start")
        if lo is not None and hi is not None and not lo < hi:
            ck.add(f"{where}.upper", f"a number above lower = {lo:g}", _show(t["upper"]))
            continue
        if key is None:
            continue
        if key in keys:
            ck.add(f"{where}.key", "a key not fitted twice", f"{key!r}, given in parameters[{keys.index(key)}] too")
            continue
        if scene_raw is not None:
            try:  # the key is one the scene has, the bounds within the format's, the start within them
                probe = dict(scene_raw)
                if x0 is not None:
                    from ..batch.sweep_spec import apply_values

                    probe = apply_values(scene_raw, {key: x0})
                fit_parameters(probe, [key], {key: (lo, hi)})
            except (ValueError, KeyError, IndexError, TypeError) as err:
                ck.add(where, "a key of the scene a fit can change, with its start within its bounds", str(err))
                continue
        keys.append(key)
        if lo is not None or hi is not None:
            bounds[key] = (lo, hi)
        if x0 is not None:
            values[key] = x0

    exps = []
    etabs = _table_array(ck, raw, "experiments")
    n_segments = None
    if scene_raw is not None:
        from .parameters import _tables

        n_segments = sum(c for _, c in _tables(scene_raw))
    for i, e in enumerate(etabs):
        exps.append(_experiment(ck, e, f"experiments[{i}]", base, n_segments))

    ft = ck.section(raw, "fit", FIT.keys())
    options = dict(loss=ck.field(ft, FIT["loss"], "fit.loss", "linear"),
                   f_scale=ck.field(ft, FIT["f_scale"], "fit.f_scale", 1e-3),
                   max_nfev=ck.field(ft, FIT["max_nfev"], "fit.max_nfev", 50),
                   start=ck.field(ft, FIT["start"], "fit.start", "rest"),
                   rtol=ck.field(ft, FIT["rtol"], "fit.rtol", 1e-7),
                   reduce=ck.field(ft, FIT["reduce"], "fit.reduce", False),
                   covariance=ck.field(ft, FIT["covariance"], "fit.covariance", "inputs"),
                   pressure_filter=ck.field(ft, FIT["pressure_filter"], "fit.pressure_filter"),
                   pressure_sigma=_pressure_sigma(ck, ft, n_segments),
                   input_draws=ck.field(ft, FIT["input_draws"], "fit.input_draws", 40))
    cut = options["pressure_filter"]
    if cut is not None:  # below every measured motion's Nyquist frequency, said here rather than mid-fit
        import numpy as np

        from .measurements import Measurements

        for i, e in enumerate(exps):
            if isinstance(e, Measurements):
                nyq = 0.5 / float(np.median(np.diff(e.pressures.times)))
                if not cut < nyq:
                    ck.add("fit.pressure_filter", f"a cutoff below {nyq:.6g} Hz (experiments[{i}]'s pressures' "
                           "Nyquist frequency, half their sample rate)", _show(ft["pressure_filter"]))
                    break
    ot = ck.section(raw, "output", OUTPUT.keys())
    folder = ck.path(ot, "folder", "output.folder", None)
    plot = ck.field(ot, OUTPUT["plot"], "output.plot", True)
    if ck.problems:
        raise FitSpecError(str(path), ck.problems)
    folder = Path(out) if out is not None else Path(os.path.normpath(
        base / folder if folder is not None else base / f"{path.stem}-fit"))
    return FitSpec(path=path, scene=scene, keys=keys, bounds=bounds, values=values, experiments=exps,
                   options=options, folder=folder, plot=plot, sources=[str(e.source) for e in exps])


def _pressure_sigma(ck: _Checker, ft: dict, n: int | None):
    """``[fit] pressure_sigma``: a number, or one a chamber (3 a segment, flat or nested)."""
    if "pressure_sigma" not in ft:
        return None
    f = FIT["pressure_sigma"]
    v = ft["pressure_sigma"]
    if isinstance(v, list):
        arr = ck.per_segment(v, "fit.pressure_sigma", n, "Pa", bounds=f.range)
        return None if arr is None else arr.reshape(-1)
    return ck.number(ft, "pressure_sigma", "fit.pressure_sigma", "Pa", bounds=f.range)


def _table_array(ck, raw: dict, name: str) -> list:
    """``raw[name]`` when it is a non-empty array of tables (``[[name]]``); else the problem
    said on ``ck`` and an empty list."""
    tabs = raw.get(name)
    if not isinstance(tabs, list) or not tabs or not all(isinstance(t, dict) for t in tabs):
        ck.add(name, f"an array of tables ([[{name}]]), at least one",
               "nothing (the key is required)" if tabs is None else f"{_type_name(tabs)} {_show(tabs)}")
        return []
    return tabs


def markdown() -> list[str]:
    """The fit file's tables as Markdown (``docs/fit.md``)."""
    out = []
    for t in TABLES:
        out += [line.replace("## ", "### ", 1) if line.startswith("## ") else line
                for line in t.markdown("Top level of a fit file")]
    return out

