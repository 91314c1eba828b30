"""Integrators: convergence orders, long-run energy behaviour, Lie-group base, clean stops."""

import re

import numpy as np
import pinocchio as pin
import pytest

from qchain import Chain, Segment
from qchain.sim.inputs import Ramp, Sine, Step, Table
from qchain.sim.simulation import METHODS, Event, simulate

SEG = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5)


def hanging_arm(n=3, damping=0.01, **kw):
    return Chain([Segment(**SEG, damping=damping) for _ in range(n)], gravity=(0, 0, 9.81), **kw)


def waving(ch):
    return Sine(amplitude=np.full(ch.nu, 2e4), frequency=2.0, phase=np.tile([0.0, 2.1, 4.2], ch.n),
                offset=np.full(ch.nu, 2e4))


def tip(ch, q):
    return ch.tip_placement(q).translation


def test_fixed_step_methods_converge_at_their_order():
    ch = hanging_arm(2)
    P = waving(ch)
    T = 0.1
    ref = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, T), pressure=P, method="DOP853", rtol=1e-12,
                   atol=1e-14, energies=False)
    assert ref.success
    x_ref = tip(ch, ref.q[-1])
    for method, order, dts in [("rk4", 4, [2e-3, 1e-3, 5e-4]), ("midpoint", 2, [2e-3, 1e-3, 5e-4])]:
        errs = []
        for dt in dts:
            tr = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, T), pressure=P, method=method, dt=dt, energies=False)
            assert tr.success, tr.message
            errs.append(np.linalg.norm(tip(ch, tr.q[-1]) - x_ref))
        rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
        assert np.all(rates > order - 0.3), (method, errs, rates)


@pytest.mark.parametrize("method", ["RK45", "DOP853", "Radau", "BDF"])
def test_adaptive_methods_meet_their_tolerance(method):
    ch = hanging_arm(2)
    P = waving(ch)
    T = 0.1
    ref = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, T), pressure=P, method="DOP853", rtol=1e-12,
                   atol=1e-14, energies=False)
    errs = []
    for rtol in [1e-5, 1e-8]:
        tr = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, T), pressure=P, method=method, rtol=rtol,
                      atol=rtol * 1e-2, energies=False)
        assert tr.success and tr.nfev > 0
        errs.append(np.linalg.norm(tip(ch, tr.q[-1]) - tip(ch, ref.q[-1])))
    assert errs[1] < errs[0] / 20  # tighter tolerance, smaller error
    assert errs[1] < 1e-6  # m


def test_midpoint_keeps_energy_bounded_where_rk4_drifts():
    """100 s undamped, unforced: at the same step the symmetric implicit midpoint rule keeps
    the energy error bounded; classical RK4 loses most of the energy."""
    ch = Chain([Segment(**SEG)], gravity=(0, 0, 9.81))
    q0 = ch.neutral()
    q0[1:] = [8.0, -3.0]
    v0 = np.array([0.0, 0.0, 3.0])
    t_eval = np.linspace(0, 100, 201)
    out = {}
    for method in ("midpoint", "rk4"):
        tr = simulate(ch, q0, v0, (0, 100), method=method, dt=1e-2, t_eval=t_eval)
        assert tr.success, tr.message
        E = tr.total_energy
        out[method] = np.abs(E - E[0]) / abs(E[0])
    mid = out["midpoint"]
    assert mid.max() < 5e-3
    assert mid[100:].max() <= 1.5 * mid[:101].max()  # no growth in the second half
    assert out["rk4"][-1] > 10 * mid.max()
    assert np.all(np.diff(out["rk4"][::20]) > 0)  # a steady drift


