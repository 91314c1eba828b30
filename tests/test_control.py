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
