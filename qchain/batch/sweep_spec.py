"""What a sweep runs: a base scene, values set for every run, axes, and how they are sampled.

A sweep is a base scene file plus *axes* over any of its values, named by dotted keys
(``segments[0].chamber_radius``, ``pressure.amplitude``, ``simulation.rtol``, with
``segments[*]`` for every ``[[segments]]`` table), sampled as a full grid, as N random
samples or as N Latin-hypercube samples with a seed. Each run is the base scene with its
values put in and validated as a scene file is (:func:`qchain.scene.parse_scene`), before
anything runs. :mod:`qchain.batch.sweeps` runs them.

Sweep file format
-----------------
TOML; every key is optional unless marked *required*::

    scene = "spatial_arm.toml"          # required: the base scene, relative to this file
    name = "reach"                      # default: the file's stem
    folder = "out/sweeps/reach"         # results (default out/sweeps/<name>), relative to the working dir
    metrics = "mypackage.study:reach"   # optional: more per-run metrics, a function (scene, model, traj) -> dict

    [sampling]
    kind = "grid"                       # "grid" (default): every combination of the axes' values;
                                        # "random" or "lhs" (Latin hypercube): n samples of the ranges
    n = 64                              # random, lhs: number of runs (required there)
    seed = 1                            # random, lhs: seed of the samples (default 0)
    max_runs = 100000                   # the most runs the sweep may have (default 100000): a grid or n
                                        # beyond it is refused before any run is made; raise it to allow more

    [set]                               # values put in every run's scene, before the axes'
    "simulation.duration" = 1.0
    "pressure.offset" = { each_segment = [25e3, 25e3, 25e3] }   # these 3 repeated for each segment

    [[axes]]                            # one table an axis
    key = "segments[0].chamber_radius"  # required (or keys): a dotted scene key
    values = [0.006, 0.007, 0.008]      # the values; or a range:
    # range = [0.005, 0.009]            #   grid: num values evenly spaced, geometrically with log = true;
    # num = 5                           #   random, lhs: drawn uniformly (log-uniformly) in the range
    # log = false
    # integer = false                   #   whole numbers (a segment count), the range's ends included

    [[axes]]
    keys = ["segments[0].count", "pressure.amplitude"]   # linked keys move together:
    values = [[2, { each_segment = [2e4, 0, 0] }], [3, { each_segment = [2e4, 0, 0] }]]

    [output]
    trajectories = false                # save each run's trajectory (runs/run-NNNNN.npz)
    mcap = false                        # record each run (runs/run-NNNNN.mcap)

    [engine]
    workers = 2                         # local worker processes (default: every core; at most 1024)
    dask = "tcp://127.0.0.1:8786"       # or a Dask scheduler's address instead
    retries = 3                         # times a run whose worker died is run again

``{ each_segment = [...] }`` stands for that list repeated once a segment of the run (after
its own segment count is set), so per-chamber vectors follow a swept segment count. An
axis sampled at random or by Latin hypercube takes its ``range`` continuously, or picks
among its ``values`` with equal chances. Grid runs are ordered as nested loops, the first
axis outermost.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..checks.addresses import host_ok
from ..checks import bounds as _B
from ..checks.convert import describe_value
from ..checks.paths import has_nul, show_nul
from ..errors import SweepError
from ..scene.scene import _TOP_KEYS, Problem, Scene, SceneError, _Checker, _show, _type_name
from ..scene.reading import load_scene, parse_scene, read_toml

__all__ = ["Axis", "SweepSpec", "SweepError", "load_sweep", "parse_key", "apply_values", "SAMPLINGS",
           "check_results_folder", "address_problem", "DEFAULT_MAX_RUNS"]

SAMPLINGS = ("grid", "random", "lhs")
#: Runs a sweep may have unless its file raises ``[sampling] max_runs`` (each run's scene is made
#: and checked before anything runs: a mistyped ``num = 1000000000`` is refused, not built).
DEFAULT_MAX_RUNS = 100_000
#: The largest ``max_runs`` a sweep may set (the runs' scene texts are held in memory).
MAX_RUNS_LIMIT = 10**8
_FILE_KEYS = ("scene", "name", "folder", "metrics", "sampling", "set", "axes", "output", "engine")
_AXIS_KEYS = ("key", "keys", "values", "range", "num", "log", "integer")
_KEY = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)((?:\[(?:[0-9]+|\*)\])*)")
_EACH = "each_segment"


# ------------------------------------------------------------------------------ keys


def parse_key(key: str) -> list:
    """``"segments[0].chamber_radius"`` -> ``["segments", 0, "chamber_radius"]`` (``"*"``
    for ``[*]``). Raises ValueError for a key of another form."""
    if not isinstance(key, str) or not key:
        raise ValueError(f"a scene key must be a dotted name like 'segments[0].radius', got {key!r}")
    out: list = []
    for part in key.split("."):
        m = _KEY.fullmatch(part)
        if m is None:
            raise ValueError(f"a scene key must be dotted names with [index] or [*], like 'segments[0].radius'; "
                             f"{key!r} has {part!r}")
        out.append(m.group(1))
        out += ["*" if idx == "*" else int(idx) for idx in re.findall(r"\[([0-9]+|\*)\]", m.group(2))]
    if out[0] not in _TOP_KEYS:
        raise ValueError(f"{key!r} does not start with a scene key ({', '.join(_TOP_KEYS)})")
    return out


def keys_overlap(a: str, b: str) -> bool:
    """Whether two scene keys can address the same value (``[*]`` matches every index; a
    table's key overlaps the keys inside it)."""
    for x, y in zip(parse_key(a), parse_key(b)):
        if x == y or (x == "*" and isinstance(y, int)) or (y == "*" and isinstance(x, int)):
            continue
        return False
    return True


def _put(node, at, value) -> None:
    """``node[at] = value``, except that a table put over a table is merged into it key by
    key (a dotted assignment per leaf): ``simulation = {duration = 0.03}`` changes the
    duration and keeps the scene's method and dt."""
    here = node.get(at) if isinstance(node, dict) else node[at]
    if isinstance(value, dict) and isinstance(here, dict) and value and set(value) != {_EACH} \
            and set(here) != {_EACH}:
        for k, v in value.items():
            _put(here, k, v)
        return
    node[at] = copy.deepcopy(value)


def _set(node, tokens: list, value, key: str) -> None:
    head, rest = tokens[0], tokens[1:]
    if isinstance(head, str) and head != "*":
        if not isinstance(node, dict):
            raise ValueError(f"{key}: {head!r} is a key of a table, found {_type_name(node)}")
        if not rest:
            _put(node, head, value)
            return
        if head not in node:
            node[head] = {} if isinstance(rest[0], str) else []
        _set(node[head], rest, value, key)
        return
    if not isinstance(node, list):
        raise ValueError(f"{key}: [{head}] indexes an array, found {_type_name(node)}")
    targets = range(len(node)) if head == "*" else [head]
    for i in targets:
        if i >= len(node):
            raise ValueError(f"{key}: index {i} is past the end of an array of {len(node)}")
        if not rest:
            _put(node, i, value)
        else:
            _set(node[i], rest, value, key)


def _segment_count(raw: dict) -> int:
    segs = raw.get("segments")
    if not isinstance(segs, list):
        return 0
    return sum(int(s.get("count", 1)) if isinstance(s, dict) and isinstance(s.get("count", 1), int) else 1
               for s in segs)


def _expand(value, n: int):
    """``{each_segment = [...]}`` -> the list repeated ``n`` times (recursively)."""
    if isinstance(value, dict):
        if set(value) == {_EACH}:
            inner = value[_EACH]
            return list(inner) * n if isinstance(inner, list) else [inner] * n
        return {k: _expand(v, n) for k, v in value.items()}
    if isinstance(value, list):
        return [_expand(v, n) for v in value]
    return value


def _segment_limit(raw: dict) -> int:
    """The most segments the scene ``raw`` may have: its ``budget.max_segments`` if that is
    valid, else the default budget's."""
    from ..sim.budget import DEFAULT, RANGES

    b = raw.get("budget")
    m = b.get("max_segments") if isinstance(b, dict) else None
    rng = RANGES["max_segments"]
    if isinstance(m, int) and not isinstance(m, bool) and rng.contains(m):
        return m
    return DEFAULT.max_segments


def apply_values(raw: dict, values: dict) -> dict:
    """A copy of the scene table ``raw`` with ``values`` ({dotted key: value}) put in, in
    order, and ``{each_segment = [...]}`` expanded for the result's segment count (left as is
    for a count over the scene's ``budget.max_segments``, which the scene's check then refuses
    by name, instead of a list of that many entries)."""
    out = copy.deepcopy(raw)
    for key, value in values.items():
        _set(out, parse_key(key), value, key)
    n = _segment_count(out)
    return _expand(out, n) if n <= _segment_limit(out) else out


# ------------------------------------------------------------------------------ axes


def _plain(x):
    """numpy scalars and arrays as Python numbers and lists (TOML and JSON take these)."""
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, dict):
        return {k: _plain(v) for k, v in x.items()}
    return x


