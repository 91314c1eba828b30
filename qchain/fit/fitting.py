"""``qchain.fit.fit``: chosen scene parameters fitted to measured experiments.

The fit rebuilds the scene's model for each trial ``theta`` (the fitted keys written into
the scene table, :func:`qchain.batch.sweep_spec.apply_values`, the model built as ``qchain
run`` builds it, with the node count held at the start model's so that the model's
structure does not change under the fit), evaluates every experiment's residuals and their
exact Jacobian, and hands them to :func:`qchain.fit.solve.least_squares_fit`. The fitted
scene is the scene file with the fitted values put in (:meth:`FitReport.scene_text`).
"""

from __future__ import annotations

import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..batch.sweep_spec import apply_values
from .dynamics import dynamic_residuals, input_noise_draws
from .measurements import MeasurementError, Measurements, filter_pressures, pressure_noise
from .parameters import FitParameter, _tables, column_map, fit_parameters, scene_values
from .solve import COVARIANCES, FitResult, least_squares_fit
from .statics import StaticPoses, static_input_draws, static_residuals

__all__ = ["fit", "FitReport"]


@dataclass
class FitReport:
    """A fit's outcome.

    Attributes
    ----------
    result : FitResult
        Values, standard errors, correlation, residuals, counters (:mod:`qchain.fit.solve`).
    parameters : list of FitParameter
    experiments : list
        What was fitted to.
    residuals : list of (n_i,) arrays
        Each experiment's residuals at the solution (m), in its own order.
    raw : dict
        The fitted scene's table.
    source : str
        The scene file fitted.
    """

    result: FitResult
    parameters: list
    experiments: list
    residuals: list
    raw: dict
    source: str
    evaluations: int = 0
    notes: list = field(default_factory=list)
    start_residuals: list = field(default_factory=list)
    wall_s: float = 0.0
    cpu_s: float = 0.0

    def predicted(self, which: str = "fitted") -> list:
        """Each experiment's model points (K, m, 3) m, world frame, of the ``"fitted"`` or the
        ``"start"`` model: the measured points plus the residuals the fit computed there (no run
        again); None for an experiment that measured no points (coordinates only)."""
        from .report import split_residuals

        rs = self.residuals if which == "fitted" else self.start_residuals
        return [split_residuals(e, r)[0] if e.points is None else e.points + split_residuals(e, r)[0]
                for e, r in zip(self.experiments, rs)]

    def predicted_coordinates(self, which: str = "fitted") -> list:
        """Each measured motion's model coordinates (K, nc) at its used coordinates
        (``e.coordinate_index``; SI units), of the ``"fitted"`` or the ``"start"`` model, as
        :meth:`predicted`; None for an experiment without measured coordinates."""
        from .report import split_residuals

        rs = self.residuals if which == "fitted" else self.start_residuals
        out = []
        for e, r in zip(self.experiments, rs):
            rc = split_residuals(e, r)[1]
            if rc is None:
                out.append(None)
                continue
            ci = e.coordinate_index
            out.append(e.coordinates[:, ci] + rc / e.coordinate_scale[ci])
        return out

    def summary(self) -> list[str]:
        """The fit in lines of text (:func:`qchain.fit.report.summary_lines`)."""
        from .report import summary_lines

        return summary_lines(self)

    def to_dict(self) -> dict:
        """The fit as plain JSON-ready values (:func:`qchain.fit.report.report_dict`)."""
        from .report import report_dict

        return report_dict(self)

    def plot(self, path=None, dpi: int = 80):
        """Measured against start and fitted motion, and the residuals, per experiment
        (:func:`qchain.fit.report.plot_report`); written to ``path`` (PNG) if given."""
        from .report import plot_report

        return plot_report(self, path, dpi=dpi)

    def scene_text(self) -> str:
        """The fitted scene as TOML, with a header saying what was fitted."""
        import tomli_w

        head = [f"# fitted by qchain.fit from {self.source}: {len(self.experiments)} experiment(s), "
                f"RMS residual {np.sqrt(np.mean(self.result.residuals ** 2)):.4g} m"]
        for p, x, s in zip(self.parameters, self.result.x, self.result.stderr):
            head.append(f"#   {p.key} = {x:.9g} {p.unit} (+- {s:.3g}; started at {p.start:.6g})")
        return "\n".join(head) + "\n" + tomli_w.dumps(self.raw)

    def write_scene(self, path) -> Path:
        """Write :meth:`scene_text` to ``path`` (whole or not at all)."""
        from ..checks.paths import written_whole

        with written_whole(path, prefix=".fitted-") as fh:
            fh.write(self.scene_text())
        return Path(path)


