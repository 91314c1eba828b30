"""Trajectory sensitivities: the exact derivative of a simulated run with respect to its
initial state and the model's parameters (forward sensitivities on the compiled engine).

:func:`sensitivities` integrates the state with an explicit Runge-Kutta method of the engine
(``rk4`` at a fixed ``dt``, or ``dopri5`` along the steps its own adaptive run takes) and,
alongside, ``S = d(q, v)/d(columns)`` by differentiating the discrete Runge-Kutta map with the
step sizes frozen (:mod:`qchain.sim.engine.sensitivity`): the result is the derivative of the
numbers the integrator returns, exact to rounding, not of the ODE's solution (they differ by
the method's error), which is what a least-squares fit needs to converge cleanly (a
Jacobian consistent with the residuals it differentiates). The step sizes an adaptive run
chose are held fixed: they are piecewise constant in the parameters.

Why forward and not an adjoint: a fit needs the Jacobian of many residuals (every sample,
every measured coordinate) with respect to few parameters (1-20): forward sensitivities give
all of it in one run, at a cost that grows slowly with the number of columns (the exact
Jacobian ``f_y`` is formed once a stage whatever the number of columns, docs/sensitivity.md,
"Cost"). An adjoint costs one backward run per output, so it pays only for few outputs
(one scalar loss) and many parameters; see docs/sensitivity.md.

docs/sensitivity.md gives the equations, the columns, what is supported and the measured cost.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field

import numpy as np

from ..arm.chain import Chain
from ..checks.convert import as_real_array, describe_value
from .._jit import first_class_functions
from ..algorithms import parameter_derivatives as pd
from .engine import sensitivity as es
from .engine import packing, system, tableaus, warmup
from .budget import Budget, Cost, as_budget
from .inputs import Schedule, as_input
from .simulation import _check_env, _check_start, _check_t_eval, check_run, check_settings, simulate

__all__ = ["sensitivities", "SensitivityResult", "tip_sensitivities", "PARAMETERS"]

#: the parameters with derivative columns: name -> (kind code of the parameter derivatives, unit);
#: per segment (``(name, segment)``) except gravity (``("gravity", axis)``, axis 0-2: x, y, z, or
#: ``("gravity", None)``: the three axes; the pairs of :class:`qchain.arm.parameter_derivatives.Parameters`)
PARAMETERS = {"youngs_modulus": (pd.KIND_YOUNGS, "Pa"), "damping": (pd.KIND_DAMPING, "s"),
              "mass": (pd.KIND_MASS, "kg"), "length": (pd.KIND_LENGTH, "m"), "chamber_area": (pd.KIND_AREA, "m^2"),
              "gravity": (pd.KIND_GRAVITY, "m/s^2")}
METHODS = ("rk4", "dopri5")
#: seconds a cold compile of the sensitivity engine takes on an idle 2-core machine, the
#: Jacobian in a worker meanwhile: the parts of radau5's engine (24 s idle, docs/engine.md) with
#: the loop in place of its stepper; measured 128 s on the 2-core machine at a load average of 9-16
#: (230 s with every part compiled in one process)
COMPILE_S = 30


@dataclass
class SensitivityResult:
    """A run with its sensitivities (:func:`sensitivities`), scipy style.

    Attributes
    ----------
    t : (K,) s
        The sample times.
    q, v : (K, nq), (K, nv)
        The state at the samples (the same numbers as :func:`qchain.simulate`'s run with the
        same method and steps).
    S : (K, 2 nv, ncol)
        ``d(q, v)/d(column)`` at the samples: rows ``0..nv-1`` the configuration in the tangent
        space (``dq`` in velocity coordinates, m and 1/m), rows ``nv..2 nv - 1`` the velocity;
        locked coordinates have zero rows.
    columns : list of str
        What each column is the derivative with respect to: ``"q0[i]"``, ``"v0[i]"`` (the free
        coordinates ``i`` of the initial state) and ``"name[j]"`` for a parameter (:data:`PARAMETERS`).
    steps : (M + 1,) s
        The step ends the run took (frozen: the derivative holds them fixed).
    success, message, status : bool, str, int
        Whether the run reached the span's end (``status`` 0) or why not (``-1``); a failed
        run keeps the samples before the failure.
    nfev, njev, nsteps : int
        Right-hand sides and exact Jacobians evaluated in the sensitivity pass, its steps;
        ``meta["grid_nfev"]`` the adaptive run that chose the steps (dopri5 without ``steps``).
    method : str
    meta : dict
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    S: np.ndarray
    columns: list
    steps: np.ndarray
    success: bool
    message: str
    status: int
    nfev: int
    njev: int
    nsteps: int
    method: str
    meta: dict = field(default_factory=dict)


