"""Parameter sweeps: ``sweep(scene, axes, ...)`` and :func:`run_sweep` (``qchain sweep SWEEP.toml``).

Each run of a :class:`qchain.batch.sweep_spec.SweepSpec` is run as ``qchain run`` would run
its scene, on the engines of :mod:`qchain.batch.workers`, into one table of per-run metrics
(:data:`METRICS`, the axes' values, a ``metrics=`` function's). The results folder
(``sweep.json``, ``runs.jsonl``, ``summary.parquet``, ``runs/``), resuming and
``restart``: ``docs/sweeps.md`` ("Results folder and resuming")."""

from __future__ import annotations

import hashlib
import importlib
import io
import json
import re
import math
import os
import sys
import time
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..checks.convert import describe_value
from ..scene.scene import Problem, Scene
from ..scene.reading import load_scene, parse_scene
from .sweep_spec import (
    Axis, SweepError, SweepSpec, _metrics_name, _plain, check_results_folder, load_sweep,
    validate_runs)
from .workers import DEFAULT_RETRIES, ClusterLost, Lost, Payload, ThreadPool, check_engine, engine_for

__all__ = ["sweep", "run_sweep", "SweepResult", "METRICS", "TIMING_COLUMNS", "summary_metrics", "Axis",
           "SweepSpec", "SweepError", "load_sweep"]

#: the summary table's metric columns (SI units; tip positions in the world frame)
METRICS = {
    "success": "the run reached the end of its duration",
    "status": "0 finished, -1 failed, -2 raised an exception",
    "message": "why the run ended",
    "t_end": "s, time reached",
    "nsamples": "output samples",
    "nfev": "dynamics evaluations",
    "nsteps": "steps",
    "nodes": "Gauss nodes of the segments (largest)",
    "dofs": "free coordinates of the model",
    "tip_final_x": "m", "tip_final_y": "m", "tip_final_z": "m",
    "tip_min_x": "m", "tip_min_y": "m", "tip_min_z": "m",
    "tip_max_x": "m", "tip_max_y": "m", "tip_max_z": "m",
    "tip_reach": "m, largest distance of the tip from its start",
    "bend_max": "rad, largest bending angle of any segment",
    "kinetic_final": "J", "potential_final": "J (gravity + elastic)", "kinetic_max": "J",
    "energy_start": "J, total at the start", "energy_final": "J, total at the end",
    "wall_s": "s, the simulation's wall time (a worker's first run includes loading the engine)",
    "build_s": "s, building the model (0 when a worker had it built)",
    "worker": "the worker process that ran it (host:pid)",
}
#: columns that depend on where and when a run ran, not on what it computed
TIMING_COLUMNS = ("wall_s", "build_s", "worker")
_MODEL_CACHE = 8  # models a worker keeps built


# ------------------------------------------------------------------------------ one run


@dataclass
class _Shared:
    metrics: object  # None, a callable or "module:function"
    trajectories: bool
    mcap: bool
    scene_path: str | None


def _metrics_fn(metrics):
    if metrics is None or callable(metrics):
        return metrics
    module, _, name = metrics.partition(":")
    fn = importlib.import_module(module)
    for part in name.split("."):
        fn = getattr(fn, part)
    return fn


def summary_metrics(scene: Scene, model, traj) -> dict:
    """The :data:`METRICS` a trajectory gives (NaN where it has no samples)."""
    ch = model.chain
    nan = float("nan")
    out = {"success": bool(traj.success), "status": int(traj.status), "message": str(traj.message),
           "t_end": float(traj.t[-1]) if len(traj.t) else nan, "nsamples": int(len(traj.t)), "nfev": int(traj.nfev),
           "nsteps": int(traj.meta.get("nsteps", 0)), "nodes": int(max(model.nodes)), "dofs": int(ch.nv_active)}
    if len(traj.t):
        tip = ch.frames_batch(traj.q, 2, t=traj.t).translation[:, -1]  # (K, 3) world
        lo, hi = tip.min(axis=0), tip.max(axis=0)
        ke, pe = traj.kinetic_energy, traj.potential_energy
        for which, at in (("final", tip[-1]), ("min", lo), ("max", hi)):
            out.update({f"tip_{which}_{c}": float(at[k]) for k, c in enumerate("xyz")})
        out["tip_reach"] = float(np.max(np.linalg.norm(tip - tip[0], axis=1)))
        out["bend_max"] = float(np.max(scene.bends(ch, traj)))
        out.update(kinetic_final=float(ke[-1]), potential_final=float(pe[-1]), kinetic_max=float(np.max(ke)),
                   energy_start=float(ke[0] + pe[0]), energy_final=float(ke[-1] + pe[-1]))
    else:  # no samples: the metrics of the samples are NaN
        out.update({k: nan for k in METRICS if k.startswith(("tip_", "kinetic", "potential", "energy", "bend"))})
    return out


