"""Pieces the benchmark scripts share: the ``--quick``/``--out`` command line, CSV files and
finished figures."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path


def main(doc: str, run, argv=None):
    """``--quick`` and ``--out DIR`` (default ``out/bench``), then ``run(quick, out_dir)``."""
    ap = argparse.ArgumentParser(description=doc.strip().splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short runs")
    ap.add_argument("--out", type=Path, default=Path("out/bench"), help="folder for the CSV and PNG files")
    args = ap.parse_args(argv)
    return run(args.quick, args.out)


def write_csv(rows: list[dict], path: Path) -> None:
    """Rows of equal keys as a CSV file (the folder is made)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)


def save(fig, path: Path) -> None:
    """Lay out, write (110 dpi) and close a matplotlib figure."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