def _columns(chain: Chain, initial, params) -> tuple[list[str], np.ndarray, np.ndarray]:
    """The column names and the parameters' ``kinds``, ``index`` (int64), checked where they enter."""
    idx = np.flatnonzero(chain.active)
    every = [f"q0[{i}]" for i in idx] + [f"v0[{i}]" for i in idx]
    if isinstance(initial, (bool, np.bool_)):
        names = every if initial else []
    elif isinstance(initial, (list, tuple)):
        names = list(initial)
        for k, name in enumerate(names):
            if name not in every:
                raise ValueError(f"initial[{k}] must name a free coordinate of the initial state, one of "
                                 f"{every}, got {describe_value(name)}")
        if len(set(names)) != len(names):
            raise ValueError(f"initial names a column twice: {names}")
    else:
        raise TypeError(f"initial must be True, False or a list of names such as 'q0[1]', 'v0[4]', got "
                        f"{describe_value(initial)}")
    if isinstance(params, (str, bytes)) or not isinstance(params, (list, tuple)):
        raise TypeError(f"params must be a list of (name, segment) pairs, e.g. [('chamber_area', 0)], got "
                        f"{describe_value(params)}")
    kinds, index = [], []
    expanded = []  # ("gravity", None): its three axes, as qchain.arm.parameter_derivatives.Parameters reads it
    for k, item in enumerate(params):
        if not (isinstance(item, (list, tuple)) and len(item) == 2 and isinstance(item[0], str)):
            raise TypeError(f"params[{k}] must be a (name, segment) pair, got {describe_value(item)}")
        if item[0] == "gravity" and item[1] is None:
            expanded += [(k, ("gravity", a)) for a in range(3)]
        else:
            expanded.append((k, tuple(item)))
    done = []
    for k, item in expanded:
        name, j = item
        if name not in PARAMETERS:
            raise ValueError(f"params[{k}]: unknown parameter {name!r}; the parameters are {tuple(PARAMETERS)}")
        hi = 2 if name == "gravity" else chain.n - 1
        what = "axis (0, 1, 2: x, y, z)" if name == "gravity" else "segment"
        if isinstance(j, (bool, np.bool_)) or not isinstance(j, (int, np.integer)) or not 0 <= j <= hi:
            raise ValueError(f"params[{k}]: the {what} of {name!r} must be an integer in [0, {hi}], got "
                             f"{describe_value(j)}")
        if name == "length" and chain._locked[int(j), 0]:
            raise ValueError(f"params[{k}]: segment {int(j)} is inextensible: its length is held at q0's, not a "
                             "parameter of the run")
        if (name, int(j)) in done:
            raise ValueError(f"params[{k}]: ({name!r}, {int(j)}) is asked twice")
        done.append((name, int(j)))
        kinds.append(PARAMETERS[name][0])
        index.append(int(j))
        names.append(f"{name}[{int(j)}]")
    if not names:
        raise ValueError("nothing to differentiate: initial=False and no params")
    return names, np.array(kinds, dtype=np.int64), np.array(index, dtype=np.int64)