@dataclass(frozen=True)
class Axis:
    """One axis of a sweep.

    Parameters
    ----------
    key : str or tuple of str
        Dotted scene key(s); several keys are linked: each value is then a sequence with
        one entry a key.
    values : sequence, optional
        The values (grid: each in turn; random and lhs: picked with equal chances).
    range : (low, high), optional
        Instead of ``values``: grid takes ``num`` values from ``low`` to ``high``; random and
        lhs draw within it.
    num : int
        Grid values in a range (>= 1).
    log : bool
        Geometric spacing (grid) or log-uniform draws (``low > 0``).
    integer : bool
        Whole numbers only (rounded; the range's ends included).
    """

    key: str | tuple
    values: tuple | None = None
    range: tuple | None = None
    num: int | None = None
    log: bool = False
    integer: bool = False

    def __post_init__(self):
        keys = (self.key,) if isinstance(self.key, str) else tuple(self.key)
        if not keys:
            raise ValueError("an axis needs at least one key")
        for k in keys:
            parse_key(k)
        object.__setattr__(self, "key", keys[0] if len(keys) == 1 else keys)
        if (self.values is None) == (self.range is None):
            raise ValueError(f"axis {self.name}: give values or range, not {'both' if self.values is not None else 'neither'}")
        if self.values is not None:
            vals = tuple(_plain(v) for v in self.values)
            if not vals:
                raise ValueError(f"axis {self.name}: values is empty")
            if len(keys) > 1:
                for v in vals:
                    if not isinstance(v, (list, tuple)) or len(v) != len(keys):
                        raise ValueError(f"axis {self.name}: each value must list {len(keys)} entries, one a key; "
                                         f"got {_show(_plain(v))}")
            object.__setattr__(self, "values", vals)
        else:
            if len(keys) > 1:
                raise ValueError(f"axis {self.name}: linked keys take values, not a range")
            r = tuple(float(x) for x in self.range)
            if len(r) != 2 or not all(math.isfinite(x) for x in r) or not r[1] >= r[0]:
                raise ValueError(f"axis {self.name}: range must be [low, high] with finite low <= high, got {self.range!r}")
            if self.log and r[0] <= 0:
                raise ValueError(f"axis {self.name}: a log range needs low > 0, got {r[0]:g}")
            object.__setattr__(self, "range", r)
            if self.integer and math.ceil(r[0]) > math.floor(r[1]):
                raise ValueError(f"axis {self.name}: an integer range needs a whole number in it, got "
                                 f"[{r[0]:g}, {r[1]:g}]")
            if self.num is not None and not (isinstance(self.num, int) and not isinstance(self.num, bool)
                                             and self.num >= 1):
                raise ValueError(f"axis {self.name}: num must be an int >= 1, got {self.num!r}")

    @property
    def keys(self) -> tuple[str, ...]:
        return (self.key,) if isinstance(self.key, str) else tuple(self.key)

    def size(self) -> int | None:
        """How many values the axis takes on a grid (at most, for an integer range), known
        without making them; None for a range without ``num``."""
        return len(self.values) if self.values is not None else self.num

    @property
    def name(self) -> str:
        return " + ".join(self.keys)

    def _num(self, x: float):
        if not self.integer:
            return float(x)
        lo, hi = self.range  # the nearest whole number inside the range (round(1.2) is not in [1.2, 1.8])
        return int(min(max(round(x), math.ceil(lo)), math.floor(hi)))

    def grid(self) -> list:
        """The axis's values on a grid."""
        if self.values is not None:
            return list(self.values)
        if self.num is None:
            raise ValueError(f"axis {self.name}: a range on a grid needs num (how many values)")
        lo, hi = self.range
        xs = np.geomspace(lo, hi, self.num) if self.log else np.linspace(lo, hi, self.num)
        out = [self._num(x) for x in xs]
        return list(dict.fromkeys(out)) if self.integer else out

    def pick(self, u: float):
        """The value at ``u`` in [0, 1): uniform (log-uniform) in the range, or one of the values."""
        if self.values is not None:
            return self.values[min(int(u * len(self.values)), len(self.values) - 1)]
        lo, hi = self.range
        if self.integer:
            a, b = math.ceil(lo), math.floor(hi)  # a <= b: checked when the axis was made
            return int(min(a + math.floor(u * (b - a + 1)), b))
        if self.log:
            return float(math.exp(math.log(lo) + u * (math.log(hi) - math.log(lo))))
        return float(lo + u * (hi - lo))

    def assign(self, value) -> dict:
        """``{key: value}`` for this axis's value (one entry a linked key)."""
        if len(self.keys) == 1:
            return {self.keys[0]: value}
        return dict(zip(self.keys, value))

    def to_json(self) -> dict:
        return {"key": list(self.keys) if len(self.keys) > 1 else self.key, "values": _plain(list(self.values))
                if self.values is not None else None, "range": list(self.range) if self.range else None,
                "num": self.num, "log": self.log, "integer": self.integer}