_MODELS: OrderedDict = OrderedDict()  # in a worker: model key -> SceneModel


def _model_key(text: str) -> str:
    """What the built model depends on: the scene less its method, tolerances and outputs."""
    import tomllib

    raw = tomllib.loads(text)
    for k in ("name", "description", "output"):
        raw.pop(k, None)
    raw["simulation"] = {k: v for k, v in raw.get("simulation", {}).items()
                         if k not in ("method", "rtol", "atol", "dt", "max_step")}
    return hashlib.sha256(json.dumps(raw, sort_keys=True, default=str).encode()).hexdigest()


def _model(scene: Scene, text: str):
    key = _model_key(text)
    m = _MODELS.get(key)
    if m is not None:
        _MODELS.move_to_end(key)
        return m, 0.0
    t0 = time.perf_counter()
    m = scene.build()
    build_s = time.perf_counter() - t0
    _MODELS[key] = m
    while len(_MODELS) > _MODEL_CACHE:
        _MODELS.popitem(last=False)
    return m, build_s


def _one(shared: _Shared, i: int, text: str) -> dict:
    """Run ``i``: its row, and its trajectory and MCAP bytes if asked for."""
    import socket

    row: dict = {"run": i}
    extra: dict = {}
    try:
        scene = parse_scene(text, path=shared.scene_path)
        model, build_s = _model(scene, text)
        t0 = time.perf_counter()
        traj = scene.simulate(model=model)
        wall = time.perf_counter() - t0
        row.update(summary_metrics(scene, model, traj))
        fn = _metrics_fn(shared.metrics)
        if fn is not None:
            more = fn(scene, model, traj)
            if not isinstance(more, dict):
                raise TypeError(f"the metrics function returned {type(more).__name__}, not a dict")
            clash = set(more) & (set(METRICS) | {"run"})
            if clash:
                raise ValueError(f"the metrics function's names {sorted(clash)} are the sweep's own")
            more = {str(k): _plain(v) for k, v in more.items()}
            for k, v in more.items():
                _check_metric(k, v)
            row.update(more)
        row.update(wall_s=wall, build_s=build_s)
        if shared.trajectories:
            extra["trajectory"] = (traj, model.chain.frames_batch(traj.q, 2, t=traj.t).translation[:, -1]
                                   if len(traj.t) else np.zeros((0, 3)))
        if shared.mcap:
            extra["mcap"] = _mcap_bytes(scene, model, traj)
    except Exception as err:  # a run that cannot be built or raises is a failed run, not a failed sweep
        row.update(success=False, status=-2, message=f"raised {type(err).__name__}: {err}")
    row["worker"] = f"{socket.gethostname()}:{os.getpid()}"
    return {"row": row, **extra}


def _metric_ok(v, depth: int = 0) -> bool:
    if v is None or isinstance(v, (bool, str, int, float)):
        return True
    if isinstance(v, list) and depth < 8:
        return all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                   or isinstance(x, list) and _metric_ok(x, depth + 1) for x in v)
    return False


def _check_metric(key: str, value) -> None:
    """``TypeError`` naming the metric ``key`` and its type unless ``value`` is a number, a
    boolean, a string, None or a (nested) list of finite numbers: a value the run journal
    (JSON) and the summary table cannot hold makes its run a failed row, not a lost sweep."""
    if not key or "\0" in key:
        raise ValueError(f"the metrics function's name {key!r} is empty or holds a NUL character: a table column "
                         "needs a name")
    if not _metric_ok(value):
        shown = "list holding something other than finite numbers" if isinstance(value, list) else type(value).__name__
        raise TypeError(f"the metrics function's value {key!r} is a {shown} ({describe_value(value, 40)}); "
                        "a metric must be a number, a boolean, a string, None or a list of finite numbers")