def _fixed_grid(t0: float, t1: float, dt: float) -> np.ndarray:
    """The fixed-step methods' step ends ``t0 + k dt`` cut at ``t1``, computed as the engine's
    ``_fixed_next`` does (the same floating-point operations, so the same steps)."""
    ts = [t0]
    t = t0
    while t < t1:
        k = np.floor((t - t0) / dt + 1e-9) + 1.0
        t_new = t0 + k * dt
        if t_new - t < 1e-9 * dt:
            t_new += dt
        t = min(t_new, t1)
        ts.append(t)
    return np.array(ts)


def _check_steps(steps, t0: float, t1: float) -> np.ndarray:
    g = as_real_array("steps", steps)
    if g.ndim != 1 or g.size < 2:
        raise ValueError(f"steps must be a 1-D array of step ends from t0 to t1 (at least 2 times), got shape {g.shape}")
    if not np.all(np.isfinite(g)):
        raise ValueError(f"steps[{int(np.flatnonzero(~np.isfinite(g))[0])}] must be finite")
    if g[0] != t0 or g[-1] != t1:
        raise ValueError(f"steps must start at t0 = {t0!r} s and end at t1 = {t1!r} s, got {g[0]!r} to {g[-1]!r} s")
    if np.any(np.diff(g) <= 0):
        k = int(np.flatnonzero(np.diff(g) <= 0)[0])
        raise ValueError(f"steps must be strictly increasing: steps[{k + 1}] = {g[k + 1]!r} s <= steps[{k}] = {g[k]!r} s")
    return g