def _as_axes(axes) -> list[Axis]:
    if isinstance(axes, dict):
        for k, a in axes.items():
            if not isinstance(a, Axis) and (isinstance(a, (str, bytes, dict)) or not hasattr(a, "__iter__")):
                raise TypeError(f"axes[{k!r}] must be a list of values (or an Axis), got {describe_value(a)}")
        return [a if isinstance(a, Axis) else Axis(k, values=tuple(a)) for k, a in axes.items()]
    out = []
    for a in axes or []:
        if not isinstance(a, Axis):
            raise TypeError(f"axes must be Axis objects or a dict {{key: values}}, got {type(a).__name__}")
        out.append(a)
    return out


# ------------------------------------------------------------------------------ the sweep


@dataclass
class SweepSpec:
    """A sweep: base scene, values for every run, axes, sampling, outputs.

    Attributes
    ----------
    scene : Scene
        The base scene.
    axes : list of Axis
    sampling : str
        One of :data:`SAMPLINGS`.
    n : int or None
        Runs of random and lhs sampling.
    seed : int
    set : dict
        {dotted key: value} put in every run before the axes' values.
    name : str
    folder : Path or None
        Results folder (None: results in memory only, nothing to resume).
    trajectories, mcap : bool
        Save each run's trajectory (npz) / MCAP recording.
    metrics : callable or None
        ``(scene, model, traj) -> dict`` of more per-run metrics (module level, so workers
        can import it).
    workers : int or None
    dask : str or None
    retries : int
    path : Path or None
        The sweep file.
    """

    scene: Scene
    axes: list[Axis]
    sampling: str = "grid"
    n: int | None = None
    seed: int = 0
    set: dict = field(default_factory=dict)
    name: str = "sweep"
    folder: Path | None = None
    trajectories: bool = False
    mcap: bool = False
    metrics: object = None
    workers: int | None = None
    dask: str | None = None
    retries: int = 3
    path: Path | None = None
    max_runs: int = DEFAULT_MAX_RUNS

    def __post_init__(self):
        if self.sampling not in SAMPLINGS:
            raise ValueError(f"sampling must be one of {SAMPLINGS}, got {self.sampling!r}")
        self.axes = _as_axes(self.axes)
        self.set = {k: _plain(v) for k, v in (self.set or {}).items()}
        for k in self.set:
            parse_key(k)
        seen: dict[str, str] = {}
        for a in self.axes:
            for k in a.keys:
                if k in seen:
                    raise ValueError(f"the key {k!r} is on two axes ({seen[k]} and {a.name})")
                for other, axis in seen.items():  # another spelling of it: segments[*] and segments[0]
                    if axis != a.name and keys_overlap(k, other):
                        raise ValueError(f"the keys {other!r} and {k!r} address the same value, on two axes "
                                         f"({axis} and {a.name}): which run used which would be unknown")
                seen[k] = a.name
        if not (isinstance(self.max_runs, int) and not isinstance(self.max_runs, bool)
                and 1 <= self.max_runs <= MAX_RUNS_LIMIT):
            raise ValueError(f"max_runs must be an int >= 1 and <= {MAX_RUNS_LIMIT}, got {self.max_runs!r}")
        if self.sampling == "grid":
            if self.n is not None:
                raise ValueError("n is for random and lhs sampling; a grid runs every combination")
            too_many = runs_problem("grid", None, self.axes, self.max_runs)
            if too_many is not None:  # before a.grid() makes the values
                raise ValueError(f"{too_many[0]}: expected {too_many[1]}, found {too_many[2]}")
            for a in self.axes:
                a.grid()  # a range without num raises here
        elif not (isinstance(self.n, int) and not isinstance(self.n, bool) and self.n >= 1):
            raise ValueError(f"{self.sampling} sampling needs n, the number of runs (an int >= 1), got {self.n!r}")
        elif self.n > self.max_runs:
            key, expected, found = runs_problem(self.sampling, self.n, self.axes, self.max_runs)
            raise ValueError(f"{key}: expected {expected}, found {found}")
        if not (isinstance(self.seed, int) and not isinstance(self.seed, bool) and 0 <= self.seed < 2**128):
            raise ValueError(f"seed must be an int >= 0 and < 2**128 (numpy's generators take no other), got "
                             f"{self.seed!r}")
        from .workers import check_engine

        self.retries = check_engine(None, None, self.retries)
        if self.folder is not None:
            self.folder = Path(self.folder)

    def points(self) -> list[dict]:
        """Each run's axis values, ``{key: value}``, in run order."""
        if not self.axes:
            return [{}]
        if self.sampling == "grid":
            return [{k: x for a, v in zip(self.axes, combo) for k, x in a.assign(v).items()}
                    for combo in itertools.product(*(a.grid() for a in self.axes))]
        d = len(self.axes)
        if self.sampling == "random":
            U = np.random.default_rng(self.seed).random((self.n, d))
        else:
            from scipy.stats import qmc

            kw = {"rng": np.random.default_rng(self.seed)} if _takes_rng(qmc.LatinHypercube) else {"seed": self.seed}
            U = qmc.LatinHypercube(d=d, **kw).random(self.n)
        return [{k: v for a, u in zip(self.axes, row) for k, v in a.assign(a.pick(float(u))).items()} for row in U]

    def run_texts(self) -> list[tuple[dict, str]]:
        """``(axis values, scene TOML text)`` of every run."""
        import tomli_w

        raw = tomllib.loads(self.scene.text)
        return [(point, tomli_w.dumps(apply_values(raw, {**self.set, **point}))) for point in self.points()]

    def fingerprint(self, runs: list[tuple[dict, str]]) -> str:
        """A hash of what the runs compute (their scene texts) and what they write."""
        h = hashlib.sha256()
        h.update(json.dumps({"trajectories": self.trajectories, "mcap": self.mcap,
                             "metrics": _metrics_name(self.metrics)}, sort_keys=True).encode())
        for _, text in runs:
            h.update(hashlib.sha256(text.encode()).digest())
        return h.hexdigest()

    def describe(self) -> list[str]:
        lines = [f"sweep {self.name}: base scene {self.scene.path or '<text>'}, {self.sampling} sampling"
                 + (f", n = {self.n}, seed = {self.seed}" if self.sampling != "grid" else "")]
        lines += [f"  set {k} = {_show(v)}" for k, v in self.set.items()]
        for a in self.axes:
            what = (f"{len(a.values)} values {_show(list(a.values))}" if a.values is not None else
                    f"range [{a.range[0]:g}, {a.range[1]:g}]{' log' if a.log else ''}{' integer' if a.integer else ''}"
                    + (f", {a.num} values" if self.sampling == "grid" else ""))
            lines.append(f"  axis {a.name}: {what}")
        from ..checks.text import printable

        return [printable(line) for line in lines]


