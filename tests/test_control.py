"""qchain.control: the controllers' input checks and the pressure allocation's bounds."""

import numpy as np
import pytest

from qchain import Chain, Segment
from qchain.control import PDCompensation, SlotineLi, allocate


def _chain():
    seg = Segment(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085,
                  youngs_modulus=1e5, damping=0.02, extensible=False)
    return Chain([seg, seg], gravity=(0.0, 0.0, -9.81))


@pytest.mark.parametrize("kw, words", [
    ({"rate": 0.0}, "rate must be > 0"),
    ({"rate": -5.0}, "rate must be > 0"),
    ({"p_min": 1e5, "p_max": 5e4}, "p_max must be > p_min = 100000 Pa, got 50000 Pa"),
    ({"p_min": -2e5}, "p_min must be >= -101325"),
    ({"rate": float("nan")}, "rate must be finite"),
])
def test_bad_settings_are_refused_naming_the_parameter(kw, words):
    ch = _chain()
    args = {"rate": 500.0, "p_max": 1e5} | kw
    with pytest.raises(ValueError, match=words):
        PDCompensation(ch, ch.neutral(), Kp=1e-3, Kd=1e-4, **args)


def test_a_reference_of_the_wrong_shape_or_with_nan_is_refused():
    ch = _chain()
    with pytest.raises(ValueError, match=r"q_d must have shape \(6,\)"):
        SlotineLi(ch, np.zeros(5), K=1e-4, Lambda=10.0, rate=500.0, p_max=1e5)
    with pytest.raises(ValueError, match="q_d has non-finite entries"):
        SlotineLi(ch, np.full(6, np.nan), K=1e-4, Lambda=10.0, rate=500.0, p_max=1e5)
    with pytest.raises(ValueError, match=r"Lambda\[0\] must be a number > 0"):
        SlotineLi(ch, ch.neutral(), K=1e-4, Lambda=-1.0, rate=500.0, p_max=1e5)


def test_the_allocation_stays_within_bounds_and_realises_a_reachable_force():
    rng = np.random.default_rng(0)
    B = rng.normal(size=(4, 6))
    p_true = rng.uniform(0.0, 1.0, 6)
    a = allocate(B, B @ p_true, 0.0, 1.0, 1e-6)
    assert np.all(a.p >= 0.0) and np.all(a.p <= 1.0)
    assert a.residual < 1e-4 and not a.saturated
    far = allocate(B, 100.0 * B @ p_true, 0.0, 1.0, 1e-6)  # 100 times what the bounds allow
    assert np.all(far.p <= 1.0) and far.saturated and far.at_upper > 0


# -- closed-loop validation on a small arm (2 inextensible segments, short runs)

def _targets(ch):
    """A static target the chambers can hold (the equilibrium under admissible pressures)
    and a start away from it (the equilibrium under half of them)."""
    from qchain.arm.statics import equilibrium

    p_eq = np.array([1e4, 0.0, 0.0, 0.0, 1e4, 0.0])
    return equilibrium(ch, p_eq).q, equilibrium(ch, 0.5 * p_eq).q


def _critical_damping(ch, q, Kp):
    """Kd_i = 2 sqrt(Kp M_ii) on the free coordinates: each coordinate's PD critically damped
    on its own inertia (the couplings aside)."""
    a = np.flatnonzero(ch.active)
    return 2.0 * np.sqrt(Kp * np.diag(ch.mass_matrix(q))[a])


def _controllers(ch, q_d, q0, p_max):
    from qchain.control import TipPD, TipTracking

    x_d = ch.tip_placement(q_d).translation
    x0 = ch.tip_placement(q0).translation
    Kd = _critical_damping(ch, q_d, 1e-3)
    return [
        PDCompensation(ch, q_d, Kp=1e-3, Kd=Kd, rate=500.0, p_max=p_max),
        SlotineLi(ch, q_d, K=Kd, Lambda=10.0, rate=500.0, p_max=p_max),
        TipPD(ch, x_d, Kp=1.0, Kd=0.05, rate=500.0, p_max=p_max),
        TipTracking(ch, lambda t: x0 + (x_d - x0) * t / 0.3, 0.3, q0, K=Kd, Lambda=10.0, rate=500.0, p_max=p_max),
    ]