def sensitivities(chain: Chain, q0, v0, t_span, *, params=(), initial: bool = True, method: str = "dopri5",
                  dt: float | None = None, rtol: float = 1e-6, atol: float = 1e-8, steps=None, t_eval=None,
                  pressure=None, tau=None, env=None, max_step: float = np.inf,
                  first_step: float | None = None, budget: Budget | None = None, tension=None) -> SensitivityResult:
    """A run of ``chain`` from ``(q0, v0)`` over ``t_span`` and the exact derivative of its
    samples with respect to the initial state and ``params``.

    Parameters
    ----------
    chain : Chain
        Fixed or prescribed base, curvature coordinates, the material law (what the compiled
        engine runs); a floating base is refused (its chart's Lie terms are not differentiated yet).
    q0 : (nq,), v0 : (nv,)
    t_span : (t0, t1) s
    params : list of (name, segment)
        The parameters to differentiate with respect to (:data:`PARAMETERS`): segment ``j``'s
        ``"youngs_modulus"`` (Pa), ``"damping"`` (s), ``"mass"`` (kg), ``"length"`` (rest
        length, m), ``"chamber_area"`` (m^2), or ``("gravity", axis)`` (m/s^2; ``("gravity", None)``: the
        three axes, as :meth:`~qchain.Chain.parameters` reads it).
    initial : bool or list of str
        True: the columns of the initial state's free coordinates (``q0[i]`` in the tangent
        space, then ``v0[i]``, ``i`` in ``flatnonzero(chain.active)``); or a list of those names.
    method : ``"dopri5"`` (adaptive: its steps are those of :func:`qchain.simulate`'s own
        dopri5 run at ``rtol``, ``atol``, ``max_step``, ``first_step``, then frozen) or ``"rk4"``
        (``dt``).
    steps : (M + 1,) s, optional
        The step ends to take, from ``t0`` to ``t1`` (for either method; then no adaptive run).
    t_eval : (K,) s, optional
        Sample times (the method's dense output, and its derivative); default every step end.
    pressure, tau, env, tension
        As :func:`qchain.simulate`'s (compiled inputs: constants or schedules; ``tension`` for
        a chain with tendons, docs/tendons.md).
    budget : qchain.sim.budget.Budget, optional
        What the run may cost: its steps, samples and the memory of the samples'
        sensitivities (K x 2 nA x ncol floats) are checked before it starts.

    Returns
    -------
    SensitivityResult
        ``t``, ``q``, ``v``, ``S`` (K, 2 nv, ncol) with ``columns``; counters. See
        :func:`tip_sensitivities` for the tip position's derivative.
    """
    t0, t1 = check_run(chain, "dopri5", t_span)
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS} (explicit methods of the compiled engine), got "
                         f"{describe_value(method)}")
    if chain.base == "floating":
        raise ValueError("sensitivities: a floating base is not supported (the exact derivative of the base's chart "
                         "map is not written yet); use a fixed or prescribed base")
    q0, v0 = _check_start(chain, q0, v0, t0)
    cfg = check_settings(chain, t0, t1, method=method if steps is None else "dopri5", dt=dt, rtol=rtol, atol=atol,
                         max_step=max_step, first_step=first_step, wall_limit=None, t_eval=t_eval, energies=False,
                         progress=False, on_sample=None, events=None, controller_rate=None)
    env = _check_env(chain, env)
    columns, kinds, index = _columns(chain, initial, params)
    if len(kinds) and chain._literal.any():
        j = int(np.flatnonzero(chain._literal)[0])
        raise ValueError(f"params: parameter derivatives need the material law in every segment; segments[{j}] has "
                         "the paper's literal linear law (stiffness_matrix or damping_matrix)")
    if len(kinds) and chain._has_drag and np.any(kinds == pd.KIND_LENGTH) and chain._any_locked:
        raise ValueError("params: a rest length's derivative with drag on an inextensible segment is not supported "
                         "(the held length moves the drag)")
    if env is not None and np.any(kinds == pd.KIND_LENGTH):
        raise ValueError("params: a rest length's derivative with env is not supported (the contact nodes move along "
                         "the segment with it)")
    if tension is not None and not chain.nt:
        raise ValueError("tension is given but the chain has no tendons (Chain(..., tendons=[...]))")
    if tension is not None and np.any(kinds == pd.KIND_LENGTH) and any(td.pitch is not None for td in chain.tendons):
        raise ValueError("params: a rest length's derivative with a helical tendon's tension is not supported (the "
                         "helix turns with the rest length)")
    for name, u, size in (("pressure", pressure, chain.nu), ("tau", tau, chain.nv), ("tension", tension, chain.nt)):
        as_input(name, u, size)  # checked where it enters
        if callable(u) and not isinstance(u, Schedule):
            raise ValueError(f"{name}: a controller (t, q, v) -> array has no compiled sensitivities; pass a "
                             f"constant or a schedule of qchain.sim.inputs")
    m = packing.pack(chain, pressure, tau, env, tension)
    if m is None:
        raise ValueError(f"sensitivities need the compiled engine, which cannot serve this run: "
                         f"{packing.python_reason(chain, pressure, tau, tension)}")
    meta = {}
    budget = as_budget(budget)
    if steps is not None:
        grid = _check_steps(steps, t0, t1)
    elif method == "rk4":
        n_steps = np.ceil((t1 - t0) / cfg["dt"])
        budget.check(Cost(steps=n_steps, steps_why=f"duration / dt = {t1 - t0:g} s / {cfg['dt']:g} s", samples=0,
                          samples_why="", memory=0.0, memory_why=""))
        grid = _fixed_grid(t0, t1, cfg["dt"])
    else:
        plain = simulate(chain, q0, v0, (t0, t1), method="dopri5", rtol=cfg["rtol"], atol=cfg["atol"],
                         max_step=cfg["max_step"], first_step=cfg["first_step"], pressure=pressure, tau=tau, env=env,
                         energies=False, tension=tension)
        if not plain.success:
            raise ValueError(f"the dopri5 run that chooses the steps failed: {plain.message}")
        grid = np.array(plain.t, dtype=float)
        meta["grid_nfev"] = int(plain.nfev)
    t_out = grid.copy() if cfg["t_eval"] is None else np.array(cfg["t_eval"], dtype=float)
    nA, ncol = int(np.count_nonzero(chain.active)), len(columns)
    budget.check(Cost(steps=grid.size - 1, steps_why="the steps to take", samples=t_out.size,
                      samples_why="t_eval" if cfg["t_eval"] is not None else "a sample every step",
                      memory=8.0 * t_out.size * (chain.nq + chain.nv + 2 * nA * ncol + 2 * chain.nv * ncol),
                      memory_why=f"{t_out.size} samples of the state and of {ncol} sensitivity columns"))
    return _run(chain, m, method, q0, v0, grid, t_out, columns, kinds, index, meta)