def _runs(shared: _Shared, items: list) -> list:
    """In a worker: run each ``(index, scene text)``."""
    return [_one(shared, i, text) for i, text in items]


def _mcap_bytes(scene: Scene, model, traj) -> bytes:
    """The run's MCAP recording (as ``qchain run`` writes it), made in memory after the run."""
    from ..recording.logger import RunLogger
    from ..recording.records import RunInfo
    from ..recording.recorder import ChainRecorder

    ch = model.chain
    info = RunInfo(n_segments=ch.n, radii=[s.radius for s in ch.segments],
                   chamber_radii=[s.chamber_radius for s in ch.segments], scene=scene.text,
                   scene_path=str(scene.path) if scene.path else None,
                   params={"base": ch.base, "gravity": ch.gravity, "nodes": model.nodes, "planar": ch.planar,
                           "reductions": model.reductions, "method": scene.method},
                   name=scene.name or "qchain sweep run")
    buf = io.BytesIO()
    with RunLogger(info, buf, worker="thread", quiet=True) as log, ChainRecorder(log, ch) as rec:
        for k in range(len(traj.t)):
            rec(traj.t[k], traj.q[k], traj.v[k], traj.p[k], energies=(traj.kinetic_energy[k], traj.potential_energy[k]))
        log.set_outcome(traj.success, traj.message, traj.status, traj.nfev)
    return buf.getvalue()


def _warm(shared_and_texts) -> float:
    """A one-step run of each kind of engine the sweep needs (compiles or loads it)."""
    shared, texts = shared_and_texts
    t0 = time.perf_counter()
    for text in texts:
        try:
            scene = parse_scene(text, path=shared.scene_path)
            model = scene.build()
            traj = scene.simulate(model=model, duration=min(scene.duration, scene.dt or 1e-6))
            summary_metrics(scene, model, traj)
            if shared.mcap:
                _mcap_bytes(scene, model, traj)
        except Exception:  # the run itself will say what is wrong with it, in its row
            continue
    return time.perf_counter() - t0


def _engine_kinds(scenes: list[Scene]) -> dict:
    """The first run of each (method, planar kernel): one-step runs of these compile or load
    every engine the sweep uses."""
    kinds: dict = {}
    for i, sc in enumerate(scenes):
        planar = sc.reduce and sc.planar_obstacle() is None
        kinds.setdefault((sc.method, planar), i)
    return kinds


# ------------------------------------------------------------------------------ the folder


#: The files a sweep writes in its runs/ folder, and their temporaries
_RUN_FILE = re.compile(r"\.?run-[0-9]{5,}\.[A-Za-z0-9]+(\.[A-Za-z0-9._-]*)?")


