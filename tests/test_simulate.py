"""Integrators: convergence orders, long-run energy behaviour, Lie-group base, clean stops;
simulate's arguments (times, steps, budgets, controllers, events) checked where they enter."""

import math
import re
import subprocess
import sys
import textwrap
import time

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from helpers import deadline
from qchain import Chain, Segment, simulate_batch
from qchain.checks import bounds as B
from qchain.errors import NonFiniteError
from qchain.sim.budget import Budget, BudgetError
from qchain.sim.inputs import Ramp, Sine, Step, Table
from qchain.sim.simulation import METHODS, Event, simulate
from support import CH1, CH2, NOT_NUMBERS, ROOT, S, SEGMENT, outside, refused, soft_arm, soft_segment, value_id

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


@pytest.mark.slow
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


def _released_rod(n=3):
    """A soft clamped rod (0.2 m, r 0.02 m, 0.5 MPa) released under gravity: its root segment swings
    toward |kappa| r_s = 1, the domain's boundary, within 0.1 s."""
    L, r = 0.2, 0.02
    seg = Segment(length=L / n, radius=r, mass=1000.0 * np.pi * r * r * L / n, youngs_modulus=5e5, damping=0.0,
                  extensible=False, chamber_area=1e-6, chamber_radius=0.005, nodes=5)
    return Chain([seg] * n, base_placement=pin.SE3(pin.utils.rotate("y", np.pi / 2), np.zeros(3)),
                 gravity=(0.0, 0.0, -9.81), planar=True)


@pytest.mark.parametrize("method, n", [("dopri5", 3), ("RK45", 5)])
def test_samples_interpolated_outside_the_domain_end_the_run_before_them(method, n):
    """A loose step ends inside the domain while its interpolant, between the samples' times,
    overshoots |kappa| r_s = 1 (on the compiled engine, up to 1.34: those samples were kept,
    states no call of the model accepts, and the run failed only later). Now the run
    fails at the first such sample, naming the segment, the bound and the step, and every
    sample it kept is a state of the model."""
    ch = _released_rod(n)
    t_eval = np.linspace(0.0, 1.0, 2001)
    tr = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, 1.0), method=method, rtol=1.0, atol=1e-2,
                  t_eval=t_eval, energies=False)
    assert not tr.success and tr.status == -1
    assert re.search(r"segment \d .*kappa.* r_s = 1\.\d+ must be < 1 .*an output sample interpolated inside",
                     tr.message), tr.message
    assert 10 < len(tr.t) < t_eval.size
    t_fail = float(re.search(r"at t = ([0-9.e+-]+) s, an output sample", tr.message).group(1))
    assert np.isclose(t_fail, t_eval[len(tr.t)], rtol=1e-5)  # the first sample it did not keep
    assert np.max(np.abs(tr.q[:, 1::3])) * 0.02 < 1.0
    for q in tr.q:
        ch.tip_placement(q)  # every sample is a state of the model


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


def test_method_names_are_matched_exactly():
    """A method is named exactly, case included: "radau" is neither the compiled "radau5" nor
    scipy's "Radau" (an order of magnitude slower), so it is refused, naming both; a name with no
    close method is refused without a guess."""
    ch = hanging_arm(1)
    q, v = ch.neutral(), np.zeros(3)
    for name, hint in (("radau", "did you mean 'radau5' (compiled) or 'Radau' (scipy's)?"),
                       ("Radau5", "did you mean 'radau5' (compiled) or 'Radau' (scipy's)?"),
                       ("RK4", "did you mean 'rk4' (compiled) or 'RK45' (scipy's)?"),
                       ("dopri", "did you mean 'dopri5' (compiled)?"),
                       ("bdf", "did you mean 'BDF' (scipy's)?")):
        with pytest.raises(ValueError, match=re.escape(f"method must be one of {METHODS}, got {name!r}: {hint}")):
            simulate(ch, q, v, (0, 1), method=name)
    for name in ("euler", 5, None):
        with pytest.raises(ValueError, match=re.escape(f"method must be one of {METHODS}, got {name!r}")) as err:
            simulate(ch, q, v, (0, 1), method=name)
        assert str(err.value).endswith(f"got {name!r}"), err.value


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