def _run(chain, m, method, q0, v0, grid, t_out, columns, kinds, index, meta) -> SensitivityResult:
    idx = m.idx
    nA = idx.size
    N = 2 * nA
    ncol = len(columns)
    P = kinds.size
    wk = system.workspace(chain, m)
    wk.q_chart[:] = q0
    y = np.zeros(N)
    y[nA:] = v0[idx]
    S = np.zeros((N, ncol))
    for c, name in enumerate(columns[: ncol - P]):  # the initial state's columns: unit vectors
        i = int(np.flatnonzero(idx == int(name[3:-1]))[0])
        S[i if name.startswith("q0") else nA + i, c] = 1.0
    K = np.zeros((11, N))
    dK = np.zeros((11, N, ncol))
    Jq, Jv = np.zeros((nA, nA)), np.zeros((nA, nA))
    da = np.zeros((chain.nv, P))
    nt = t_out.size
    Qo, Vo, So = np.zeros((nt, chain.nq)), np.zeros((nt, chain.nv)), np.zeros((nt, N, ncol))
    cnt = np.zeros(8, dtype=np.int64)
    if method == "dopri5":
        A, C, Pd = tableaus.DOPRI5_A.copy(), tableaus.DOPRI5_C.copy(), tableaus.DOPRI5_P.copy()
    else:
        A, C, Pd = np.zeros((7, 7)), np.zeros(7), np.zeros((7, 4))
    if P == 0:
        param_kernel, pbuf = es.no_parameters, np.zeros(1)
    elif np.all(kinds == pd.KIND_AREA):  # the input gain alone: from the Jacobian's da/dp
        param_kernel, pbuf = es.chamber_area_derivatives, np.zeros(1)
    else:
        param_kernel, pbuf = es.model_parameter_derivatives, np.zeros(es.parameter_buffer_size(chain.n, chain.nv, P))
        pbuf[: chain.n] = [s.youngs_modulus for s in chain.segments]
    fs = _callbacks(m, wk, y, K[0], Jq, Jv, param_kernel, (kinds, index, pbuf, da))
    code = es.RK4 if method == "rk4" else es.DOPRI5
    with first_class_functions():
        status = es.advance_sensitivities(fs, m, wk, code, A, C, Pd, grid, y, S, K, dK, np.zeros(N),
                                          np.zeros((N, ncol)), np.zeros(N), np.zeros((N, ncol)), Jq, Jv, da, kinds,
                                          index, pbuf, t_out, Qo, Vo, So, cnt)
    k = int(cnt[es.K_OUT])
    if status == system.OK:
        message = "The solver successfully reached the end of the integration interval."
    else:
        step = int(cnt[es.T_FAIL_STEP])
        why = {system.DOMAIN: f"segment {int(wk.info[1])} left the model's domain (|kappa| r >= 1 or l <= 0)",
               system.SINGULAR: "an articulated inertia was not positive definite",
               system.NONFINITE: "a non-finite value (state or sensitivity)"}.get(int(status), f"status {int(status)}")
        message = f"{why} in the step from {grid[step]:.9g} s to {grid[step + 1]:.9g} s"
    Sfull = np.zeros((k, 2 * chain.nv, ncol))
    Sfull[:, idx] = So[:k, :nA]
    Sfull[:, chain.nv + idx] = So[:k, nA:]
    return SensitivityResult(t=t_out[:k].copy(), q=Qo[:k], v=Vo[:k], S=Sfull, columns=columns, steps=grid,
                             success=status == system.OK, message=message, status=0 if status == system.OK else -1,
                             nfev=int(cnt[es.NFEV]), njev=int(cnt[es.NJEV]), nsteps=int(cnt[es.NSTEPS]),
                             method=method, meta=meta)