def test_floating_base_stays_on_the_lie_group_and_keeps_momentum():
    ch = Chain([Segment(**SEG) for _ in range(2)], base="floating", gravity=np.zeros(3))
    q0 = ch.neutral()
    q0[7:] = [0.1, 5.0, -2.0, 0.1, -4.0, 3.0]
    v0 = np.zeros(ch.nv)
    v0[:6] = [0.1, -0.2, 0.05, 8.0, -5.0, 6.0]  # tumbling fast: several turns
    P = waving(ch)
    tr = simulate(ch, q0, v0, (0, 1.0), pressure=P, method="DOP853", rtol=1e-10, atol=1e-12, energies=False)
    assert tr.success, tr.message
    assert np.allclose(np.linalg.norm(tr.q[:, 3:7], axis=1), 1.0, atol=1e-12)
    R = pin.XYZQUATToSE3(tr.q[-1, :7]).rotation
    assert np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))) > 30  # it did turn
    h0 = ch.momentum(tr.q[0], tr.v[0])
    for k in range(0, len(tr.t), max(1, len(tr.t) // 10)):
        assert np.linalg.norm(ch.momentum(tr.q[k], tr.v[k]) - h0) < 1e-7 * np.linalg.norm(h0)
    # fixed-step methods: the momentum error is their truncation error, falling at their order
    # (measured: rk4 3.1e-7, 1.8e-8; midpoint 7.3e-5, 1.8e-5 at dt = 0.4, 0.2 ms)
    for method, order in (("rk4", 4), ("midpoint", 2)):
        errs = []
        for dt in (4e-4, 2e-4):
            tf = simulate(ch, q0, v0, (0, 0.2), pressure=P, method=method, dt=dt, energies=False)
            assert tf.success
            assert np.allclose(np.linalg.norm(tf.q[:, 3:7], axis=1), 1.0, atol=1e-12)
            errs.append(np.linalg.norm(ch.momentum(tf.q[-1], tf.v[-1]) - h0) / np.linalg.norm(h0))
        assert errs[1] < 1e-4
        assert np.log2(errs[0] / errs[1]) > order - 0.3


@pytest.mark.parametrize("method, kw", [("RK45", {}), ("rk4", dict(dt=2e-4)), ("midpoint", dict(dt=1e-3)),
                                        ("BDF", {})])
def test_domain_exit_stops_cleanly_with_the_trajectory_kept(method, kw):
    """A pressure ramp drives |kappa| r_s toward 1: the run stops with a clear domain error."""
    ch = Chain([Segment(**SEG, damping=0.05)], gravity=np.zeros(3))
    P = Ramp(0.0, 1.0, end=[3e6, 0.0, 0.0])
    tr = simulate(ch, ch.neutral(), np.zeros(3), (0, 1.0), pressure=P, method=method, **kw)
    assert not tr.success and tr.status == -1
    assert "segment 0" in tr.message and "kappa" in tr.message and "t = " in tr.message
    assert len(tr.t) > 10 and np.all(np.isfinite(tr.q)) and tr.t[-1] < 1.0
    kappa_rs = np.hypot(tr.q[-1, 1], tr.q[-1, 2]) * SEG["radius"]
    assert 0.5 < kappa_rs < 1.0  # stopped on the way to the boundary, last sample valid


def test_non_finite_state_stops_cleanly():
    ch = Chain([Segment(**SEG)], gravity=np.zeros(3))
    tau = Step(0.05, after=[0.0, 1e15, 0.0])  # within the force range; the state blows up
    tr = simulate(ch, ch.neutral(), np.zeros(3), (0, 0.1), tau=tau, method="rk4", dt=1e-3)
    assert not tr.success
    assert ("non-finite" in tr.message) or ("segment 0" in tr.message)
    assert tr.t[-1] < 0.06 and np.all(np.isfinite(tr.q))


def test_inputs_events_samples_and_progress(capsys):
    ch = hanging_arm(1)
    calls = []
    table = Table([0.0, 0.1, 0.2], [[0, 0, 0], [3e4, 0, 0], [0, 3e4, 0]])
    ev = Event(lambda t, q, v: q[1] + 1.0, terminal=True, direction=-1, name="ux=-1")
    tr = simulate(ch, ch.neutral(), np.zeros(3), (0, 0.4), pressure=table, method="RK45",
                  t_eval=np.linspace(0, 0.4, 41), events=[ev], on_sample=lambda t, q, v, p: calls.append(t),
                  progress=True)
    assert tr.status == 1 and tr.success
    (name, te), = tr.meta["events"]
    assert name == "ux=-1" and 0.05 < te < 0.4
    assert tr.t[-1] <= te + 1e-12 and len(calls) == len(tr.t)
    assert np.allclose(tr.p[tr.t <= 0.1, 0], 3e5 * tr.t[tr.t <= 0.1])
    # a controller (t, q, v) -> p
    tr2 = simulate(ch, ch.neutral(), np.zeros(3), (0, 0.05), pressure=lambda t, q, v: [1e4 * (1 - q[1]), 0, 0],
                   method="rk4", dt=1e-3)
    assert tr2.success and tr2.p[-1, 0] > 1e4


@pytest.mark.parametrize("method", ["radau5", "RK45"])
def test_progress_lines_for_a_log_say_how_far_and_how_long(method, capsys, monkeypatch):
    """progress="lines" (qchain run's default off a terminal): plain lines, no carriage
    returns, each with the time reached, the fraction, the wall time and the time to go."""
    import qchain.sim.simulation as S

    monkeypatch.setattr(S, "LINES_AFTER", 0.0)
    monkeypatch.setattr(S, "LINES_EVERY", 0.0)
    ch = hanging_arm(2)
    tr = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.5), pressure=Sine([1e4] * 6, 2.0), method=method,
                  t_eval=np.linspace(0, 0.5, 51), progress="lines")
    assert tr.success
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert lines and "\r" not in err, err
    for line in lines:
        m = re.fullmatch(r"qchain: t = (\S+) s of 0.5 s \((\S+) %\) after (\S+) s wall time(, about (\S+) s to go)?",
                         line)
        assert m, line
        t, pct = float(m.group(1)), float(m.group(2))
        assert 0 <= t <= 0.5 and pct == pytest.approx(200 * t, abs=0.06) and float(m.group(3)) >= 0
    with pytest.raises(TypeError, match=r"progress must be True, False or 'lines', got a str 'bar'"):
        simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.5), progress="bar")