class _Folder:
    """A sweep's results folder: manifest, journal, table, per-run files."""

    def __init__(self, folder: Path):
        self.folder = Path(folder)
        self.manifest = self.folder / "sweep.json"
        self.journal = self.folder / "runs.jsonl"
        self.table = self.folder / "summary.parquet"
        self.runs = self.folder / "runs"
        self._fh = None
        self._lock: int | None = None

    def clear(self) -> None:
        """Remove this sweep's own files (and nothing else)."""
        for p in (self.manifest, self.journal, self.table):
            p.unlink(missing_ok=True)
        if self.runs.is_dir():  # only names this sweep gives (run-00012.npz, .run-00012...): a
            for p in self.runs.iterdir():  # qchain run's runs/run-20261202-134758.mcap stays
                if _RUN_FILE.fullmatch(p.name):
                    p.unlink()

    def open(self, manifest: dict) -> list[dict]:
        """Start or resume: the rows finished before (raises if the folder holds another sweep)."""
        self.folder.mkdir(parents=True, exist_ok=True)
        if self.manifest.is_file():
            old = json.loads(self.manifest.read_text())
            if old.get("fingerprint") != manifest["fingerprint"]:
                what = [f"{k}: {old.get(k)!r} there, {manifest.get(k)!r} now"
                        for k in ("runs", "trajectories", "mcap", "metrics") if old.get(k) != manifest.get(k)]
                why = "; ".join(what) or "the runs' scenes differ"
                raise SweepError(str(self.folder), [Problem(
                    "folder", "the results of this same sweep to resume, or an empty folder",
                    f"the results of another sweep ({why}); use another folder, or restart (--restart) to clear it")])
        else:
            _atomic_write(self.manifest, json.dumps(manifest, indent=1).encode())
        rows = self._read_journal()
        if manifest.get("trajectories") or manifest.get("mcap"):
            self.runs.mkdir(exist_ok=True)
        self._fh = open(self.journal, "a", encoding="utf-8")
        return rows

    def _read_journal(self) -> list[dict]:
        if not self.journal.is_file():
            return []
        data = self.journal.read_bytes()
        end = data.rfind(b"\n") + 1
        if end < len(data):  # a line cut by a kill: that run was not finished; drop it
            with open(self.journal, "r+b") as fh:
                fh.truncate(end)
        rows = []
        for n, line in enumerate(data[:end].splitlines()):
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError as err:
                raise SweepError(str(self.journal), [Problem(f"line {n + 1}", "one JSON object a finished run",
                                                           f"{err}")]) from None
        return rows

    def path(self, i: int, ext: str) -> Path:
        return self.runs / f"run-{i:05d}.{ext}"

    def add(self, row: dict, extra: dict) -> None:
        """Write a finished run's files, then its line (flushed: a kill after this keeps it)."""
        i = row["run"]
        if "trajectory" in extra:
            traj, tip = extra["trajectory"]
            buf = io.BytesIO()
            np.savez_compressed(buf, t=traj.t, q=traj.q, v=traj.v, p=traj.p, kinetic_energy=traj.kinetic_energy,
                                potential_energy=traj.potential_energy, tip=tip, success=traj.success,
                                message=traj.message)
            _atomic_write(self.path(i, "npz"), buf.getvalue())
        if "mcap" in extra:
            _atomic_write(self.path(i, "mcap"), extra["mcap"])
        self._fh.write(json.dumps(row) + "\n")
        self._fh.flush()

    def lock(self) -> None:
        """Hold the folder for this process (an exclusive ``flock`` on its ``.sweep.lock``,
        released by :meth:`close` or the process's end); a SweepError naming the folder and
        the holder if another sweep holds it."""
        import fcntl

        self.folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.folder / ".sweep.lock", os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
            os.close(fd)
            raise SweepError(str(self.folder), [Problem(
                "folder", "a folder no other sweep is writing",
                f"another sweep{f' (pid {holder})' if holder.isdigit() else ''} is writing it: wait for it to end "
                "(then run this one to resume), or use another folder")]) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        self._lock = fd

    def close(self) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None
        if self._lock is not None:
            os.close(self._lock)  # (the lock goes with it)
            self._lock = None


def _atomic_write(path: Path, data: bytes) -> None:
    tmp = path.with_name(f".{path.name}.tmp")
    with open(tmp, "wb") as fh:
        fh.write(data)
    os.replace(tmp, path)


def _table(rows: list[dict], columns: list[str]):
    """The summary as a pyarrow Table: ``columns`` first, in order, then any others."""
    import pyarrow as pa

    rows = sorted(rows, key=lambda r: r["run"])
    names = list(dict.fromkeys(columns + [k for r in rows for k in r]))
    cols = {}
    for name in names:
        vals = [r.get(name) for r in rows]
        try:
            cols[name] = pa.array(vals)
        except (pa.ArrowInvalid, pa.ArrowTypeError):  # mixed kinds of values: keep them readable
            cols[name] = pa.array([None if v is None else json.dumps(v) for v in vals], pa.string())
    return pa.table(cols)


def _write_table(path: Path, table) -> None:
    import pyarrow.parquet as pq

    buf = io.BytesIO()
    pq.write_table(table, buf)
    _atomic_write(path, buf.getvalue())


# ------------------------------------------------------------------------------ running