def _callbacks(m, wk, y, f, Jq, Jv, param_kernel, param_args) -> tuple:
    """The compiled loop's callbacks (right-hand side, Jacobian, parameter kernel), loaded from
    the cache or compiled. Cold, it says so once on stderr, and the Jacobian (the largest part)
    is compiled in a worker process (:mod:`qchain.sim.engine.warmup`'s) while this one
    compiles the rest."""
    rhs = system.rhs(m)
    cold = [k.__name__ for k, args in ((rhs, (f,)), (system.jacobian, (Jq, Jv)), (param_kernel, param_args))
            if k.is_cached(m, wk, 0.0, y, *args) is False]
    if not es.advance_sensitivities.overloads and warmup.is_cached(es.advance_sensitivities) is False:
        cold.append("advance_sensitivities")
    if cold:
        print(f"qchain: compiling the sensitivity engine for this machine ({', '.join(cold)}): about "
              f"{COMPILE_S} s on 2 cores, once after install or an update (cached for later runs)", file=sys.stderr,
              flush=True)
    if "jacobian" in cold and warmup._parallel():
        warmup._spawn(["jacobian"], "radau5", bool(m.planar_kernel == 1))
    out_rhs = rhs.compile(m, wk, 0.0, y, f)
    out_param = param_kernel.compile(m, wk, 0.0, y, *param_args)
    if "jacobian" in cold:
        warmup._wait()  # then loaded from the cache (or compiled here if the worker failed)
    return out_rhs, system.jacobian.compile(m, wk, 0.0, y, Jq, Jv), out_param


def tip_sensitivities(chain: Chain, result: SensitivityResult, segment: int | None = None,
                      alpha: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The world position of the tip (or of the backbone point at ``alpha`` in [0, 1] of
    ``segment``) along ``result`` and its derivative: ``p (K, 3)`` (m) and ``dp (K, 3, ncol)``
    = ``J(q) dq/d(column)``, with ``J`` the linear rows of the point's exact frame Jacobian in
    world axes (as :meth:`qchain.Chain.tip_jacobian` with ``"local_world_aligned"``: the root
    maps of the segments before, then the slice's map at ``alpha``)."""
    if not isinstance(result, SensitivityResult):
        raise TypeError(f"result must be a SensitivityResult, got {type(result).__name__}")
    if result.q.shape[1:] != (chain.nq,):
        raise ValueError(f"result is for nq = {result.q.shape[1]}, the chain has nq = {chain.nq}")
    seg = chain.n - 1 if segment is None else segment
    if isinstance(seg, (bool, np.bool_)) or not isinstance(seg, (int, np.integer)) or not 0 <= seg < chain.n:
        raise ValueError(f"segment must be an integer in [0, {chain.n - 1}], got {describe_value(segment)}")
    a = float(alpha) if isinstance(alpha, (int, float, np.integer, np.floating)) else np.nan
    if not 0.0 <= a <= 1.0:
        raise ValueError(f"alpha must be a number in [0, 1], got {describe_value(alpha)}")
    K = result.t.size
    p = np.zeros((K, 3))
    dp = np.zeros((K, 3, result.S.shape[2]))
    for k in range(K):
        t = float(result.t[k])
        p[k] = chain.points(result.q[k], [(seg, a)], t)[0]
        dp[k] = chain.point_jacobian(result.q[k], seg, a, t) @ result.S[k, : chain.nv]
    return p, dp
