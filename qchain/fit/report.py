"""What a fit says, as text, JSON-ready values and a picture (:class:`~qchain.fit.FitReport`'s
``summary()``, ``to_dict()`` and ``plot()``; ``qchain fit`` writes them as its outputs).

The model's points come from the fit itself: the residuals it computed at its first point
(the start model) and at the solution (the fitted model) are the model's points minus the
measured ones (:meth:`FitReport.predicted`), so nothing is simulated again here.

The picture (:func:`plot_report`): one column an experiment. A measured motion
(:class:`~qchain.fit.Measurements`) shows the first measured point's x, y and z over time
(measured as dots, the start model and the fitted model as lines) and the residual norm
over time (each measured point's distance to the model's, the largest of them a sample); a
motion measured as coordinates only shows the three of them that move most (SI units) and
the largest scaled coordinate residual a sample; static poses
(:class:`~qchain.fit.StaticPoses`) the same against the pose's number, as markers.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

__all__ = ["summary_lines", "report_dict", "plot_report", "experiment_rms", "split_residuals", "FIGURE_WIDTH", "FIGURE_HEIGHT"]

#: The picture's size (inches) a column (one experiment) and its height.
FIGURE_WIDTH, FIGURE_HEIGHT = 6.0, 8.0


def _kind(e) -> str:
    from .statics import StaticPoses

    return "static" if isinstance(e, StaticPoses) else "dynamic"


def split_residuals(e, r: np.ndarray):
    """An experiment's residuals (K rows,) as its points' part (K, m, 3) m and its coordinates'
    part (K, nc) (scaled, m), each None when it measured none."""
    from .measurements import Measurements
    from .statics import StaticPoses

    K = e.points.shape[0] if isinstance(e, StaticPoses) else e.n_samples
    R = np.asarray(r, dtype=float).reshape(K, -1)
    m = 0 if e.points is None else e.points.shape[1]
    pts = R[:, :3 * m].reshape(K, m, 3) if m else None
    crd = R[:, 3 * m:] if (isinstance(e, Measurements) and e.coordinates is not None) else None
    return pts, crd


def _rms(e, r: np.ndarray) -> float:
    """The RMS residual (m) of experiment ``e``'s residuals ``r``: sqrt of the mean, over its
    measured items, of each one's squared residual -- a point's distance, a coordinate's scaled
    residual (:func:`qchain.fit.measurements.coordinate_scale`)."""
    pts, crd = split_residuals(e, r)
    sq = []
    if pts is not None:
        sq.append(np.sum(pts ** 2, axis=-1).reshape(-1))
    if crd is not None:
        sq.append((crd ** 2).reshape(-1))
    sq = np.concatenate(sq) if sq else np.zeros(0)
    return float(np.sqrt(np.mean(sq))) if sq.size else math.nan


def _sample_error(e, r: np.ndarray) -> np.ndarray:
    """(K,) m: a sample's largest item residual (a point's distance or a scaled coordinate's)."""
    pts, crd = split_residuals(e, r)
    parts = []
    if pts is not None:
        parts.append(np.linalg.norm(pts, axis=-1))
    if crd is not None:
        parts.append(np.abs(crd))
    return np.concatenate(parts, axis=1).max(axis=1)


def experiment_rms(report) -> list[tuple[float, float]]:
    """Each experiment's RMS residual (m: a point's distance, a coordinate's scaled residual) for
    the start model and the fitted model."""
    starts = report.start_residuals or [None] * len(report.experiments)
    return [(math.nan if s is None else _rms(e, s), _rms(e, r))
            for e, s, r in zip(report.experiments, starts, report.residuals)]


def _finite_or_none(x):
    x = float(x)
    return x if math.isfinite(x) else None


def report_dict(report) -> dict:
    """The fit as JSON-ready values: each parameter's key, unit, start, fitted value, standard
    error (None: not fixed by the data) and bounds; the correlation matrix (None where it is not
    defined); the warnings' findings; the counters; each experiment's RMS point distance (m)
    before and after; wall and CPU time (s)."""
    res = report.result
    params = [{"key": p.key, "unit": p.unit, "start": float(x0), "value": float(x), "stderr": _finite_or_none(s),
               "lower": _finite_or_none(p.lower), "upper": _finite_or_none(p.upper)}
              for p, x0, x, s in zip(report.parameters, res.x0, res.x, res.stderr)]
    corr = [[_finite_or_none(c) for c in row] for row in np.asarray(res.correlation)]
    exps = []
    for e, (before, after) in zip(report.experiments, experiment_rms(report)):
        coords = e.coordinate_index.size if _kind(e) == "dynamic" else 0
        exps.append({"source": str(e.source), "kind": _kind(e),
                     "samples": int(e.pressures.shape[0] if _kind(e) == "static" else e.n_samples),
                     "points": 0 if e.points is None else int(e.points.shape[1]), "coordinates": int(coords),
                     "rms_start_m": _finite_or_none(before), "rms_fitted_m": _finite_or_none(after)})
    return {
        "scene": str(report.source),
        "parameters": params,
        "correlation": corr,
        "sigma_m": _finite_or_none(res.sigma),
        "cost": float(res.cost),
        "success": bool(res.success),
        "message": str(res.message),
        "unidentifiable": [list(g) for g in res.unidentifiable],
        "correlated": [[a, b, float(c)] for a, b, c in res.correlated],
        "at_bound": list(res.at_bound),
        "counters": {"nfev": int(res.nfev), "njev": int(res.njev), "evaluations": int(report.evaluations)},
        "experiments": exps,
        "wall_s": float(report.wall_s),
        "cpu_s": float(report.cpu_s),
    }