@dataclass
class SweepResult:
    """The outcome of a sweep.

    Attributes
    ----------
    table : pyarrow.Table
        One row a run, sorted by ``run``: the axes' values (one column a key), then
        :data:`METRICS` and any extra metrics. ``table.to_pylist()`` gives dicts;
        ``table.column(name).to_numpy()`` a column.
    folder : Path or None
    computed : int
        Runs computed by this call.
    resumed : int
        Runs found finished in the folder.
    wall_s : float
        Wall time of this call, s.
    complete : bool
        Every run has its row (False after Ctrl-C).
    engine : str
        "serial", "local" or "dask".
    trajectories : dict
        Without a folder, ``run -> (Trajectory, tip path (N, 3))`` when trajectories were
        asked for (:meth:`trajectory`, :meth:`tip_path` read them, or the saved files).
    """

    table: object
    folder: Path | None
    computed: int
    resumed: int
    wall_s: float
    complete: bool
    engine: str
    trajectories: dict

    @property
    def n_failed(self) -> int:
        return int(sum(1 for s in self.table.column("success").to_pylist() if not s))

    def rows(self) -> list[dict]:
        return self.table.to_pylist()

    def _saved(self, run: int, what: str):
        if run in self.trajectories:
            return self.trajectories[run]
        if self.folder is None:
            raise KeyError(f"run {run} has no {what} (run the sweep with trajectories=True)")
        path = _Folder(self.folder).path(run, "npz")
        if not path.is_file():
            raise KeyError(f"run {run} has no saved {what} ({path} is missing; trajectories=True saves them)")
        return path

    def trajectory(self, run: int):
        """Run ``run``'s :class:`~qchain.sim.trajectory.Trajectory` (kept with ``trajectories``)."""
        from ..sim.trajectory import Trajectory

        saved = self._saved(run, "trajectory")
        if isinstance(saved, tuple):
            return saved[0]
        with np.load(saved) as z:
            return Trajectory(t=z["t"], q=z["q"], v=z["v"], p=z["p"], kinetic_energy=z["kinetic_energy"],
                              potential_energy=z["potential_energy"], success=bool(z["success"]),
                              message=str(z["message"]))

    def tip_path(self, run: int) -> np.ndarray:
        """Run ``run``'s world tip positions (N, 3) m at its samples (kept with ``trajectories``)."""
        saved = self._saved(run, "tip path")
        if isinstance(saved, tuple):
            return saved[1]
        with np.load(saved) as z:
            return z["tip"]


def run_sweep(spec: SweepSpec, *, workers=None, client=None, progress: bool | None = None, restart: bool = False,
              stream=sys.stderr, runs: list | None = None) -> SweepResult:
    """Run a :class:`SweepSpec` (see :func:`sweep`); ``workers``/``client`` override the spec's
    engine; ``runs``: ``spec.run_texts()`` if the caller has them already."""
    w_start = time.perf_counter()
    if workers is None and client is None:
        workers, client = spec.workers, spec.dask
    check_engine(workers, client, spec.retries)
    if isinstance(workers, ThreadPool):
        raise ValueError(f"workers must be a count, a qchain.batch.workers.LocalPool or None for a sweep, got {workers!r}: "
                         "a sweep's run builds its scene, computes its metrics and writes its files in Python, which "
                         "threads would run one at a time")
    runs = spec.run_texts() if runs is None else runs
    scenes = validate_runs(spec, runs)
    axis_cols = [k for a in spec.axes for k in a.keys]
    points = {i: p for i, (p, _) in enumerate(runs)}
    folder = _Folder(spec.folder) if spec.folder is not None else None
    done: dict[int, dict] = {}
    if folder is not None:
        check_results_folder(spec.folder, n_runs=len(runs))  # a folder it cannot resume from, before any run
        folder.lock()  # one sweep a folder at a time: a second one would compute every run again
        try:
            if restart:
                folder.clear()
            fingerprint = spec.fingerprint(runs)
            manifest = {"name": spec.name, "fingerprint": fingerprint, "runs": len(runs), "sampling": spec.sampling,
                        "n": spec.n, "seed": spec.seed, "set": spec.set, "axes": [a.to_json() for a in spec.axes],
                        "scene": str(spec.scene.path) if spec.scene.path else None, "trajectories": spec.trajectories,
                        "mcap": spec.mcap, "metrics": _metrics_name(spec.metrics)}
            for row in folder.open(manifest):
                done[int(row["run"])] = row
        except BaseException:
            folder.close()
            raise
    todo = [i for i in range(len(runs)) if i not in done]
    resumed = len(done)
    engine = engine_for(workers, client, tasks=len(todo)) if todo else None
    shared = _Shared(metrics=spec.metrics, trajectories=spec.trajectories, mcap=spec.mcap,
                     scene_path=str(spec.scene.path) if spec.scene.path else None)
    show = stream is not None and (stream.isatty() if progress is None else progress)
    from tqdm import tqdm

    bar = tqdm(total=len(runs), initial=resumed, unit="run", file=stream, smoothing=0.1, desc=f"sweep {spec.name}",
               disable=not show)
    kept: dict = {}
    complete = False
    try:
        items = [(i, runs[i][1]) for i in todo]
        if engine is None:
            results = ((i, _one(shared, i, text)) for i, text in items)
            name = "serial"
        else:
            name = engine.kind
            kinds = _engine_kinds([scenes[i] for i in todo])
            warm = (shared, [runs[todo[k]][1] for k in kinds.values()])
            _warm(warm)  # compile or load every engine here once; the workers load them from the cache
            engine.warm(_warm, Payload.of(warm), key=("sweep", tuple(sorted(map(str, kinds)))))
            results = ((items[k][0], res) for k, res in engine.map(_runs, Payload.of(shared), items,
                                                                     retries=spec.retries))
        for i, res in results:
            if isinstance(res, Lost):
                res = {"row": {"run": i, "success": False, "status": -2, "message": f"not run: {res.message}"}}
            clash = sorted(set(res["row"]) & set(points[i]))
            if clash:  # the metrics would overwrite the values the run was made with: the row says so instead
                res = {"row": {"run": i, "success": False, "status": -2,
                               "message": f"the metrics function's names {clash} are the sweep's axis keys: its "
                                          "results are not kept (the run's axis values would be lost)"}}
            row = {**{"run": i}, **points[i], **res["row"]}
            if folder is not None:
                folder.add(row, res)
            elif "trajectory" in res:
                kept[i] = res["trajectory"]
            done[i] = row
            bar.update(1)
        complete = True
    except ClusterLost as err:
        if folder is None:
            raise
        raise ClusterLost(f"{err}; the {len(done)} of {len(runs)} runs finished are in {spec.folder} (run the sweep "
                          "again to compute the rest)") from None
    finally:
        bar.close()
        if engine is not None and isinstance(client, str):  # a client this call connected
            engine.close()
        if folder is not None:
            folder.close()
            if done:
                _write_table(folder.table, _table(list(done.values()), ["run"] + axis_cols + list(METRICS)))
    table = _table(list(done.values()), ["run"] + axis_cols + list(METRICS))
    return SweepResult(table=table, folder=spec.folder, computed=len(done) - resumed, resumed=resumed,
                       wall_s=time.perf_counter() - w_start, complete=complete, engine=name if todo else "none",
                       trajectories=kept)