def runs_problem(sampling: str, n: int | None, axes: list[Axis], max_runs: int) -> tuple[str, str, str] | None:
    """``(key, expected, found)`` if the sweep would have more than ``max_runs`` runs (counted
    without making them), else None."""
    how = f"at most [sampling] max_runs = {max_runs} runs (raise it to allow more)"
    if sampling != "grid":
        return ("sampling.n", how, f"n = {n}") if n is not None and n > max_runs else None
    total, sizes = 1, []
    for a in axes:
        k = a.size()
        if k is None:
            return None  # a range without num: said elsewhere
        sizes.append(f"{k} ({a.name})")
        total *= k
    if total <= max_runs:
        return None
    shown = f"{total:.4g}" if total < 10**300 else "more than 1e300"  # (a float of it would overflow)
    return "axes", how, f"a grid of {shown} runs: {' x '.join(sizes)} values"


def _takes_rng(cls) -> bool:
    import inspect

    return "rng" in inspect.signature(cls.__init__).parameters


def address_problem(address: str) -> str | None:
    """What is wrong with a Dask scheduler's address (``[SCHEME://]HOST:PORT``: a known
    scheme, a host that is an IP address or a DNS name, a port from 1 to 65535), or None.
    ``qchain sweep --dask`` can check its value with it too."""
    from urllib.parse import urlsplit

    from .workers import SCHEDULER_SCHEMES

    text = str(address)
    if not text.strip() or any(c.isspace() or not c.isprintable() for c in text):
        return "not an address (empty, or with spaces or control characters)"
    if "://" not in text:
        text = "tcp://" + text
    try:
        parts = urlsplit(text)
        port = parts.port
    except ValueError as err:
        return f"a bad port ({err})"
    if parts.scheme not in SCHEDULER_SCHEMES:
        return f"the scheme {parts.scheme!r} is not one of {', '.join(SCHEDULER_SCHEMES)}"
    if parts.scheme == "inproc":
        return None
    if not parts.hostname or not host_ok(parts.hostname):
        return "no host (an IP address or a DNS name)"
    if port is not None and not 1 <= port <= 65535:
        return f"the port {port} is not from 1 to 65535"
    return None


