"""``qchain sweep SWEEP.toml``: the command over :mod:`qchain.batch.sweeps` (parse, check the
flags, print the runs and the summary, set the exit code)."""

from __future__ import annotations

import argparse
import json
import os
import sys

from ..batch.sweep_spec import address_problem, load_sweep, validate_runs
from ..batch.sweeps import run_sweep
from ..checks import bounds as _bounds
from ..checks.text import printable
from .checks import check_output_folder, path_argument
from .command import command
from .errors import BadInput, take_debug

__all__ = ["main"]


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="qchain sweep", description="Run a sweep file (format: the docstring of "
                                "qchain.batch.sweep_spec): a base scene over axes of its values, on every core or a Dask "
                                "cluster; per-run metrics in SWEEP_FOLDER/summary.parquet. Run it again to resume.")
    p.add_argument("sweep", type=path_argument, help="the sweep file (.toml)")
    eng = p.add_mutually_exclusive_group()
    eng.add_argument("--workers", type=int, default=None, metavar="N",
                     help="local worker processes (default: the file's, else every core; 1: in this process)")
    eng.add_argument("--dask", default=None, metavar="ADDRESS", help="run on a Dask scheduler, e.g. tcp://HOST:8786")
    p.add_argument("--out", type=path_argument, default=None, metavar="DIR", help="results folder, instead of the file's")
    p.add_argument("--restart", action="store_true", help="clear the folder's earlier results of this sweep first")
    p.add_argument("--trajectories", action="store_true", default=None, help="save each run's trajectory (npz)")
    p.add_argument("--mcap", action="store_true", default=None, help="record each run (MCAP)")
    p.add_argument("--retries", type=int, default=None, metavar="N", help="times a run whose worker died runs again")
    p.add_argument("--dry-run", action="store_true", help="list the runs and check their scenes; run nothing")
    bar = p.add_mutually_exclusive_group()
    bar.add_argument("--progress", dest="progress", action="store_true", default=None,
                     help="progress bar on stderr (default: when stderr is a terminal)")
    bar.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    return p


def main(argv=None, *, debug: bool | None = None, session=None) -> int:
    """``qchain sweep SWEEP.toml [...]`` (``argv``: the arguments after ``sweep``; ``debug``
    default: whether ``argv`` holds ``--debug``; ``session``: the ``qchain`` command's) -> the
    exit code: 0 the sweep completed (failed runs are results), 1 it stopped early, 2 bad input
    refused before any run (``docs/cli.md``)."""
    argv = [os.fspath(a) for a in (sys.argv[1:] if argv is None else argv)]
    if debug is None:
        argv, debug = take_debug(argv)
    return command("sweep", lambda s: _main(argv, s), bool(debug), session)


def _main(argv: list[str], session) -> int:
    """The body of :func:`main`; its exceptions become one line and an exit code there."""
    args = _parser().parse_args(argv)
    for flag, value, rng in (("--workers", args.workers, _bounds.WORKERS), ("--retries", args.retries, _bounds.RETRIES)):
        if value is not None and not rng.contains(value):
            raise BadInput(f"{flag} must be an integer {rng.text()}, got {value}")
    if args.dask is not None and (why := address_problem(args.dask)) is not None:
        raise BadInput(f"--dask {args.dask!r}: {why}")
    spec = load_sweep(args.sweep)
    if args.out is not None:
        spec.folder = args.out
    if args.trajectories:
        spec.trajectories = True
    if args.mcap:
        spec.mcap = True
    if args.retries is not None:
        spec.retries = args.retries
    for line in spec.describe():
        print(line)
    runs = spec.run_texts()
    print(printable(f"{len(runs)} runs; results in {spec.folder}"))
    if args.dry_run:
        validate_runs(spec, runs)
        for i, (point, _) in enumerate(runs):
            print(f"  run {i}: " + (", ".join(f"{k} = {json.dumps(v)}" for k, v in point.items()) or "(base)"))
        return 0
    if spec.folder is not None:  # before any run: a folder that cannot take the results is said at once
        check_output_folder("the results folder", spec.folder)
    sys.stdout.flush()
    session.phase = "run"
    try:  # (run_sweep takes the file's engine where neither flag is given)
        res = run_sweep(spec, workers=args.workers, client=args.dask, progress=args.progress, restart=args.restart,
                        runs=runs)
    except KeyboardInterrupt:
        where = f"; the finished runs are in {spec.folder} (run the same command again to continue)" \
            if spec.folder is not None else ""
        print(f"qchain sweep: interrupted{where}", file=sys.stderr)
        return 1
    session.phase = "end"
    n = res.table.num_rows
    now = f"{res.computed} computed now on the {res.engine} engine" if res.computed else "nothing left to compute"
    print(printable(f"sweep {spec.name}: {n} runs ({res.resumed} finished before, {now}, {res.n_failed} failed) in "
                    f"{res.wall_s:.3g} s"))
    failed = [r for r in res.rows() if not r["success"]]
    for r in failed[:5]:
        print(printable(f"  run {r['run']} failed: {r['message']}"))
    if len(failed) > 5:
        print(f"  ... and {len(failed) - 5} more (summary.parquet, column message)")
    if spec.folder is not None:
        print(printable(f"wrote {spec.folder / 'summary.parquet'}"))
    return 0