def sweep(scene, axes, *, sampling: str = "grid", n: int | None = None, seed: int = 0, set: dict | None = None,
          folder=None, trajectories: bool = False, mcap: bool = False, metrics=None, workers=None, client=None,
          retries: int = DEFAULT_RETRIES, progress: bool | None = None, restart: bool = False,
          name: str | None = None) -> SweepResult:
    """Run a scene over axes of its values; one row of summary metrics a run (``docs/sweeps.md``).

    Parameters
    ----------
    scene : Scene or path
    axes : dict {key: values} or list of Axis
        Dotted scene keys and their values (:class:`qchain.batch.sweep_spec.Axis` for ranges,
        log spacing, whole numbers and linked keys).
    sampling, n, seed
        ``"grid"`` (every combination), or ``n`` ``"random"`` or ``"lhs"`` samples drawn with ``seed``.
    set : dict, optional
        {dotted key: value} for every run (``{"each_segment": [...]}``: the list once a segment).
    folder : path, optional
        Results folder, resumed when started again; None keeps the results in memory only.
    trajectories, mcap : bool
        Also keep each run's trajectory (npz) and MCAP recording.
    metrics : callable or "module:function", optional
        ``(scene, model, traj) -> dict`` of more per-run metrics, defined at module level.
    workers, client, retries
        The engine, as for :func:`qchain.simulate_batch`.
    progress : bool, optional
        A progress bar on stderr (default: when stderr is a terminal).
    restart : bool
        Clear the folder's earlier results of this sweep first."""
    if not isinstance(scene, Scene):
        scene = load_scene(scene)
    spec = SweepSpec(scene=scene, axes=axes, sampling=sampling, n=n, seed=seed, set=set or {},
                     name=name or (scene.path.stem if scene.path else "sweep"), folder=folder,
                     trajectories=trajectories, mcap=mcap, metrics=metrics, retries=retries)
    return run_sweep(spec, workers=workers, client=client, progress=progress, restart=restart)