def check_results_folder(folder, n_runs: int | None = None) -> None:
    """Refuse, before any run, a results folder a sweep cannot resume from (``sweep.json``,
    ``runs.jsonl`` with run numbers below ``n_runs``, ``summary.parquet``, ``runs/``; a missing
    file is fine): one :class:`SweepError` listing every problem."""
    import os
    import stat

    root = Path(folder)
    problems: list[Problem] = []

    def kind(p: Path) -> str | None:
        """None if ``p`` is missing, else what it is."""
        try:
            mode = os.stat(p).st_mode
        except FileNotFoundError:
            return None
        except OSError as err:
            return f"a path that cannot be read ({err.strerror or err})"
        return "a file" if stat.S_ISREG(mode) else "a folder" if stat.S_ISDIR(mode) else "not a regular file"

    def add(name, expected, found):
        problems.append(Problem(str(root / name), expected, found))

    def read(name: str, limit: int | None) -> bytes | None:
        k = kind(root / name)
        if k is None:
            return None
        if k != "a file":
            add(name, "a regular file", k)
            return None
        size = os.stat(root / name).st_size
        if limit is not None and size > limit:
            add(name, f"a file of at most {limit} bytes", f"{size} bytes")
            return None
        return (root / name).read_bytes()

    data = read("sweep.json", 64 * 2**20)
    if data is not None:
        try:
            manifest = json.loads(data)
        except (ValueError, UnicodeDecodeError) as err:
            add("sweep.json", "the JSON description of a sweep (written by qchain sweep)", f"not JSON ({err})")
        else:
            if not isinstance(manifest, dict) or not isinstance(manifest.get("fingerprint"), str):
                add("sweep.json", "a JSON object with the sweep's fingerprint (written by qchain sweep)",
                    f"{_type_name(manifest)} {_show(manifest)}")
    data = read("runs.jsonl", None)
    if data is not None:
        lines = data[: data.rfind(b"\n") + 1].splitlines()  # a last line cut by a kill is dropped on resuming
        for number, line in enumerate(lines, 1):
            try:
                row = json.loads(line)
            except (ValueError, UnicodeDecodeError) as err:
                add(f"runs.jsonl, line {number}", "one JSON object a finished run", f"not JSON ({err})")
                break
            run = row.get("run") if isinstance(row, dict) else None
            if not (isinstance(run, int) and not isinstance(run, bool) and run >= 0
                    and (n_runs is None or run < n_runs)):
                what = f"a whole run number{f' below {n_runs}' if n_runs is not None else ''}"
                add(f"runs.jsonl, line {number}", f"a JSON object with 'run', {what}", _show(row))
                break
    for name, want in (("summary.parquet", "a file"), ("runs", "a folder")):
        k = kind(root / name)
        if k is not None and k != want:
            add(name, "a regular file" if want == "a file" else "a folder", k)
    if problems:
        raise SweepError(str(root), problems)