def test_a_large_implicit_model_says_at_its_start_that_each_jacobian_is_dense_work(capsys):
    """Over STABILITY_MAX_NV free coordinates, radau5 with progress on says so before its
    first (dense, O(nv^3)) Jacobian; without progress it says nothing."""
    seg = Segment(**{**SEG, "length": 0.01, "damping": 0.05})
    ch = Chain([seg] * 101)  # 303 free coordinates
    q, v = ch.neutral(), np.zeros(ch.nv)
    tr = simulate(ch, q, v, (0, 1e-4), method="radau5", t_eval=[1e-4], progress="lines")
    assert tr.success
    err = capsys.readouterr().err
    assert ("qchain: radau5 on 303 free coordinates: each exact Jacobian is dense 303 x 303 work, O(nv^3) (seconds "
            "to minutes each for nv in the thousands, docs/engine.md); progress is shown after each step") in err, err
    simulate(ch, q, v, (0, 1e-4), method="radau5", t_eval=[1e-4])
    assert capsys.readouterr().err == ""


def test_argument_errors():
    ch = hanging_arm(1)
    q, v = ch.neutral(), np.zeros(3)
    with pytest.raises(ValueError, match="method must be one of"):
        simulate(ch, q, v, (0, 1), method="euler")
    with pytest.raises(ValueError, match=r"method 'rk4' needs a step dt > 0 s"):
        simulate(ch, q, v, (0, 1), method="rk4")
    with pytest.raises(ValueError, match=r"t_span must be \(t0, t1\)"):
        simulate(ch, q, v, (1, 0))
    with pytest.raises(ValueError, match=r"pressure must have shape \(3,\), got shape \(2,\)"):
        simulate(ch, q, v, (0, 1), pressure=[1, 2])
    with pytest.raises(ValueError, match=r"pressure schedule gives 6 values, the model needs 3"):
        simulate(ch, q, v, (0, 1), pressure=Step(0.1, after=np.zeros(6)))
    with pytest.raises(ValueError, match=r"v0 must have shape \(3,\)"):
        simulate(ch, q, np.zeros(2), (0, 1))
    assert set(METHODS) == {"rk4", "midpoint", "dopri5", "radau5", "RK45", "DOP853", "Radau", "BDF"}