def _model_params(params: list[FitParameter]) -> list:
    """The model's derivative columns of the fit parameters, each once: ``(name, segment)``,
    gravity ``("gravity", axis)`` -- the pairs both :meth:`~qchain.Chain.parameters` (the
    rest poses' derivatives) and :func:`qchain.sim.sensitivities` take, one column a pair."""
    out = []
    for p in params:
        for c in ([("gravity", p.component)] if p.name == "gravity" else [(p.name, s) for s in p.segments]):
            if c not in out:
                out.append(c)
    return out


def fit(scene, experiments, keys, *, bounds: dict | None = None, loss: str = "linear",
        f_scale: float = 1e-3, reduce: bool = False, max_nfev: int | None = 50, start: str = "rest",
        rtol: float = 1e-7, covariance: str = "inputs", pressure_filter: float | None = None,
        input_draws: int = 40, pressure_sigma=None, values: dict | None = None) -> FitReport:
    """Fit the scene keys ``keys`` to ``experiments``.

    Parameters
    ----------
    scene : path
        The scene file (TOML) whose parameters are fitted; the fit starts from its values.
    experiments : sequence of StaticPoses or Measurements
        Static poses (:mod:`qchain.fit.statics`) and measured motions
        (:mod:`qchain.fit.measurements`, :mod:`qchain.fit.dynamics`), mixed as they come; each
        experiment's pressures must match the arm's chambers, its points lie within the arm's
        reach.
    keys : sequence of str
        Scene keys to fit (:mod:`qchain.fit.parameters`): ``"segments[0].youngs_modulus"``,
        ``"segments[*].mass"``, ``"gravity[2]"``, ...
    bounds : dict, optional
        ``{key: (lower, upper)}`` (SI units).
    loss, f_scale : str, float
        The least-squares loss (``"linear"``, or robust ``"soft_l1"``, ``"huber"``, ...) and
        the residual size (m) where a robust loss starts to down-weight.
    reduce : bool
        The scene's automatic reductions (planar, node counts). Off by default: they are
        decided from the scene's own pressures and state, which the experiments' need not
        share (a planar model cannot follow pressures that differ in chambers 2 and 3).
    max_nfev : int, optional
        Residual evaluations at most.
    start : {"rest", "scene"}
        Where a measured motion starts: at rest under its first pressures (its pose moving with
        the parameters), or at the scene's initial state.
    rtol : float
        The runs' dopri5 tolerance (their steps are held for the exact sensitivities).
    covariance : {"inputs", "iid", "hac"}
        How the standard errors are formed (:func:`qchain.fit.solve.least_squares_fit`).
        ``"inputs"`` (default): the measured pressures are taken as the true ones plus a
        white sensor noise, its level estimated from each recording's pressures themselves
        (:func:`qchain.fit.measurements.pressure_noise`), and its effect on the fitted values
        (an error in the fit's inputs, which least squares does not see in the residuals) is
        propagated through the model at the solution by ``input_draws`` runs under freshly
        drawn noise; the measurement noise is white. Assumes the pressure noise is white (or
        low-passed as ``pressure_filter`` says), independent of the measurement noise, small
        enough for the model's response to it to be near linear. Static poses add draws
        (:func:`qchain.fit.statics.static_input_draws`, the equilibria's exact pressure
        derivative) when ``pressure_sigma`` is given; their held pressures give no estimate.
        ``"iid"``: independent residuals of one standard deviation, the pressures exact.
        ``"hac"``: Newey-West, residuals correlated in time by an unknown law.
    pressure_filter : float, optional, Hz
        Low-pass every measured motion's pressures at this cutoff before fitting
        (:func:`qchain.fit.measurements.filter_pressures`, zero phase); in (0, Nyquist).
    input_draws : int
        The runs that sample the pressure noise's effect for ``covariance="inputs"``: the
        standard errors' own relative error is about ``1 / sqrt(2 input_draws)`` of the part
        the inputs add.
    pressure_sigma : float or (3 n,) float, optional, Pa
        The pressure sensor's noise (standard deviation a sample, a chamber) when known (a
        datasheet); default: estimated from each recording (about 16 % off a chamber from
        100 samples).
    values : dict, optional
        ``{key: value}`` start values of fitted keys instead of the scene's (SI units).
    """
    from ..scene.reading import parse_scene
    import tomli_w

    path = Path(scene)
    try:
        raw = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ValueError(f"scene {path}: cannot be read ({exc})") from None
    experiments = list(experiments)
    if not experiments:
        raise ValueError("experiments: give at least one")
    if covariance not in COVARIANCES:
        raise ValueError(f"covariance must be 'inputs', 'iid' or 'hac', got {covariance!r}")
    if isinstance(input_draws, bool) or not isinstance(input_draws, (int, np.integer)) or input_draws < 2:
        raise ValueError(f"input_draws must be an integer >= 2, got {input_draws!r}")
    for i, e in enumerate(experiments):
        if not isinstance(e, (StaticPoses, Measurements)):
            raise TypeError(f"experiments[{i}] must be StaticPoses or Measurements, got {type(e).__name__}")
    experiments, noise = _pressure_noise(experiments, pressure_sigma, pressure_filter)
    keys = list(keys)
    if values:
        extra = sorted(set(values) - set(keys))
        if extra:
            raise ValueError(f"values: {extra[0]!r} is not one of the fitted keys {keys}")
        raw = apply_values(raw, values)
    params = fit_parameters(raw, keys, bounds)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    start_model = parse_scene(tomli_w.dumps(raw) if values else path.read_text(), path).build(reduce=reduce)
    nodes = [len(s.alpha_nodes) for s in start_model.chain.segments]
    chain0 = start_model.chain
    total = sum(e.n_values for e in experiments)
    if total < 2 * len(params):
        raise MeasurementError(f"{total} measured numbers are too few for {len(params)} parameters: at least "
                               f"{2 * len(params)} are needed")
    for e in experiments:
        e.check_model(chain0)
    pairs = _model_params(params)
    T = column_map(params, pairs)
    experiments, notes = _resolve_coordinates(chain0, experiments)
    if start == "scene":
        q_start, v_start = start_model.q0, start_model.v0
    guesses = [[None] * e.pressures.shape[0] if isinstance(e, StaticPoses) else None for e in experiments]
    state = {"n": 0, "last": None}

    def model_at(x):
        values = scene_values(params, x)
        values.update({f"segments[{i}].nodes": n for i, n in enumerate(_table_nodes(raw, nodes))})
        new = apply_values(raw, values)
        return new, parse_scene(tomli_w.dumps(new), path).build(reduce=reduce).chain

    def evaluate(x, jacobian: bool):
        state["n"] += 1
        new, chain = model_at(x)
        rs, Js = [], []
        for e, g in zip(experiments, guesses):
            if isinstance(e, StaticPoses):
                r, J = static_residuals(chain, e, pairs, g, jacobian=jacobian)
                J = None if J is None else J @ T
            else:
                r, J = dynamic_residuals(chain, e, pairs, T, start=start,
                                         q0=q_start if start == "scene" else None,
                                         v0=v_start if start == "scene" else None, rtol=rtol, jacobian=jacobian)
            rs.append(r)
            Js.append(J)
        state["last"] = (new, rs)
        if state["n"] == 1:  # the solver's first point is the start: its residuals draw the start model
            state["first"] = rs
        return np.concatenate(rs), (np.concatenate(Js) if jacobian else None)

    def fun(x):
        return evaluate(x, True)

    def fun_r(x):
        return evaluate(x, False)[0]

    def draws(x):
        return _input_draws(model_at(x)[1], experiments, noise, input_draws, pressure_filter, start,
                            q_start if start == "scene" else None, v_start if start == "scene" else None, rtol)

    res = least_squares_fit(fun, [p.start for p in params], [p.key for p in params],
                            lower=[p.lower for p in params], upper=[p.upper for p in params], loss=loss,
                            f_scale=f_scale, max_nfev=max_nfev, residuals=fun_r, covariance=covariance,
                            blocks=_residual_blocks(experiments), input_draws=draws)
    fun_r(res.x)  # the report's residuals and scene at the solution
    new, rs = state["last"]
    return FitReport(result=res, parameters=params, experiments=experiments, residuals=rs, raw=new,
                     source=str(path), evaluations=state["n"], start_residuals=state["first"], notes=notes,
                     wall_s=time.perf_counter() - wall0, cpu_s=time.process_time() - cpu0)