def _metrics_problem(name: str) -> str | None:
    """Why ``"module:function"`` names no function that can be imported, or None."""
    import importlib

    module, _, attr = name.partition(":")
    try:
        obj = importlib.import_module(module)
    except Exception as err:  # noqa: BLE001 - any error of the user's module is its problem, said by name
        return f"module {module!r} cannot be imported ({type(err).__name__}: {err})"
    for part in attr.split("."):
        if not hasattr(obj, part):
            return f"module {module!r} has no {attr!r}"
        obj = getattr(obj, part)
    return None if callable(obj) else f"{attr!r} is not a function"


def _metrics_name(fn) -> str | None:
    if fn is None or isinstance(fn, str):
        return fn
    return f"{getattr(fn, '__module__', '?')}:{getattr(fn, '__qualname__', repr(fn))}"


def validate_runs(spec: SweepSpec, runs: list[tuple[dict, str]]) -> list[Scene]:
    """Every run's scene, parsed and checked; one :class:`SweepError` for the first run that
    is not a valid scene (and how many are not)."""
    scenes = []
    bad: list[tuple[int, dict, SceneError]] = []
    from ..recording.records import T_MAX, T_MAX_WHY

    for i, (point, text) in enumerate(runs):
        try:
            sc = parse_scene(text, path=spec.scene.path)
        except SceneError as err:
            bad.append((i, point, err))
            continue
        if spec.mcap and sc.duration > T_MAX:  # its recording would fail at 2**32 s (as qchain run refuses)
            bad.append((i, point, SceneError(str(spec.scene.path), [Problem(
                "simulation.duration", f"at most {T_MAX:.10g} s for a recorded run ({T_MAX_WHY}; or no --mcap)",
                f"{sc.duration:g}")])))
            continue
        scenes.append(sc)
    if bad:
        i, point, err = bad[0]
        where = ", ".join(f"{k} = {_show(v)}" for k, v in point.items()) or "the values in [set]"
        more = f" ({len(bad)} of {len(runs)} runs are invalid; this is the first)" if len(bad) > 1 else ""
        raise SweepError(f"{spec.path or spec.name}: run {i} ({where}){more}", err.problems)
    return scenes