def summary_lines(report) -> list[str]:
    """The parameters' table (:meth:`FitResult.table`), the residuals' size, each experiment's
    RMS point distance before and after, the counters and the time."""
    res = report.result
    out = list(res.table())
    out.append(f"residuals: {res.residuals.size} numbers, sigma {res.sigma * 1e3:.4g} mm; "
               f"{'converged' if res.success else 'not converged'} ({res.message})")
    for i, (e, (before, after)) in enumerate(zip(report.experiments, experiment_rms(report))):
        static = _kind(e) == "static"
        K = e.pressures.shape[0] if static else e.n_samples
        what = "" if static or e.coordinates is None else f", {e.coordinate_index.size} coordinates"
        out.append(f"experiment {i} ({_kind(e)}, {K} {'poses' if static else 'samples'}{what}):"
                   f" RMS residual {before * 1e3:.4g} mm at the start, {after * 1e3:.4g} mm fitted  [{e.source}]")
    out += [f"note: {n}" for n in getattr(report, "notes", [])]
    out.append(f"{res.nfev} residual evaluations ({res.njev} with the Jacobian), {report.wall_s:.3g} s wall, "
               f"{report.cpu_s:.3g} s CPU")
    return out


def plot_report(report, path=None, dpi: int = 80):
    """Measured against start and fitted motion and the residual norm, a column an experiment.

    Parameters
    ----------
    report : FitReport
    path : path, optional
        Where to write the PNG (whole or not at all); the figure is closed then.
    dpi : int
        The picture is ``FIGURE_WIDTH * n_experiments`` by ``FIGURE_HEIGHT`` inches at ``dpi``.

    Returns
    -------
    matplotlib.figure.Figure or Path
        The figure (no ``path``), or ``path``.
    """
    import matplotlib

    matplotlib.use("Agg")  # (a no-op once pyplot chose a backend elsewhere; savefig needs none)
    from matplotlib.figure import Figure

    n = len(report.experiments)
    fig = Figure(figsize=(FIGURE_WIDTH * n, FIGURE_HEIGHT), dpi=dpi)
    axes = fig.subplots(4, n, squeeze=False, sharex="col")
    fitted = report.predicted("fitted")
    start = report.predicted("start") if report.start_residuals else [None] * n
    fitted_q = report.predicted_coordinates("fitted")
    start_q = report.predicted_coordinates("start") if report.start_residuals else [None] * n
    starts_r = report.start_residuals or [None] * n
    for j, e in enumerate(report.experiments):
        static = _kind(e) == "static"
        x = np.arange(e.points.shape[0]) if static else e.t
        style = dict(marker="o", ls="none", ms=4) if static else dict(lw=1.2)
        if e.points is not None:  # the first point's x, y, z (mm)
            shown = [(e.points[:, 0, i] * 1e3, None if start[j] is None else start[j][:, 0, i] * 1e3,
                      fitted[j][:, 0, i] * 1e3, f"{_point_name(e.where[0])} {'xyz'[i]} (mm)") for i in range(3)]
        else:  # coordinates only: the three used ones that move most (SI units)
            ci = e.coordinate_index
            qm = e.coordinates[:, ci]
            pick = np.argsort(-np.ptp(qm, axis=0), kind="stable")[:3]
            shown = [(qm[:, k], None if start_q[j] is None else start_q[j][:, k], fitted_q[j][:, k],
                      _coordinate_name(int(ci[k]))) for k in pick]
        for i, (meas, st, fi, label) in enumerate(shown):
            ax = axes[i, j]
            ax.plot(x, meas, "x" if static else ".", ms=5 if static else 2, color="0.35", label="measured")
            if st is not None:
                ax.plot(x, st, color="C3", label="start model", **style)
            ax.plot(x, fi, color="C0", label="fitted model", **style)
            ax.set_ylabel(label)
        axes[0, j].set_title(_short(str(e.source)), fontsize=9)
        axes[0, j].legend(loc="best", fontsize=7)
        ax = axes[3, j]
        before, after = experiment_rms(report)[j]
        for rr, color, what, rms in ((starts_r[j], "C3", "start", before), (report.residuals[j], "C0", "fitted", after)):
            if rr is None:
                continue
            err = _sample_error(e, rr) * 1e3  # the largest item's a sample
            label = f"{what} (RMS {rms * 1e3:.3g} mm)"
            if static:
                w = 0.4
                ax.bar(x + (-w / 2 if what == "start" else w / 2), err, width=w, color=color, label=label)
            else:
                ax.plot(x, err, color=color, lw=1, label=label)
        ax.set_ylabel("residual norm (mm)")
        ax.set_xlabel("pose" if static else "t (s)")
        ax.legend(loc="best", fontsize=7)
    fig.suptitle("qchain fit: measured against the start and the fitted model")
    fig.tight_layout()
    if path is None:
        return fig
    from ..checks.paths import written_whole

    with written_whole(path, binary=True, prefix=".fit-") as fh:
        fig.savefig(fh, format="png", dpi=dpi)
    return Path(path)


def _coordinate_name(i: int) -> str:
    """Entry ``i`` of a curvature-coordinate ``q`` in words, with its unit."""
    j, k = divmod(i, 3)
    return f"segment {j} {('l (m)', 'ux (1/m)', 'uy (1/m)')[k]}"


def _point_name(where) -> str:
    seg, alpha = where
    return "tip" if (seg == -1 and alpha == 1.0) else f"segment {seg} at {alpha:g}"


def _short(text: str, limit: int = 70) -> str:
    return text if len(text) <= limit else "..." + text[-(limit - 3):]