def test_locked_coordinates_are_held_and_reduce_the_state():
    """An inextensible segment keeps l = l0; a planar chain keeps uy = 0 — in the integrator
    and in the model (forward dynamics on the reduced coordinates equals P^T M P a = P^T (f - h))."""
    segs = [Segment(**SEG, extensible=False), Segment(**SEG)]
    ch = Chain(segs, planar=True, gravity=(2.0, 0.0, 9.81))
    assert ch.nv_active == 3 and list(np.flatnonzero(ch.active)) == [1, 3, 4]
    q = ch.neutral()
    q[[1, 3, 4]] = [4.0, 0.105, -3.0]
    v = np.zeros(6)
    v[[1, 3, 4]] = [1.0, 0.01, 2.0]
    p = np.array([2e4, 0, 0, 1e4, 3e4, 3e4])
    a = ch.forward_dynamics(q, v, p)
    A = ch.active
    M = ch.mass_matrix(q)[np.ix_(A, A)]
    rhs = (ch.internal_forces(q, v, p) - ch.nonlinear_effects(q, v))[A]
    assert np.allclose(a[~A], 0.0)
    assert np.allclose(a[A], np.linalg.solve(M, rhs), rtol=1e-10, atol=0)
    tr = simulate(ch, q, v, (0, 0.05), pressure=p, method="RK45", energies=False)
    assert tr.success
    assert np.all(tr.q[:, 0] == SEG["length"]) and np.all(tr.q[:, [2, 5]] == 0.0)
    bad = q.copy()
    bad[0] = 0.11
    with pytest.raises(ValueError, match=r"q\[0\] \(segment 0, l\) is locked at 0.1"):
        ch.forward_dynamics(bad, v)
    with pytest.raises(ValueError, match="planar=True needs curvature coordinates"):
        Chain([Segment(**SEG, coords="paper")], planar=True)


def test_rk4_above_its_stability_limit_says_so():
    """A clamped rod of 10 short segments released under gravity: the exact Jacobian's fastest
    mode puts RK4's limit near 7.2e-4 s. Above it the run says the step is unstable (not only
    that the model left its domain); just below it the run succeeds; a genuine domain exit at
    a stable step is reported without that diagnosis."""
    n, L, r = 10, 0.2, 0.02
    seg = dict(length=L / n, radius=r, mass=1000 * np.pi * r * r * L / n, chamber_area=2e-5, chamber_radius=0.01,
               youngs_modulus=5e5)
    ch = Chain([Segment(**seg) for _ in range(n)], gravity=(9.81, 0.0, 0.0))
    bad = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.3), method="rk4", dt=1e-3)
    assert not bad.success
    assert bad.message.startswith("rk4 became unstable: the step dt = 0.001 s is above its stability limit")
    limit = float(bad.message.split("about ")[1].split(" s")[0])
    assert 6e-4 < limit < 8e-4
    ok = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.3), method="rk4", dt=0.9 * limit)
    assert ok.success, ok.message
    one = Chain([Segment(**SEG, damping=0.05)], gravity=np.zeros(3))
    exit_ = simulate(one, one.neutral(), np.zeros(3), (0, 1.0), pressure=Ramp(0.0, 1.0, end=[3e6, 0.0, 0.0]),
                     method="rk4", dt=2e-4)
    assert not exit_.success and "kappa" in exit_.message and "unstable" not in exit_.message


@pytest.mark.parametrize("method", ["RK45", "dopri5"])
def test_ctrl_c_says_how_far_the_run_got_on_either_engine(method):
    """A Ctrl-C during a run (raised here by ``on_sample`` once it has seen t >= 0.1 s)
    ends it with its samples so far, and the message names the time they reach, not the
    start: the Python path is interrupted inside its adaptive loop, before it returns
    its time."""
    from qchain.sim.engine.driver import Interrupted

    ch = hanging_arm(1)
    seen = []

    def on_sample(t, q, v, p):
        seen.append(t)
        if t >= 0.1:
            raise KeyboardInterrupt

    with pytest.raises(Interrupted) as info:
        simulate(ch, ch.neutral(), np.zeros(3), (0, 1.0), method=method, t_eval=np.linspace(0, 1.0, 101),
                 on_sample=on_sample)
    tr = info.value.trajectory
    assert tr.status == -1 and tr.meta["engine"] == ("python" if method == "RK45" else "compiled")
    reached = float(tr.message.rsplit("t = ", 1)[1].split(" s")[0])
    assert reached >= 0.1 and reached >= tr.t[-1] - 1e-12, tr.message