# --------------------------------------------------------------------------------------
# Bad input (issue 18): refused where it enters, naming the argument, the value and the bound;
# never a foreign traceback, a hang, a crash, a silent NaN or lost data.

@pytest.mark.parametrize("ctl", [lambda: np.zeros(3), lambda t, q: np.zeros(3)], ids=["no argument", "two"])
def test_a_controller_of_the_wrong_arity_is_named_where_it_enters(ctl):
    for kw in (dict(method="RK45"), dict(controller_rate=1e3)):
        msg = refused(lambda: simulate(CH1, CH1.neutral(), np.zeros(3), (0, 0.01), pressure=ctl, **kw), "pressure",
                      TypeError)
        assert "(t, q, v)" in msg


@pytest.mark.parametrize("ret", [math.nan, "1", np.ones(2), None, 1j], ids=value_id)
@pytest.mark.parametrize("method", ["radau5", "RK45"])
def test_an_event_function_must_return_a_finite_real(ret, method):
    """NaN never crosses zero (the event was silently never seen); the others failed in a
    comparison naming nothing."""
    def level(t, q, v):
        return ret

    msg = refused(lambda: simulate(CH1, CH1.neutral(), np.zeros(3), (0, 0.01), method=method, events=[Event(level)]),
                  "event 'level'")
    assert "t = 0 s" in msg
    refused(lambda: Event(level, terminal="no"), "terminal")
    refused(lambda: Event(level, name=3), "name")


@pytest.mark.slow
@pytest.mark.parametrize("method", ["radau5", "rk4", "RK45"])
def test_callables_get_copies_of_the_state(method):
    """A controller, an event function and ``on_sample`` that write into the arrays they get
    change neither the caller's q0, nor the run, nor the recorded samples (on the Python
    path the run went outside the model, and a private exception escaped)."""
    def careless(t, q, v):
        q[:] = 0.0
        v[:] = 1e3
        return np.full(6, 1e4)

    def ev(t, q, v):
        q[:] = -1.0
        return 1.0

    def cb(t, q, v, p):
        q[:] = 7.0
        p[:] = 7.0

    kw = dict(method=method, dt=1e-3, t_eval=[0, 0.005, 0.01])
    if method != "RK45":
        kw["controller_rate"] = 1e3
    ref = simulate(CH2, CH2.neutral(), np.zeros(6), (0, 0.01), pressure=lambda t, q, v: np.full(6, 1e4), **kw)
    q0 = CH2.neutral()
    tr = simulate(CH2, q0, np.zeros(6), (0, 0.01), pressure=careless, events=[Event(ev)], on_sample=cb, **kw)
    assert np.array_equal(q0, CH2.neutral()) and tr.success
    assert np.allclose(tr.q, ref.q, rtol=1e-12, atol=1e-15) and np.allclose(tr.p, ref.p)


def test_inputs_and_outputs_share_no_memory():
    q0, v0, P, te = CH2.neutral(), np.zeros(6), np.full(6, 1e4), np.linspace(0, 0.01, 3)
    keep = [x.copy() for x in (q0, v0, P, te)]
    tr = simulate(CH2, q0, v0, (0, 0.01), pressure=P, t_eval=te)
    assert all(np.array_equal(a, b) for a, b in zip((q0, v0, P, te), keep))
    assert not any(np.shares_memory(o, i) for o in (tr.t, tr.q, tr.v, tr.p) for i in (q0, v0, P, te))