def _pressure_noise(experiments: list, pressure_sigma, pressure_filter):
    """Each measured motion's pressure noise (3 n,) Pa (given, or estimated from its pressures
    as recorded, before any filtering; None for static poses) and the experiments with their
    pressures low-passed at ``pressure_filter`` Hz when asked."""
    if pressure_sigma is None:
        noise = [pressure_noise(e.pressures) if isinstance(e, Measurements) else None for e in experiments]
    else:
        ps = np.asarray(pressure_sigma, dtype=float)
        if not (np.all(np.isfinite(ps)) and np.all(ps >= 0) and ps.ndim <= 1):
            raise ValueError(f"pressure_sigma must be finite and >= 0 (Pa, one value or one a chamber), got "
                             f"{pressure_sigma!r}")
        noise = []
        for e in experiments:
            nu = e.pressures.size if isinstance(e, Measurements) else e.pressures.shape[1]
            if ps.size not in (1, nu):
                raise ValueError(f"pressure_sigma must be one value or {nu} (one a chamber), got {ps.size} values")
            noise.append(np.broadcast_to(ps, (nu,)))
    if pressure_filter is not None:
        from dataclasses import replace

        experiments = [replace(e, pressures=filter_pressures(e.pressures, pressure_filter))
                       if isinstance(e, Measurements) else e for e in experiments]
    return experiments, noise


