"""Redraw every chart in a benchmark folder from its CSV, without running a benchmark.

Each chart's plotting function lives beside the study that measures it; this script reads the
CSV the study wrote and calls that function. A CSV that is not there is skipped.

Run: ``python benchmarks/replot.py [DIR]`` (default ``docs/bench``; ``out/bench`` for fresh runs).
"""

from __future__ import annotations

import argparse
import importlib
from pathlib import Path

import _study

# chart stem -> (module, how it redraws from (csv_path, png_path))
CHARTS = {
    "work_precision": ("bench_precision", "replot"),
    "release": ("bench_release", "replot"),
    "cosserat_release": ("bench_cosserat", "replot"),
    "static_cantilever": ("bench_static", "plot"),
    "scaling": ("bench_chain", None),
    "stability_map": ("stability_map", "replot"),
    "reduced_precision": ("bench_reduced", "replot"),
}


def replot(folder: Path) -> list[Path]:
    """Redraw ``<stem>.png`` from ``<stem>.csv`` in ``folder`` for every chart of ``CHARTS``; return the PNGs."""
    done = []
    for stem, (module, fn) in CHARTS.items():
        csv_path, png_path = folder / f"{stem}.csv", folder / f"{stem}.png"
        if not csv_path.exists():
            print(f"skip {stem}: no {csv_path}")
            continue
        mod = importlib.import_module(module)
        if fn is None:  # bench_chain.plot takes rows only
            mod.plot(_study.read_csv(csv_path), png_path)
        else:
            getattr(mod, fn)(csv_path, png_path)
        print(f"wrote {png_path}")
        done.append(png_path)
    return done


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folder", nargs="?", type=Path, default=Path("docs/bench"), help="folder of the CSV and PNG files")
    return replot(ap.parse_args(argv).folder)


if __name__ == "__main__":
    main()