def test_a_failed_run_of_a_large_chain_does_not_spend_minutes_on_its_stability_limit():
    """A 1000-segment rk4 run that failed formed the 6000 x 6000 Jacobian for its message."""
    from helpers import deadline
    from qchain.sim.engine.driver import STABILITY_MAX_NV, stability_limit

    big = Chain([S] * (STABILITY_MAX_NV // 3 + 1))
    with deadline(10, "stability_limit of a large chain"):
        assert stability_limit(big, big.neutral(), np.zeros(big.nv), np.zeros(big.nu), np.zeros(big.nv), 0.0) is None
    small = Chain([S] * 2)
    lim = stability_limit(small, small.neutral(), np.zeros(small.nv), np.zeros(small.nu), np.zeros(small.nv), 0.0)
    assert lim is not None and 0 < lim < 1


def test_an_explicit_adaptive_method_on_a_stiff_model_stops_at_the_step_budget():
    """Refused before it starts where the stability limit puts it over budget; where the
    limit (a lower bound of the steps) lets it start, stopped at budget.max_steps as it goes."""
    from qchain.sim.budget import Budget, BudgetError
    from qchain.sim.simulation import explicit_stability_limit

    s = Segment(length=1e-5, radius=1e-3, mass=1e-9, chamber_area=1e-8, chamber_radius=5e-4, youngs_modulus=1e12)
    ch = Chain([s])
    t = time.perf_counter()
    with pytest.raises(BudgetError, match=r"budget.max_steps: expected at most 10000000 steps, found .* steps \("
                       r"duration 0.02 s / dopri5's stability limit of the step at the start, about .* s: the model "
                       r"is stiff for an explicit method, use method 'radau5'\)"):
        simulate(ch, s.neutral(), np.zeros(3), (0, 0.02), method="dopri5")
    h = explicit_stability_limit(ch, "dopri5", s.neutral(), np.zeros(3), 0.0)
    r = simulate(ch, s.neutral(), np.zeros(3), (0, 2000 * h), method="dopri5", budget=Budget(max_steps=5000))
    assert time.perf_counter() - t < 60
    assert not r.success and "budget.max_steps = 5000" in r.message and "radau5" in r.message, r.message


def test_controller_rate_counts_in_the_run_budget():
    """controller_rate=1e9 built every instant (a 7.45 GiB array) or made 1e8 Python calls."""
    ch = soft_arm()
    q, v, p = ch.neutral(), np.zeros(ch.nv), np.zeros(ch.nu)
    match = r"budget.max_steps: .* \(duration 1 s x controller_rate 1e\+0[89] Hz: a step ends at every controller"
    for rate in (1e8, 1e9):
        with pytest.raises(BudgetError, match=match):
            simulate(ch, q, v, (0, 1), pressure=lambda t, q, v: p, controller_rate=rate)
        with pytest.raises(BudgetError, match=match):
            simulate_batch(ch, q, v, (0, 1), pressure=lambda t, q, v: p, controller_rate=rate, t_eval=[1.0], workers=1)


def test_a_first_step_below_the_span_resolution_is_refused_and_late_spans_say_why():
    ch = soft_arm()
    q, v = ch.neutral(), np.zeros(ch.nv)
    with pytest.raises(ValueError, match=r"first_step must be >= 4.44e-15 s \(20 float64 spacings of max\(1 s, "
                                         r"\|t0\|, \|t1\|\)\), got 1e-300 s"):
        simulate(ch, q, v, (0, 1), first_step=1e-300)
    for method in ("radau5", "dopri5"):  # once: "the step size fell below its floor" at once
        r = simulate(ch, q, v, (1e11, 1e11 + 0.05), method=method, t_eval=[1e11 + 0.05])
        assert r.success, (method, r.message)
    # at 1e12 s float64 times are 1.2e-4 s apart: step times rounded by 1 % of a step spoil an
    # error estimate of 1e-8; the run stops at its start saying so (not "singular" alone)
    for span in ((1e12 - 0.05, 1e12), (-1e12, -1e12 + 0.05)):
        r = simulate(ch, q, v, span, method="radau5", t_eval=[span[1]])
        assert r.success or ("10 float64 spacings of t (0.00122 s)" in r.message
                             and "shift t_span toward 0" in r.message), r.message


@pytest.mark.slow
def test_a_noisy_controller_without_a_rate_stalls_and_says_so():
    """It once took 30 s for 6.5e-7 s of 0.01 s (hours to the step budget); now the run
    stops after 1000 steps shorter than 1e-9 s, naming controller_rate."""
    ch = soft_arm(1)
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    r = simulate(ch, ch.neutral(), np.zeros(3), (0, 0.01), pressure=lambda t, q, v: 1e4 + rng.normal(0, 10, 3),
                 t_eval=[0, 0.005, 0.01])
    assert time.perf_counter() - t0 < 60
    assert not r.success and "stalled" in r.message and "controller_rate" in r.message, r.message
    held = simulate(ch, ch.neutral(), np.zeros(3), (0, 0.01), pressure=lambda t, q, v: 1e4 + rng.normal(0, 10, 3),
                    t_eval=[0, 0.005, 0.01], controller_rate=1000.0)
    assert held.success


@pytest.mark.parametrize("method", ["rk4", "midpoint"])
def test_a_terminal_event_at_a_step_end_is_one_sample(method):
    from qchain.sim.simulation import Event

    ch = soft_arm(1)
    for root in (0.05, 0.02):
        r = simulate(ch, ch.neutral(), np.zeros(3), (0, 0.05), method=method, dt=0.01,
                     events=[Event(lambda t, q, v, root=root: t - root, terminal=True)])
        np.testing.assert_allclose(r.t, np.arange(0, root + 1e-9, 0.01))


def test_the_step_budget_hint_fits_the_method():
    from qchain.sim.budget import Budget

    ch = soft_arm(1)
    r = simulate(ch, ch.neutral(), np.zeros(3), (0, 1), pressure=lambda t, q, v: np.full(3, 1e4 * math.sin(t)),
                 controller_rate=100.0, budget=Budget(max_steps=100))
    assert not r.success and "budget.max_steps = 100" in r.message
    assert "use method='radau5'" not in r.message and "rejected steps count" in r.message, r.message


def test_runs_that_once_failed_inside_scipy_or_numba_say_why_or_run():
    import warnings

    paper = Chain([Segment(**SEGMENT, coords="paper")])
    from qchain.errors import SingularConfigurationError

    with pytest.raises(SingularConfigurationError, match="paper's \\(l, psi, kappa\\) coordinates are singular"):
        simulate(paper, paper.neutral(), np.zeros(3), (0, 0.005))
    ch = soft_arm(2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numba's experimental-feature warning at every call stopped every run
        for method in ("radau5", "dopri5", "rk4"):
            assert simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.005), method=method, dt=1e-3).success
    with np.errstate(all="raise"):  # scipy's own nextafter(0, inf) underflowed
        assert simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.005), method="RK45").success


