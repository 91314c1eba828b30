"""Every benchmark chart in one go.

Writes into ``--out`` (default ``out/bench``): ``work_precision.{csv,png}``,
``cosserat_release.{csv,png}`` (PyElastica part only with the ``bench`` extra installed),
``release.{csv,png}`` and ``release_arm.csv`` (qchain against MuJoCo at equal accuracy against a
converged unshearable extensible rod built from MuJoCo hinge and slide links, with PyElastica's
Cosserat rods beside it, and the four-segment arm in ``pinocchio.aba`` calls; needs the ``bench``
extra's mujoco and pyelastica; reference tracks cached in ``release_cache/``),
``reduced.csv`` (full against planar and inextensible models),
``static_cantilever.{csv,png}``,
``scaling.{csv,png}``, ``derivatives.csv``, ``stability_map.{csv,png}``, ``contact_{overhead,mujoco}.csv``. ``--quick`` shortens every study.

Run: ``.venv/bin/python benchmarks/run_all.py [--quick] [--out DIR] [--only STUDY ...]``.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="run_all.py", description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short runs (a few minutes in all)")
    ap.add_argument("--out", type=Path, default=Path("out/bench"), help="folder for the CSV and PNG files")
    ap.add_argument("--only", nargs="+",
                    choices=["precision", "cosserat", "release", "reduced", "static", "scaling", "derivatives", "stability", "contact"],
                    help="run only these studies")
    args = ap.parse_args(argv)
    sys.path.insert(0, str(HERE))
    args.out.mkdir(parents=True, exist_ok=True)
    todo = args.only or ["precision", "cosserat", "release", "reduced", "static", "scaling", "derivatives", "stability", "contact"]
    t_all = time.perf_counter()
    for name in todo:
        t0 = time.perf_counter()
        print(f"== {name} ==", flush=True)
        if name == "precision":
            importlib.import_module("bench_precision").run(args.quick, args.out)
        elif name == "cosserat":
            try:
                mod = importlib.import_module("bench_cosserat")
            except ImportError as err:
                print(f"skipping the Cosserat comparison: {err}")
                continue
            mod.run(quick=args.quick, out_dir=args.out)
        elif name == "release":
            try:
                import mujoco  # noqa: F401
            except ImportError as err:
                print(f"skipping the MuJoCo comparison (the `bench` extra: pip install mujoco): {err}")
                continue
            importlib.import_module("bench_release").run(args.quick, args.out)
        elif name == "reduced":
            importlib.import_module("bench_reduced").run(args.quick, args.out)
        elif name == "static":
            importlib.import_module("bench_static").run(args.quick, args.out)
        elif name == "scaling":
            bc = importlib.import_module("bench_chain")
            ns = [1, 3, 10, 30] if args.quick else [1, 3, 8, 10, 30, 60]
            reps = ["--repeats", "5", "--calls", "50"] if args.quick else ["--repeats", "21", "--calls", "200"]
            bc.main(["--n", *map(str, ns), *reps, "--csv", str(args.out / "scaling.csv"),
                     "--png", str(args.out / "scaling.png")])
        elif name == "derivatives":
            bd = importlib.import_module("bench_derivatives")
            ns = [1, 3, 10] if args.quick else [1, 3, 8, 10, 30]
            reps = ["--repeats", "5", "--calls", "20"] if args.quick else ["--repeats", "15", "--calls", "100"]
            bd.main(["--n", *map(str, ns), *reps, "--csv", str(args.out / "derivatives.csv")])
        elif name == "stability":
            importlib.import_module("stability_map").run(args.quick, args.out)
        elif name == "contact":
            importlib.import_module("bench_contact").run(args.quick, args.out)
        print(f"-- {name}: {time.perf_counter() - t0:.1f} s", flush=True)
    print(f"all charts in {args.out} ({time.perf_counter() - t_all:.1f} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
