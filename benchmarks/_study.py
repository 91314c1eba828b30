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


def spread(x) -> tuple[float, float, float]:
    """``(median, first quartile, third quartile)`` of the samples ``x`` (a set of rounds)."""
    import numpy as np

    return float(np.median(x)), float(np.percentile(x, 25)), float(np.percentile(x, 75))


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


def read_csv(path: Path) -> list[dict]:
    """Rows of a CSV written by ``write_csv``: numbers as float, ``True``/``False`` as bool, the rest as str
    (an empty cell stays ``""``)."""
    def value(s: str):
        if s in ("True", "False"):
            return s == "True"
        try:
            return float(s)
        except ValueError:
            return s

    with open(path, newline="") as fh:
        return [{k: value(v) for k, v in row.items()} for row in csv.DictReader(fh)]


def threshold(ax, value: float, text: str, axis: str = "x", at: float = 0.98, below: bool = False,
              color: str = "gray") -> None:
    """A dotted threshold line on ``ax`` with its meaning written along it.

    ``axis="x"``: a vertical line at ``x = value``, the text up its left side (right side if ``below``);
    ``axis="y"``: a horizontal line at ``y = value``, the text above it (under it if ``below``).
    ``at`` is where along the line the text sits, as a fraction of the axes: the text ends there when
    ``at > 0.5`` and starts there otherwise.
    """
    far = at > 0.5
    if axis == "x":
        ax.axvline(value, color=color, lw=0.9, ls=":")
        ax.text(value, at, f" {text} ", transform=ax.get_xaxis_transform(), rotation=90,
                ha="left" if below else "right", va="top" if far else "bottom", fontsize=8, color=color)
    else:
        ax.axhline(value, color=color, lw=0.9, ls=":")
        ax.text(at, value, f" {text} ", transform=ax.get_yaxis_transform(), ha="right" if far else "left",
                va="top" if below else "bottom", fontsize=8, color=color)