def test_simulate_refuses_bad_times_and_steps_by_name():
    ch = Chain([soft_segment()])
    q, v = ch.neutral(), np.zeros(3)
    cases = [
        (dict(t_eval=[0.0, np.nan, 0.5]), ValueError, r"t_eval\[1\] must be finite, got nan"),
        (dict(t_eval=[0.0, 0.5, 0.4]), ValueError, r"t_eval must be strictly increasing"),
        (dict(t_eval=[0.0, 2.0]), ValueError, r"t_eval must be inside t_span"),
        (dict(t_eval="0 1"), TypeError, r"t_eval must be an array of real numbers, got a str"),
        (dict(method="rk4", dt=True), TypeError, r"dt must be a real number \(booleans are not numbers\)"),
        (dict(method="rk4", dt="1e-3"), TypeError, r"dt must be a real number, got a str '1e-3'"),
        (dict(method="rk4", dt=1e-300), BudgetError, r"budget.max_steps: expected at most 10000000 steps, found "
                                                     r"1e\+300 steps \(duration 1 s / dt 1e-300 s\).*budget=qchain"),
        (dict(max_step=1e-300), BudgetError, r"duration 1 s / max_step 1e-300 s"),
        (dict(rtol="1e-6"), TypeError, r"rtol must be a real number, got a str"),
        (dict(rtol=0.0), ValueError, r"rtol must be >= 1e-15 and <= 1, got 0"),
        (dict(atol=np.nan), ValueError, r"atol must be finite, got nan"),
        (dict(first_step=-1.0), ValueError, r"first_step must be > 0 and <= 1e\+12 s"),
        (dict(wall_limit=True), TypeError, r"wall_limit must be a real number \(booleans"),
        (dict(t_eval=np.linspace(0, 1, 2_000_001)), BudgetError, r"budget.max_samples: expected at most 1000000"),
        (dict(budget="big"), TypeError, r"budget must be a qchain.sim.budget.Budget"),
    ]
    for kw, exc, match in cases:
        with deadline(20):
            with pytest.raises(exc, match=match):
                simulate(ch, q, v, (0.0, 1.0), **kw)
    with pytest.raises(TypeError, match=r"t_span must be an array of real numbers \(complex"):
        simulate(ch, q, v, (0.0, 1.0 + 0j))
    with pytest.raises(ValueError, match=r"t_span\[1\] must be >= -1e\+12 and <= 1e\+12 s"):
        simulate(ch, q, v, (0.0, 1e300))
    with pytest.raises(BudgetError, match=r"2 steps a period of the fastest input, 10000 Hz, over 1000 s"):
        simulate(ch, q, v, (0.0, 1000.0), pressure=Sine(np.full(3, 1e3), 1e4))
    with pytest.raises(ValueError, match=r"frequency\[0\] must be >= 0 and <= 10000 Hz, got 1e\+300"):
        Sine(np.full(3, 1e3), 1e300)