def _resolve_coordinates(chain, experiments: list) -> tuple[list, list]:
    """The measured motions with coordinates given their scale for the start model ``chain``
    (:func:`qchain.fit.measurements.coordinate_scale`: fixed for the whole fit, so that a
    fitted rest length does not reweight its own residuals), and a note for each whose
    coordinates the model holds still (left out)."""
    from dataclasses import replace

    from .measurements import coordinate_scale

    out, notes = [], []
    for i, e in enumerate(experiments):
        if isinstance(e, Measurements) and e.coordinates is not None:
            w, held = coordinate_scale(chain, e)
            if held:
                notes.append(f"experiment {i}: the measured coordinates {', '.join(held)} are held still by the model "
                             "(inextensible or planar) and left out of the fit")
            e = replace(e, coordinate_scale=w)
        out.append(e)
    return out, notes


def _sizes(experiments: list) -> list:
    """Each experiment's ``(K, rows)``: K samples (or poses) of ``rows`` residuals."""
    return [(e.points.shape[0], e.points.size // e.points.shape[0]) if isinstance(e, StaticPoses)
            else (e.n_samples, e.rows) for e in experiments]


def _residual_blocks(experiments: list) -> list:
    """Each experiment's residual rows as ``(start, K, rows)``: K samples (or poses) of ``rows``
    residuals (m points x 3, then a measured motion's used coordinates)."""
    blocks, at = [], 0
    for K, rows in _sizes(experiments):
        blocks.append((at, K, rows))
        at += K * rows
    return blocks


def _input_draws(chain, experiments: list, noise: list, n: int, cutoff, start: str, q0, v0, rtol: float):
    """(n, m): each measured motion's :func:`~qchain.fit.dynamics.input_noise_draws` in its
    rows, each set of static poses' :func:`~qchain.fit.statics.static_input_draws` when
    ``pressure_sigma`` was given (else zeros: their pressures taken as exact)."""
    sizes = [K * rows for K, rows in _sizes(experiments)]
    out = np.zeros((n, sum(sizes)))
    at = 0
    for e, sz, s_p in zip(experiments, sizes, noise):
        if isinstance(e, Measurements):
            out[:, at:at + sz] = input_noise_draws(chain, e, s_p, n, cutoff=cutoff, start=start, q0=q0, v0=v0,
                                                   rtol=rtol)
        elif s_p is not None:  # static poses: only with a given pressure_sigma (one pose a pressure: no estimate)
            out[:, at:at + sz] = static_input_draws(chain, e, s_p, n)
        at += sz
    return out


def _table_nodes(raw: dict, nodes: list[int]) -> list[int]:
    """Each ``[[segments]]`` table's node count (its first segment's) from the expanded list."""
    return [nodes[first] for first, _ in _tables(raw)]