@pytest.mark.parametrize("which", range(4))
def test_every_controller_keeps_its_pressures_within_bounds_in_closed_loop(which):
    ch = _chain()
    q_d, q0 = _targets(ch)
    ctl = _controllers(ch, q_d, q0, p_max=1e4)[which]  # low enough that the upper bound binds
    ctl.run(q0, np.zeros(ch.nv), 0.3)
    s = ctl.signals()
    assert s["at_upper"].max() > 0  # the bound was reached: the clamp is exercised
    assert s["p"].shape == (len(s["t"]), 6) and len(s["t"]) >= 0.3 * ctl.rate - 1
    assert np.all(np.isfinite(s["p"]))
    assert s["p"].min() >= ctl.p_min and s["p"].max() <= ctl.p_max


def test_pd_compensation_brings_the_arm_to_a_reachable_static_target():
    """The target is qchain.equilibrium's shape under admissible pressures; gravity and
    elasticity compensated at the current q leave no steady-state error (LaSalle)."""
    ch = _chain()
    q_d, q0 = _targets(ch)
    ctl = PDCompensation(ch, q_d, Kp=1e-3, Kd=_critical_damping(ch, q_d, 1e-3), rate=500.0, p_max=5e4)
    tr = ctl.run(q0, np.zeros(ch.nv), 1.0)
    s = ctl.signals()
    assert not s["saturated"].any()
    e0 = np.abs(s["error"][0]).max()
    assert e0 > 0.4  # a real move: ~0.98 on the first segment's curvature coordinate
    a = np.flatnonzero(ch.active)
    assert np.abs(tr.q[-1, a] - q_d[a]).max() < 1e-3 * e0
    assert np.abs(tr.v[-1]).max() < 1e-2


def test_slotine_li_storage_does_not_increase_while_unsaturated():
    """V = 1/2 s^T M s has dV/dt = -s^T (K + D) s in continuous time; sampled and held at
    2 kHz the hold's term s^T (B p_held - tau(t)) is O(h) smaller than the dissipation, so V
    falls at every sample (no tolerance: each step lowers V by >~2 %, far above round-off)."""
    ch = _chain()
    q_d, q0 = _targets(ch)
    ctl = SlotineLi(ch, q_d, K=_critical_damping(ch, q_d, 1e-3), Lambda=10.0, rate=2000.0, p_max=5e4)
    ctl.run(q0, np.zeros(ch.nv), 0.3)
    s = ctl.signals()
    assert not s["saturated"].any()
    V = s["storage"]
    assert V[0] > 0 and np.all(np.diff(V) <= 0.0), np.diff(V).max()
    assert V[-1] < 1e-3 * V[0]


def _operational_inertia(ch, q):
    """The tip's operational-space inertia ``(J M^-1 J^T)^-1`` (3, 3) kg on the free
    coordinates: the mass the tip shows along each direction."""
    a = np.flatnonzero(ch.active)
    M = ch.mass_matrix(q)[np.ix_(a, a)]
    J = ch.tip_jacobian(q, "local_world_aligned")[:3, a]
    return np.linalg.inv(J @ np.linalg.solve(M, J.T))