def test_raising_the_budget_of_simulate_lets_the_run_through():
    ch = Chain([soft_segment()])
    q, v = ch.neutral(), np.zeros(3)
    with pytest.raises(BudgetError, match=r"budget.max_steps: expected at most 100 steps, found 200 steps"):
        simulate(ch, q, v, (0.0, 0.02), method="rk4", dt=1e-4, budget=Budget(max_steps=100))
    tr = simulate(ch, q, v, (0.0, 0.02), method="rk4", dt=1e-4, budget=Budget(max_steps=1000))
    assert tr.success and len(tr.t) == 201
    with pytest.raises(ValueError, match=r"Budget.max_steps must be an integer >= 1 and <= 1e\+15, got 0"):
        Budget(max_steps=0)
    with pytest.raises(TypeError, match=r"Budget.max_steps must be an integer >= 1 and <= 1e\+15, got a boolean True"):
        Budget(max_steps=True)


@pytest.mark.slow
@pytest.mark.parametrize("case", ["compiled rk4", "compiled midpoint", "python rk4"])
def test_a_run_that_turns_non_finite_stops_naming_quantity_segment_and_time(case, monkeypatch):
    """Pressures of 1e300 Pa overflow the accelerations at the first stage: the run stops
    with success = False and a message naming the quantity, the coordinate's segment and
    the time; every sample it kept is finite. (Such pressures are refused where they enter,
    outside :data:`qchain.checks.bounds.PRESSURE`; the range is lifted here to reach the check
    within the run, which guards against any overflow on the way.)"""
    import qchain.sim.inputs

    method = case.split()[1]
    coords = "paper" if case.startswith("python") else "curvature"
    seg = soft_segment(coords=coords)
    ch = Chain([seg, seg])
    q = ch.neutral()
    if coords == "paper":
        q[2] = q[5] = 1.0  # away from the paper coordinates' singular straight pose
    with pytest.raises(ValueError, match=r"pressure\[0\] must be >= -101325 and <= 1e\+09 Pa, got 1e\+300 Pa"):
        simulate(ch, q, np.zeros(ch.nv), (0.0, 0.1), method=method, dt=1e-3, pressure=np.full(6, 1e300))
    monkeypatch.setattr(qchain.sim.inputs, "input_range", lambda name: None)
    with deadline(60):
        tr = simulate(ch, q, np.zeros(ch.nv), (0.0, 0.1), method=method, dt=1e-3, pressure=np.full(6, 1e300))
    assert tr.meta["engine"] == ("python" if coords == "paper" else "compiled")
    assert not tr.success and tr.status == -1
    assert "non-finite" in tr.message or "not finite" in tr.message, tr.message
    assert "segment 0" in tr.message and "t = " in tr.message, tr.message
    assert np.all(np.isfinite(tr.q)) and np.all(np.isfinite(tr.v)) and len(tr.t) >= 1