# ------------------------------------------------------------------------------ the file


def load_sweep(path) -> SweepSpec:
    """Read and validate a sweep file; one :class:`SweepError` lists every problem."""
    path = Path(path)
    _, raw = read_toml(path, "sweep file", SweepError)  # a regular file, bounded in size and nesting
    ck = _Checker()
    ck.keys(raw, "", _FILE_KEYS)
    scene_name = ck.string(raw, "scene", "scene")
    scene = None
    if scene_name is None:
        ck.add("scene", "the base scene file (a path relative to this file)", "nothing (the key is required)")
    elif has_nul(scene_name) or not scene_name.strip():
        ck.add("scene", "the base scene file (a path relative to this file)", _show(show_nul(scene_name)))
    else:
        sp = (path.parent / scene_name)
        try:
            scene = load_scene(sp)
        except SceneError as err:
            for p in err.problems:
                ck.add(f"scene ({_show(str(sp), 120)}): {p.key}", p.expected, p.found)
    name = ck.string(raw, "name", "name", path.stem)
    if name is not None and (not name.strip() or has_nul(name) or "/" in name or "\\" in name or name in (".", "..")
                             or len(name.encode("utf-8", "surrogatepass")) > 200):
        ck.add("name", "a name for the sweep (it names the default folder out/sweeps/NAME): not empty, no NUL, / or "
               "\\, at most 200 bytes", _show(show_nul(name)))
        name = None
    folder = ck.path(raw, "folder", "folder", None) if "folder" in raw else None
    metrics = ck.string(raw, "metrics", "metrics", None)
    if metrics is not None and not re.fullmatch(r"[\w.]+:[\w.]+", metrics):
        ck.add("metrics", "'module:function', a function (scene, model, traj) -> dict", _show(metrics))
    elif metrics is not None:
        why = _metrics_problem(metrics)
        if why is not None:
            ck.add("metrics", "'module:function' naming a function (scene, model, traj) -> dict that can be imported",
                   f"{_show(metrics)}: {why}")
    st = ck.section(raw, "sampling", ("kind", "n", "seed", "max_runs"))
    kind = ck.choice(st, "kind", "sampling.kind", SAMPLINGS, default="grid")
    n = ck.integer(st, "n", "sampling.n", default=None, minimum=1)
    seed = ck.integer(st, "seed", "sampling.seed", default=0, minimum=0)
    max_runs = ck.integer(st, "max_runs", "sampling.max_runs", default=DEFAULT_MAX_RUNS, minimum=1,
                          maximum=MAX_RUNS_LIMIT)
    if kind in ("random", "lhs") and "n" not in st:
        ck.add("sampling.n", f"the number of runs (an integer >= 1) for {kind} sampling", "nothing")
    if kind == "grid" and "n" in st:
        ck.add("sampling.n", "no n with kind = \"grid\" (a grid runs every combination)", _show(st["n"]))
        n = None
    sets = ck.table(raw, "set", "set") or {}
    for k in sets:
        try:
            parse_key(k)
        except ValueError as err:
            ck.add(f"set.{_show(k)}", "a dotted scene key", str(err))
    axes = []
    raw_axes = raw.get("axes", [])
    if not isinstance(raw_axes, list) or not all(isinstance(a, dict) for a in raw_axes):
        ck.add("axes", "an array of tables [[axes]]", f"{_type_name(raw_axes)} {_show(raw_axes)}")
        raw_axes = []
    for i, a in enumerate(raw_axes):
        where = f"axes[{i}]"
        ck.keys(a, where, _AXIS_KEYS)
        if ("key" in a) == ("keys" in a):
            ck.add(where, "key (one scene key) or keys (linked keys)", "both" if "key" in a else "neither")
            continue
        key = a["key"] if "key" in a else a["keys"]
        if "keys" in a and (not isinstance(key, list) or not key or not all(isinstance(k, str) for k in key)):
            ck.add(f"{where}.keys", "an array of dotted scene keys", _show(key))
            continue
        if "key" in a and not isinstance(key, str):
            ck.add(f"{where}.key", "a dotted scene key (a string)", f"{_type_name(key)} {_show(key)}")
            continue
        rng = a.get("range")
        if rng is not None and not (isinstance(rng, list) and len(rng) == 2 and all(isinstance(x, (int, float))
                                                                                    and not isinstance(x, bool)
                                                                                    for x in rng)):
            ck.add(f"{where}.range", "[low, high], two numbers", _show(rng))
            continue
        vals = a.get("values")
        if vals is not None and not isinstance(vals, list):
            ck.add(f"{where}.values", "an array of values", f"{_type_name(vals)} {_show(vals)}")
            continue
        num = ck.integer(a, "num", f"{where}.num", default=None, minimum=1)
        log = ck.boolean(a, "log", f"{where}.log", False)
        integer = ck.boolean(a, "integer", f"{where}.integer", False)
        if kind == "grid" and rng is not None and num is None and "num" not in a:
            ck.add(f"{where}.num", "how many values of the range the grid takes (an integer >= 1)", "nothing")
            continue
        try:
            axes.append(Axis(tuple(key) if isinstance(key, list) else key, values=None if vals is None else tuple(vals),
                             range=None if rng is None else tuple(rng), num=num, log=log, integer=integer))
        except ValueError as err:
            ck.add(where, "a valid axis", str(err))
    ot = ck.section(raw, "output", ("trajectories", "mcap"))
    trajectories = ck.boolean(ot, "trajectories", "output.trajectories", False)
    mcap = ck.boolean(ot, "mcap", "output.mcap", False)
    et = ck.section(raw, "engine", ("workers", "dask", "retries"))
    # the ranges qchain.simulate_batch takes (qchain.checks.bounds)
    workers = ck.integer(et, "workers", "engine.workers", default=None, minimum=int(_B.WORKERS.low),
                         maximum=int(_B.WORKERS.high))
    dask = ck.string(et, "dask", "engine.dask", None)
    if dask is not None:
        why = address_problem(dask)
        if why is not None:
            ck.add("engine.dask", "a Dask scheduler's address, [SCHEME://]HOST:PORT (tcp://127.0.0.1:8786)",
                   f"{_show(dask)}: {why}")
            dask = None
    retries = ck.integer(et, "retries", "engine.retries", default=3, minimum=int(_B.RETRIES.low),
                         maximum=int(_B.RETRIES.high))
    if workers is not None and dask is not None:
        ck.add("engine", "workers or dask, not both (a Dask cluster has its own workers)", "both")
    if not ck.problems:  # how many runs, counted before any is made
        too_many = runs_problem(kind, n, axes, max_runs)
        if too_many is not None:
            ck.add(*too_many)
    if ck.problems:
        raise SweepError(str(path), ck.problems)
    try:
        return SweepSpec(scene=scene, axes=axes, sampling=kind, n=n, seed=seed, set=sets, name=name,
                         folder=Path(folder) if folder is not None else Path("out") / "sweeps" / name,
                         trajectories=trajectories, mcap=mcap, metrics=metrics, workers=workers, dask=dask,
                         retries=retries, path=path, max_runs=max_runs)
    except ValueError as err:
        raise SweepError(str(path), [Problem("(sweep)", "a consistent sweep", str(err))]) from None