def test_tip_pd_brings_the_tip_to_a_reachable_static_target():
    """The target is the tip of qchain.equilibrium's shape under admissible pressures. The
    tip's inertia differs by a factor ~27 between directions (0.0087 to 0.24 kg here), so one
    Kd cannot damp all three critically: it is the critical damping of Kp on the geometric mean
    of the extremes (the slowest direction decays at ~2.8 1/s). From 13.5 mm away the tip,
    measured by the forward kinematics of the run's last state, ends within 1 % of it."""
    from qchain.control import TipPD

    ch = _chain()
    q_d, q0 = _targets(ch)
    x_d = ch.tip_placement(q_d).translation
    lam = np.linalg.eigvalsh(_operational_inertia(ch, q_d))
    Kp = 10.0
    ctl = TipPD(ch, x_d, Kp=Kp, Kd=2.0 * np.sqrt(Kp * np.sqrt(lam[0] * lam[-1])), rate=500.0, p_max=5e4)
    tr = ctl.run(q0, np.zeros(ch.nv), 1.5)
    e0 = np.linalg.norm(ch.tip_placement(q0).translation - x_d)
    e1 = np.linalg.norm(ch.tip_placement(tr.q[-1]).translation - x_d)
    s = ctl.signals()
    assert e0 > 0.01  # a real move
    assert e1 < 0.01 * e0, (e0, e1)
    assert np.allclose(s["x"] - s["x_d"], s["error"]) and not s["saturated"][len(s["t"]) // 2:].any()


def test_tip_tracking_error_on_a_reachable_path_falls_to_a_small_bound():
    """A 5 mm circle at 1 Hz in the plane of the tip's two easiest directions (the leading
    singular vectors of its Jacobian) through the tip of a static shape; the arm starts at rest
    13.5 mm off it. Slotine-Li with Lambda = 10 1/s: the error filter ``de/dt = -Lambda e + s``
    and ``s``'s decay bring the tip error down roughly like exp(-10 t) (13.5 mm -> ~12 um at
    0.7 s): measured by forward kinematics of the run's states against the path, it falls
    tenth of a second by tenth of a second and stays below 0.1 mm after 0.7 s."""
    from qchain.control import TipTracking

    ch = _chain()
    q_d, q0 = _targets(ch)
    x_c = ch.tip_placement(q_d).translation
    a = np.flatnonzero(ch.active)
    U = np.linalg.svd(ch.tip_jacobian(q_d, "local_world_aligned")[:3, a])[0]
    R, w = 0.005, 2.0 * np.pi

    def path(t):
        return (x_c + R * ((np.cos(w * t) - 1.0) * U[:, 0] + np.sin(w * t) * U[:, 1]),
                R * w * (-np.sin(w * t) * U[:, 0] + np.cos(w * t) * U[:, 1]))

    ctl = TipTracking(ch, path, 1.0, q_d, K=_critical_damping(ch, q_d, 1e-3), Lambda=10.0, rate=500.0, p_max=5e4)
    tr = ctl.run(q0, np.zeros(ch.nv), 1.0, t_eval=np.linspace(0.0, 1.0, 101))
    tip = np.array([ch.tip_placement(q).translation for q in tr.q])
    err = np.linalg.norm(tip - np.array([path(t)[0] for t in tr.t]), axis=1)
    assert err[0] > 0.01
    assert np.all(np.diff(err[::10]) < 0.0), err[::10]
    assert err[tr.t >= 0.7].max() < 1e-4, err[tr.t >= 0.7].max()


# -- model-predictive control (qchain.control.MPC)

def _mpc(ch, path, **kw):
    from qchain.control import MPC

    return MPC(ch, path, **({"horizon": 5, "rate": 50.0, "p_max": 5e4} | kw))


def test_mpc_horizon_gradient_matches_central_differences_of_the_rolled_out_cost():
    """dJ/dP by the adjoint recursion on the exact linearisation against central differences
    of J computed by rolling out the same discrete dynamics (no derivatives in the rollout)."""
    ch = _chain()
    q_d, q0 = _targets(ch)
    ctl = _mpc(ch, lambda t: ch.tip_placement(q_d).translation + [0.01 * t, 0.0, 0.0])
    P = np.random.default_rng(0).uniform(0.0, 5e4, (5, 6))
    v0 = np.random.default_rng(1).normal(0.0, 1.0, ch.nv) * ch.active
    cost, G = ctl.horizon_gradient(0.1, q0, v0, P)
    G_fd = np.empty_like(P)
    for i, j in np.ndindex(P.shape):
        dP = np.zeros_like(P)
        dP[i, j] = 1.0  # Pa: J is a smooth function of P on the scale of kPa
        G_fd[i, j] = (ctl.horizon_cost(0.1, q0, v0, P + dP) - ctl.horizon_cost(0.1, q0, v0, P - dP)) / 2.0
    assert cost == ctl.horizon_cost(0.1, q0, v0, P) > 0
    assert np.abs(G - G_fd).max() < 1e-6 * np.abs(G_fd).max(), np.abs(G - G_fd).max() / np.abs(G_fd).max()


def test_mpc_step_linearisation_matches_finite_differences():
    """A = ds'/ds and B = ds'/dp of the RK4 interval map against central differences of it."""
    ch = _chain()
    _, q0 = _targets(ch)
    ctl = _mpc(ch, np.zeros(3))
    a = np.flatnonzero(ch.active)
    v0 = np.zeros(ch.nv)
    v0[a] = [0.5, -0.3, 0.2, 0.4]
    p = np.array([1e4, 2e3, 0.0, 5e3, 1.5e4, 3e3])
    _, _, A, B = ctl.step(q0, v0, p, derivatives=True)

    def F(s, p):
        q, v = q0.copy(), np.zeros(ch.nv)
        q[a], v[a] = s[:4], s[4:]
        q1, v1 = ctl.step(q, v, p)
        return np.concatenate([q1[a], v1[a]])

    s = np.concatenate([q0[a], v0[a]])
    A_fd = np.column_stack([(F(s + e, p) - F(s - e, p)) / 2e-6 for e in 1e-6 * np.eye(8)])
    B_fd = np.column_stack([(F(s, p + e) - F(s, p - e)) / 2.0 for e in np.eye(6)])
    assert np.abs(A - A_fd).max() < 1e-7 * np.abs(A).max()
    assert np.abs(B - B_fd).max() < 1e-7 * np.abs(B).max()


def test_mpc_compiled_horizon_passes_equal_the_python_chain_rule():
    """The compiled rollout and linearisation (qchain.sim.engine.horizon: the engine's
    right-hand side and Jacobian, the RK4 map differentiated stage by stage) against the
    Python path (per-stage forward_dynamics / forward_dynamics_derivatives calls, the chain
    rule through the stages in numpy): equal to rounding, interval by interval and over the
    horizon, and the plans of one box-DDP solve agree."""
    ch = _chain()
    q_d, q0 = _targets(ch)
    path = lambda t: ch.tip_placement(q_d).translation + [0.01 * t, 0.0, 0.0]  # noqa: E731
    fast, slow = _mpc(ch, path), _mpc(ch, path, compiled=False)
    assert fast._engine is not None and slow._engine is None
    rng = np.random.default_rng(3)
    v0 = rng.normal(0.0, 1.0, ch.nv) * ch.active
    p = rng.uniform(0.0, 5e4, 6)
    out, ref = fast.step(q0, v0, p, derivatives=True), slow.step(q0, v0, p, derivatives=True)
    for x, r in zip(out, ref):
        assert np.abs(x - r).max() <= 1e-12 * np.abs(r).max(), np.abs(x - r).max() / np.abs(r).max()
    P = rng.uniform(0.0, 5e4, (5, 6))
    (c, G), (c_ref, G_ref) = fast.horizon_gradient(0.1, q0, v0, P), slow.horizon_gradient(0.1, q0, v0, P)
    assert abs(c - c_ref) <= 1e-12 * c_ref
    assert np.abs(G - G_ref).max() <= 1e-12 * np.abs(G_ref).max(), np.abs(G - G_ref).max() / np.abs(G_ref).max()
    fast.torque(0.0, q0, v0)
    slow.torque(0.0, q0, v0)
    assert np.abs(fast.plan - slow.plan).max() <= 1e-6 * fast.p_max, np.abs(fast.plan - slow.plan).max()


def test_mpc_a_plan_that_leaves_the_models_domain_is_refused_naming_the_interval():
    """3 MPa held in one chamber bends the first segment past |kappa| r = 1 within the horizon:
    the compiled rollout stops there with the segment and the interval, never a NaN cost."""
    from qchain.errors import DomainError

    ch = _chain()
    _, q0 = _targets(ch)
    P = np.zeros((5, 6))
    P[:, 0] = 3e6
    for compiled in (True, False):
        with pytest.raises(DomainError, match="segment 0" + (".* in interval [0-4] of the planned" if compiled else "")):
            _mpc(ch, np.zeros(3), compiled=compiled).horizon_cost(0.0, q0, np.zeros(ch.nv), P)


def test_mpc_keeps_its_pressures_within_bounds_in_closed_loop():
    """A target that needs p = 1e4 Pa with p_max = 1e4 Pa: the box binds in the plan."""
    ch = _chain()
    q_d, q0 = _targets(ch)
    ctl = _mpc(ch, ch.tip_placement(q_d).translation, p_max=1e4)
    ctl.run(q0, np.zeros(ch.nv), 0.3, method="rk4", dt=2e-3)
    s = ctl.signals()
    assert len(s["t"]) >= 0.3 * ctl.rate - 1 and s["at_upper"].max() > 0
    assert np.all(np.isfinite(s["p"])) and s["p"].min() >= ctl.p_min and s["p"].max() <= ctl.p_max
    assert ctl.plan.min() >= ctl.p_min and ctl.plan.max() <= ctl.p_max
    assert np.all(s["solve_s"] > 0) and np.all(s["iterations"] >= 1) and ctl.sustainable_rate > 0


def test_mpc_tracks_a_reachable_tip_path_far_better_than_zero_pressure():
    """The path is the tip of the static shapes under pressures that vary at 0.5 Hz (so every
    point is reachable within the bounds), a cubic spline through 17 of them; MPC on the model
    itself from the first shape, against the zero-pressure run from the same start."""
    from scipy.interpolate import CubicSpline

    from qchain import simulate
    from qchain.arm.statics import equilibrium

    ch = _chain()
    w = np.pi

    def pressures(t):
        return np.array([1e4 * (1 + 0.5 * np.sin(w * t)), 0.0, 0.0, 0.0, 1e4, 5e3 * (1 - np.cos(w * t))])

    ts = np.linspace(0.0, 0.8, 17)
    path = CubicSpline(ts, [ch.tip_placement(equilibrium(ch, pressures(t)).q).translation for t in ts], axis=0)
    q0 = equilibrium(ch, pressures(0.0)).q
    T = 0.4
    ctl = _mpc(ch, path, horizon=10)
    ctl.run(q0, np.zeros(ch.nv), T, method="rk4", dt=2e-3)
    s = ctl.signals()
    err = np.linalg.norm(s["error"], axis=1)
    free = simulate(ch, q0, np.zeros(ch.nv), (0.0, T), method="rk4", dt=2e-3, t_eval=s["t"])
    base = np.linalg.norm([ch.tip_placement(q).translation - path(t) for t, q in zip(free.t, free.q)], axis=1)
    assert base.mean() > 0.01  # without pressure the arm falls back: a real baseline
    assert err.mean() < 0.01 * base.mean() and err.max() < 1e-4, (err.mean(), base.mean(), err.max())
    assert s["p"].min() >= 0.0 and s["p"].max() <= 5e4


@pytest.mark.parametrize("kw, error, words", [
    ({"horizon": 0}, ValueError, "horizon must be an integer >= 1 and <= 10000, got 0"),
    ({"horizon": 2.5}, TypeError, "horizon must be an integer"),
    ({"Q": -1.0}, ValueError, "Q must be >= 0 and <= 1e\\+15 1/m\\^2, got -1 1/m\\^2"),
    ({"R": 0.0}, ValueError, "R must be > 0"),
    ({"Q_terminal": float("nan")}, ValueError, "Q_terminal must be finite"),
    ({"Q": 0.0, "Q_terminal": 0.0}, ValueError, "Q and Q_terminal must not both be 0"),
    ({"rate": 0.0}, ValueError, "rate must be > 0"),
    ({"max_iter": 0}, ValueError, "max_iter must be an integer >= 1"),
    ({"max_step": -1e-3}, ValueError, "max_step must be > 0"),
])
def test_mpc_bad_settings_are_refused_naming_the_parameter(kw, error, words):
    with pytest.raises(error, match=words):
        _mpc(_chain(), np.zeros(3), **kw)


def test_tip_inverse_kinematics_reaches_a_far_target_inside_the_model_and_names_an_unreachable_one():
    """From the straight arm to the tip of a strongly bent one (bent 3 and 2 rad): full Newton
    steps leave the model's domain (|kappa| r_s >= 1); halved steps stay inside and reach it
    to 1e-12 m. A target out of reach is a ValueError naming x."""
    from qchain.control.references import tip_inverse_kinematics
    from qchain.errors import DomainError

    ch = _chain()
    q_far = ch.neutral()
    q_far[1::3] = [30.0, -20.0]  # ux (1/m)
    q_far[2::3] = [-8.0, 15.0]
    x = ch.tip_placement(q_far).translation
    idx = np.flatnonzero(ch.active)
    q = ch.neutral()
    with pytest.raises(DomainError):  # what the undamped iteration meets
        for _ in range(50):
            J = ch.tip_jacobian(q, "local_world_aligned")[:3, idx]
            q = q.copy()
            q[idx] += np.linalg.lstsq(J, x - ch.tip_placement(q).translation, rcond=None)[0]
    q = tip_inverse_kinematics(ch, x, ch.neutral())
    assert np.linalg.norm(ch.tip_placement(q).translation - x) < 1e-12
    with pytest.raises(ValueError, match=r"x = \[1\. 0\. 0\.\] m: no configuration reaches it"):
        tip_inverse_kinematics(ch, np.array([1.0, 0.0, 0.0]), ch.neutral())
    with pytest.raises(ValueError, match="x must have shape"):
        tip_inverse_kinematics(ch, np.zeros(2), ch.neutral())


def _tendon_chain():
    """_chain's arm driven by tendons: three at 120 degrees to the first segment's tip and
    three to the arm's tip (a positive span of both segments' bending)."""
    from qchain import Tendon

    seg = Segment(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085,
                  youngs_modulus=1e5, damping=0.02, extensible=False)
    tendons = [Tendon(radius=0.012, angle=a + d, end=end) for end, d in ((0, 0.0), (1, 0.5))
               for a in (0.0, 2 * np.pi / 3, 4 * np.pi / 3)]
    return Chain([seg, seg], gravity=(0.0, 0.0, -9.81), tendons=tendons)


def test_pd_compensation_on_tendons_brings_the_arm_to_a_reachable_target_with_tensions_in_bounds():
    """tension_max: the wanted force realised by tensions in [0, tension_max] through B_T;
    the target is the arm's equilibrium under admissible tensions, reached with no
    steady-state error as with the chambers; the tensions are the controller's output at
    its rate (held), recorded as its "tension" signal and in the run's Trajectory.tension."""
    from qchain.arm.statics import equilibrium

    ch = _tendon_chain()
    T_eq = np.array([1.5, 0.0, 0.0, 0.0, 0.8, 0.0])
    q_d = equilibrium(ch, tension=T_eq).q
    q0 = equilibrium(ch, tension=0.3 * T_eq[::-1]).q
    ctl = PDCompensation(ch, q_d, Kp=1e-3, Kd=_critical_damping(ch, q_d, 1e-3), rate=500.0, tension_max=5.0)
    assert ctl.input == "tension"
    tr = ctl.run(q0, np.zeros(ch.nv), 1.0, t_eval=np.linspace(0.0, 1.0, 11))
    s = ctl.signals()
    assert "p" not in s and s["tension"].shape == (len(s["t"]), 6)
    assert s["tension"].min() >= 0.0 and s["tension"].max() <= 5.0
    assert s["at_upper"][0] > 0 and not s["saturated"][250:].any()  # the bound binds at first, not in the last 0.5 s
    free = ~s["saturated"]
    assert np.abs(s["tau_realised"][free] - s["tau"][free]).max() <= 1e-3 * np.abs(s["tau"][free]).max()
    e0 = np.abs(s["error"][0]).max()
    a = np.flatnonzero(ch.active)
    assert e0 > 0.3 and np.abs(tr.q[-1, a] - q_d[a]).max() < 1e-3 * e0
    assert np.array_equal(tr.tension[-1], s["tension"][-1]) and tr.meta["engine"] == "compiled"
    with pytest.raises(ValueError, match="chain has no tendons"):
        PDCompensation(_chain(), q_d, Kp=1e-3, Kd=1e-3, rate=500.0, tension_max=5.0)
    with pytest.raises(ValueError, match="either p_max .* or tension_max"):
        PDCompensation(ch, q_d, Kp=1e-3, Kd=1e-3, rate=500.0, p_max=5e4, tension_max=5.0)
    with pytest.raises(TypeError, match="p_max is required"):
        PDCompensation(ch, q_d, Kp=1e-3, Kd=1e-3, rate=500.0)
    with pytest.raises(ValueError, match="tension_max must be >= 0"):
        PDCompensation(ch, q_d, Kp=1e-3, Kd=1e-3, rate=500.0, tension_max=-1.0)


def test_mpc_on_tendons_derivatives_paths_and_tracking():
    """MPC planning tensions (tension_max): the horizon gradient against central differences
    of the rolled-out cost, the compiled passes (tensions written into the engine's tendon
    input, da/dT = M^-1 B_T in the linearisation) equal to the Python chain rule, and the
    closed loop bringing the tip to the tip of an equilibrium under admissible tensions with
    every tension in [0, tension_max]."""
    from qchain.arm.statics import equilibrium
    from qchain.control import MPC

    ch = _tendon_chain()
    T_eq = np.array([1.5, 0.0, 0.0, 0.0, 0.8, 0.0])
    q_d = equilibrium(ch, tension=T_eq).q
    x_d = ch.tip_placement(q_d).translation
    q0 = equilibrium(ch, tension=0.3 * T_eq[::-1]).q
    kw = dict(horizon=5, rate=50.0, tension_max=5.0)
    fast, slow = MPC(ch, x_d, **kw), MPC(ch, x_d, compiled=False, **kw)
    assert fast._engine is not None and slow._engine is None and fast.input == "tension"
    rng = np.random.default_rng(4)
    v0 = rng.normal(0.0, 0.5, ch.nv) * ch.active
    P = rng.uniform(0.0, 3.0, (5, 6))
    (c, G), (c_ref, G_ref) = fast.horizon_gradient(0.0, q0, v0, P), slow.horizon_gradient(0.0, q0, v0, P)
    assert abs(c - c_ref) <= 1e-12 * c_ref
    assert np.abs(G - G_ref).max() <= 1e-11 * np.abs(G_ref).max(), np.abs(G - G_ref).max() / np.abs(G_ref).max()
    G_fd = np.empty_like(P)
    for i, j in np.ndindex(P.shape):
        dP = np.zeros_like(P)
        dP[i, j] = 1e-4  # N
        G_fd[i, j] = (fast.horizon_cost(0.0, q0, v0, P + dP) - fast.horizon_cost(0.0, q0, v0, P - dP)) / 2e-4
    assert np.abs(G - G_fd).max() < 1e-6 * np.abs(G_fd).max(), np.abs(G - G_fd).max() / np.abs(G_fd).max()
    out, ref = fast.step(q0, v0, P[0], derivatives=True), slow.step(q0, v0, P[0], derivatives=True)
    for x, r in zip(out, ref):
        assert np.abs(x - r).max() <= 1e-12 * np.abs(r).max(), np.abs(x - r).max() / np.abs(r).max()
    with pytest.raises(ValueError, match=r"R must be >= 0 and <= 1e\+09 1/N\^2, got -1"):
        MPC(ch, x_d, R=-1.0, **kw)
    with pytest.raises(ValueError, match=r"P must have shape \(5, 6\) \(horizon, nt\)"):
        fast.horizon_cost(0.0, q0, v0, np.zeros((5, 12)))

    tr = fast.run(q0, np.zeros(ch.nv), 1.0, t_eval=np.linspace(0.0, 1.0, 11))
    s = fast.signals()
    assert "p" not in s and s["tension"].shape == (len(s["t"]), 6) and tr.meta["engine"] == "compiled"
    assert s["tension"].min() >= 0.0 and s["tension"].max() <= 5.0 and fast.plan.min() >= 0.0
    err = np.linalg.norm(s["error"], axis=1)
    assert err[0] > 0.02 and err[-10:].max() < 1e-3 * err[0], (err[0], err[-10:].max())
    np.testing.assert_array_equal(tr.tension[-1], s["tension"][-1])