def test_simulate_refuses_a_start_that_overflows_naming_the_segment():
    seg = soft_segment()
    ch = Chain([seg, seg])
    q = ch.neutral()
    q[3] = 1e300
    with pytest.raises(NonFiniteError, match=r"not finite at t = 0 s: segment 1 \(q\[3:6\] = \(1e\+300, 0, 0\)"):
        simulate(ch, q, np.zeros(6), (0.0, 1.0))
    with pytest.raises(NonFiniteError, match=r"segment 0 .* its kinetic energy inf J"):
        simulate(ch, ch.neutral(), np.full(6, 1e200), (0.0, 1.0))


@pytest.mark.parametrize("base", ["fixed", "floating"])
@pytest.mark.parametrize("radius", [B.RADIUS.high, B.RADIUS.low])
def test_energies_are_finite_inside_the_box_where_simulate_does_not_compute_them(base, radius):
    """simulate computes a start's energies (to name the segment that overflows) only outside
    ENERGY_BOX: inside it they are finite for every parameter at its bound. Here the heaviest,
    stiffest, longest segments, the strongest gravity and payload, at starts on the box's faces
    (every |v| and every length up to the box, curvatures up to the domain's 1 / radius, the
    base at its farthest) stay below 1e100 J; starts just outside it are still checked."""
    from qchain.sim.simulation import ENERGY_BOX

    rng = np.random.default_rng(5)
    seg = Segment(length=B.LENGTH.high, radius=radius, mass=B.MASS.high, youngs_modulus=B.YOUNGS_MODULUS.high,
                  chamber_area=1e-2 * radius**2, chamber_radius=radius / 2)
    g = B.GRAVITY.high
    ch = Chain([seg] * 4, base=base, gravity=(g, -g, g),
               payload=pin.Inertia(1e6, np.full(3, 100.0), np.eye(3) * 1e8))
    worst = 0.0
    for _ in range(40):
        q = ch.neutral()
        v = rng.choice([-ENERGY_BOX, ENERGY_BOX], ch.nv) * rng.uniform(0.5, 1.0, ch.nv)
        for j in range(ch.n):
            d = rng.normal(size=2)
            q[ch.q_slice(j)] = [ENERGY_BOX * rng.uniform(1e-6, 1.0), *(d / np.linalg.norm(d) * 0.999 / radius)]
        if ch.floating:
            q[:3] = rng.choice([B.POSITION.low, B.POSITION.high], 3)
            quat = rng.normal(size=4)
            q[3:7] = quat / np.linalg.norm(quat)
        worst = max(worst, abs(ch.kinetic_energy(q, v)), abs(ch.potential_energy(q)))
    assert np.isfinite(worst) and worst < 1e100, worst
    # beyond the box, the start is checked (its energy computed) and refused where it overflows
    with pytest.raises(NonFiniteError, match=r"kinetic energy inf J"):
        simulate(ch, ch.neutral(), np.full(ch.nv, 1e160), (0.0, 1.0))


@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(data=st.data())
def test_fuzzed_simulate_arguments_give_a_clean_error_naming_the_argument(data):
    ch = Chain([soft_segment()])
    q, v = ch.neutral(), np.zeros(3)
    name = data.draw(st.sampled_from(["dt", "rtol", "atol", "max_step", "first_step", "wall_limit",
                                      "controller_rate"]))
    rng = {"dt": B.STEP, "rtol": B.RTOL, "atol": B.ATOL, "max_step": B.STEP, "first_step": B.STEP,
           "wall_limit": B.WALL_LIMIT, "controller_rate": B.SAMPLE_RATE}[name]
    value = data.draw(st.one_of(outside(rng).filter(lambda x: not (name == "max_step" and x == math.inf)),
                                NOT_NUMBERS, st.complex_numbers(),
                                st.none() if name in ("dt", "rtol", "atol", "max_step") else st.nothing()))
    kw = {name: value}
    if name == "dt":
        kw["method"] = "rk4"
    if name == "controller_rate":
        kw["pressure"] = lambda t, q, v: np.zeros(3)
    with deadline(20):
        with pytest.raises((ValueError, TypeError)) as exc:
            simulate(ch, q, v, (0.0, 0.01), **kw)
    assert name in str(exc.value), str(exc.value)
    assert "could not convert" not in str(exc.value)


HANG_SCRIPT = textwrap.dedent('''
    import sys, time
    import numpy as np
    from qchain.scene import SceneError, parse_scene
    from qchain.sim.budget import BudgetError
    from qchain import Chain, Segment
    from qchain import simulate
    from qchain.sim.inputs import Sine
    SCENE = """
    [[segments]]
    length = 0.1
    radius = 0.015
    mass = 0.05
    chamber_area = 4.5e-5
    chamber_radius = 0.0085
    youngs_modulus = 1e5
    {seg}
    [simulation]
    duration = {duration}
    {sim}
    {rest}
    """
    cases = {
        "count": dict(seg="count = 1000000000000"),
        "max_step": dict(sim="max_step = 1e-300"),
        "dt": dict(sim='method = "rk4"\\ndt = 1e-300'),
        "rate": dict(rest="[output]\\nsample_rate = 1e9"),
        "frequency": dict(rest='[pressure]\\ntype = "sine"\\namplitude = [1e3, 0, 0]\\nfrequency = 1e300'),
        "velocity": dict(rest='[base]\\ntype = "floating"\\nvelocity = [1e300, 0, 0]'),
        "duration": dict(duration="1e300"),
    }
    for name, kw in cases.items():
        t0 = time.perf_counter()
        text = SCENE.format(**{**dict(seg="", sim="", rest="", duration="1.0"), **kw})
        try:
            parse_scene(text, name + ".toml").simulate()
            print(name, "RAN")
        except SceneError as err:
            print(name, "refused", f"{time.perf_counter() - t0:.3f}", err.problems[0].key)
    ch = Chain([Segment(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085,
                        youngs_modulus=1e5)])
    for name, kw in {"api_dt": dict(method="rk4", dt=1e-300), "api_max_step": dict(max_step=1e-300)}.items():
        try:
            simulate(ch, ch.neutral(), np.zeros(3), (0.0, 1.0), **kw)
            print(name, "RAN")
        except BudgetError:
            print(name, "refused")
''')


@pytest.mark.slow
def test_former_hangs_are_refused_before_they_start():
    with deadline(200):
        out = subprocess.run([sys.executable, "-c", HANG_SCRIPT], capture_output=True, text=True, timeout=180,
                             cwd=ROOT)
    assert out.returncode == 0, out.stderr
    lines = dict(line.split(" ", 1) for line in out.stdout.strip().splitlines())
    expect = {"count": "segments[0].count", "max_step": "simulation.max_step", "dt": "simulation.dt",
              "rate": "output.sample_rate", "frequency": "pressure.frequency", "velocity": "base.velocity[0]",
              "duration": "simulation.duration"}
    for name, key in expect.items():
        words = lines[name].split()
        assert words[0] == "refused" and words[2] == key, out.stdout
    assert lines["api_dt"] == "refused" and lines["api_max_step"] == "refused", out.stdout
