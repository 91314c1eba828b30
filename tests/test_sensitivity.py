"""Trajectory sensitivities (qchain.sim.sensitivity): the derivative of a run's samples with
respect to the initial state and parameters, against central differences of whole runs with
the same steps, against the linearisation's exact step map near an equilibrium, and bad input."""

import numpy as np
import pytest
import scipy.linalg

from qchain import Chain, Segment, equilibrium, simulate
import pinocchio as pin

from qchain.sim.inputs import Sine, SineMotion
from qchain.sim.sensitivity import sensitivities, tip_sensitivities
from support import refused

SEG = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5,
           damping=0.02)
A0 = SEG["chamber_area"]
T_EVAL = np.array([0.0, 0.0123, 0.031, 0.05])  # between steps: the dense output's derivative
P_SINE = Sine(amplitude=[2e4, 0, 1e4] * 3, frequency=5.0, phase=[0, 1, 2] * 3, offset=[2e4, 0, 1e4] * 3)


def arm(n=3, area1=A0, change=None, **kw):
    """The test arm; ``change = (name, j, value)``: segment ``j``'s attribute (or gravity's axis ``j``) changed."""
    segs = [dict(SEG, chamber_area=area1 if j == 1 else A0) for j in range(n)]
    g = [0.0, 0.0, -9.81]
    if change is not None:
        name, j, value = change
        if name == "gravity":
            g[j] = value
        else:
            segs[j][name] = value
    return Chain([Segment(**s) for s in segs], gravity=g, **kw)


def start(chain):
    q0 = chain.neutral()
    v0 = np.zeros(chain.nv)
    free = np.flatnonzero(chain.active)
    q0[1::3] += 2.0  # bent (ux, 1/m), and moving
    v0[free] = 0.3 * np.cos(np.arange(free.size))
    return q0, v0


def run_q(chain, q0, v0, **kw):
    """The samples' (q, v) of a plain run with the given settings (the same steps)."""
    r = sensitivities(chain, q0, v0, (0.0, 0.05), t_eval=T_EVAL, pressure=P_SINE, initial=False,
                      params=[("chamber_area", 0)], **kw)
    assert r.success, r.message
    return np.concatenate([r.q, r.v], axis=1)


def check_columns(chain, r, runs, method_kw, cols, rel):
    """Central differences of whole runs (``runs(delta column) -> samples``) against ``r.S``."""
    q0, v0 = start(chain)
    nv = chain.nv
    for name in cols:
        c = r.columns.index(name)
        if name.startswith("chamber_area"):
            e = 1e-4 * A0
            fd = (run_q(arm(chain.n, A0 + e, planar=chain.planar), q0, v0, **method_kw)
                  - run_q(arm(chain.n, A0 - e, planar=chain.planar), q0, v0, **method_kw)) / (2 * e)
        elif not name.startswith(("q0", "v0")):
            pname, j = name[:-1].split("[")
            j = int(j)
            value = [0.0, 0.0, -9.81][j] if pname == "gravity" else SEG[pname]
            e = 1e-3 if pname == "gravity" else 1e-5 * value
            fd = (run_q(arm(chain.n, change=(pname, j, value + e), planar=chain.planar), q0, v0, **method_kw)
                  - run_q(arm(chain.n, change=(pname, j, value - e), planar=chain.planar), q0, v0, **method_kw)) / (2 * e)
        else:
            i = int(name[3:-1])
            e = 1e-6
            dq = np.zeros(nv)
            dq[i] = e
            if name.startswith("q0"):
                fd = (run_q(chain, q0 + dq, v0, **method_kw) - run_q(chain, q0 - dq, v0, **method_kw)) / (2 * e)
            else:
                fd = (run_q(chain, q0, v0 + dq, **method_kw) - run_q(chain, q0, v0 - dq, **method_kw)) / (2 * e)
        # rows: q (nq = nv without a floating base) and v
        an = r.S[:, :, c]
        err = np.abs(fd - an).max() / np.abs(an).max()
        assert np.abs(an).max() > 0 and err < rel, (name, err)


def test_rk4_state_is_simulates_and_sensitivities_match_differences_of_whole_runs():
    chain = arm()
    q0, v0 = start(chain)
    r = sensitivities(chain, q0, v0, (0.0, 0.05), method="rk4", dt=1e-3, t_eval=T_EVAL, pressure=P_SINE,
                      params=[("chamber_area", 1)])
    assert r.success and r.nsteps == 50 and r.njev == r.nfev == 200
    tr = simulate(chain, q0, v0, (0.0, 0.05), method="rk4", dt=1e-3, t_eval=T_EVAL, pressure=P_SINE)
    assert np.array_equal(r.q, tr.q) and np.array_equal(r.v, tr.v)  # the same numbers, bit for bit
    assert r.S.shape == (4, 2 * chain.nv, 2 * chain.nv + 1)
    assert np.array_equal(r.S[0, :, : 2 * chain.nv], np.eye(2 * chain.nv))
    check_columns(chain, r, None, dict(method="rk4", dt=1e-3), ["q0[1]", "q0[6]", "v0[0]", "v0[8]",
                                                                  "chamber_area[1]"], 1e-7)


def test_dopri5_frozen_steps_state_is_simulates_and_derivative_matches_runs_on_the_same_steps():
    chain = arm()
    q0, v0 = start(chain)
    r = sensitivities(chain, q0, v0, (0.0, 0.05), method="dopri5", rtol=1e-5, atol=1e-7, t_eval=T_EVAL,
                      pressure=P_SINE, params=[("chamber_area", 1)])
    tr = simulate(chain, q0, v0, (0.0, 0.05), method="dopri5", rtol=1e-5, atol=1e-7, t_eval=T_EVAL,
                  pressure=P_SINE)
    assert r.success and r.nsteps == tr.meta["nsteps"] == r.steps.size - 1 > 5
    assert np.array_equal(r.q, tr.q) and np.array_equal(r.v, tr.v)
    assert r.nfev == 6 * r.nsteps + 1  # first same as last
    check_columns(chain, r, None, dict(method="dopri5", steps=r.steps), ["q0[2]", "v0[4]", "chamber_area[1]"], 1e-7)


def test_planar_chain_rk4_against_differences():
    chain = arm(planar=True)
    q0, v0 = start(chain)
    r = sensitivities(chain, q0, v0, (0.0, 0.05), method="rk4", dt=1e-3, t_eval=T_EVAL, pressure=P_SINE,
                      params=[("chamber_area", 1), ("youngs_modulus", 1), ("mass", 2), ("gravity", 2)])
    locked = np.flatnonzero(~chain.active)
    assert locked.size and not np.any(r.S[:, locked]) and not np.any(r.S[:, chain.nv + locked])
    free = np.flatnonzero(chain.active)
    check_columns(chain, r, None, dict(method="rk4", dt=1e-3), [f"q0[{free[1]}]", f"v0[{free[-1]}]",
                                                                  "chamber_area[1]", "youngs_modulus[1]", "mass[2]",
                                                                  "gravity[2]"], 1e-7)


def test_every_model_parameter_against_differences_of_rebuilt_chains():
    chain = arm()
    q0, v0 = start(chain)
    params = [("youngs_modulus", 0), ("damping", 2), ("mass", 1), ("length", 1), ("gravity", 2), ("gravity", 0)]
    kw = dict(method="rk4", dt=1e-3)
    r = sensitivities(chain, q0, v0, (0.0, 0.05), t_eval=T_EVAL, pressure=P_SINE, params=params, initial=False, **kw)
    assert r.columns == ["youngs_modulus[0]", "damping[2]", "mass[1]", "length[1]", "gravity[2]", "gravity[0]"]
    errs = []
    for c, (name, j) in enumerate(params):
        value = {"gravity": [0.0, 0.0, -9.81][j]}.get(name, SEG.get(name, 0.0) if name != "length" else SEG["length"])
        e = 1e-3 if name == "gravity" else 1e-5 * value  # damping and mass: the differences' error is 1e-4 at 1e-3
        fd = (run_q(arm(change=(name, j, value + e)), q0, v0, **kw)
              - run_q(arm(change=(name, j, value - e)), q0, v0, **kw)) / (2 * e)
        an = r.S[:, :, c]
        errs.append(np.abs(fd - an).max() / np.abs(an).max())
    assert max(errs) < 1e-7, errs


def test_prescribed_base_swinging_about_a_tilted_axis_against_differences():
    motion = SineMotion(kind="rotation", axis=np.array([0.3, 0.4, 0.5]) / np.linalg.norm([0.3, 0.4, 0.5]),
                        amplitude=0.4, frequency=3.0, phase=0.2, mount=pin.SE3.Identity())
    chain = arm(base="prescribed", base_motion=motion)
    q0, v0 = start(chain)
    r = sensitivities(chain, q0, v0, (0.0, 0.05), method="rk4", dt=1e-3, t_eval=T_EVAL, pressure=P_SINE,
                      params=[("chamber_area", 1)])
    tr = simulate(chain, q0, v0, (0.0, 0.05), method="rk4", dt=1e-3, t_eval=T_EVAL, pressure=P_SINE)
    assert np.array_equal(r.q, tr.q) and np.array_equal(r.v, tr.v)
    q0p = q0.copy()
    q0p[4] += 1e-6
    q0m = q0.copy()
    q0m[4] -= 1e-6
    kw = dict(method="rk4", dt=1e-3)
    fd = (run_q(chain, q0p, v0, **kw) - run_q(chain, q0m, v0, **kw)) / 2e-6
    an = r.S[:, :, r.columns.index("q0[4]")]
    assert np.abs(fd - an).max() < 1e-7 * np.abs(an).max()
    p, dp = tip_sensitivities(chain, r)  # the base's motion is in the tip's world position
    assert np.allclose(p, [chain.tip_placement(q, t).translation for q, t in zip(tr.q, tr.t)], rtol=0, atol=1e-15)


def test_near_equilibrium_the_sensitivity_is_the_linearisations_step_map_and_its_exponential():
    chain = arm()
    p = np.array([3e4, 0, 1e4] * 3)
    q_eq = equilibrium(chain, p).q
    free = np.flatnonzero(chain.active)
    d = chain.forward_dynamics_derivatives(q_eq, np.zeros(chain.nv), p)
    nA = free.size
    A = np.block([[np.zeros((nA, nA)), np.eye(nA)], [d.da_dq[np.ix_(free, free)], d.da_dv[np.ix_(free, free)]]])
    h, n = 1e-3, 40
    r = sensitivities(chain, q_eq, np.zeros(chain.nv), (0.0, n * h), method="rk4", dt=h, pressure=p,
                      t_eval=[n * h])
    S = np.block([[r.S[-1][np.ix_(free, range(2 * nA))]], [r.S[-1][np.ix_(chain.nv + free, range(2 * nA))]]])
    Z = h * A
    R = np.eye(2 * nA) + Z + Z @ Z / 2 + Z @ Z @ Z / 6 + Z @ Z @ Z @ Z / 24  # rk4's step map of y' = A y
    exact_map = np.linalg.matrix_power(R, n)
    assert np.abs(S - exact_map).max() / np.abs(exact_map).max() < 1e-8
    E = scipy.linalg.expm(n * h * A)
    method_error = np.abs(exact_map - E).max() / np.abs(E).max()
    assert np.abs(S - E).max() / np.abs(E).max() < 2 * method_error + 1e-8


def test_tip_and_point_derivatives_match_differences_of_their_positions():
    chain = arm()
    q0, v0 = start(chain)
    kw = dict(method="rk4", dt=1e-3, t_eval=T_EVAL, pressure=P_SINE)
    r = sensitivities(chain, q0, v0, (0.0, 0.05), params=[("chamber_area", 1)], **kw)
    p, dp = tip_sensitivities(chain, r)
    tr = simulate(chain, q0, v0, (0.0, 0.05), **kw)
    assert np.allclose(p, [chain.tip_placement(q).translation for q in tr.q], rtol=0, atol=1e-15)
    e = 1e-4 * A0
    tips = [np.array([ch.tip_placement(q).translation for q in simulate(ch, q0, v0, (0.0, 0.05), **kw).q])
            for ch in (arm(3, A0 + e), arm(3, A0 - e))]
    fd = (tips[0] - tips[1]) / (2 * e)
    assert np.abs(fd - dp[:, :, -1]).max() < 1e-7 * np.abs(fd).max()
    # a point inside the arm: segment 1 at alpha = 0.5, the backbone's middle point there
    pm, dpm = tip_sensitivities(chain, r, segment=1, alpha=0.5)
    assert np.allclose(pm, [chain.backbone(q, 3)[1, 1] for q in tr.q], rtol=0, atol=1e-15)
    mids = [np.array([ch.backbone(q, 3)[1, 1] for q in simulate(ch, q0, v0, (0.0, 0.05), **kw).q])
            for ch in (arm(3, A0 + e), arm(3, A0 - e))]
    fd = (mids[0] - mids[1]) / (2 * e)
    assert np.abs(fd - dpm[:, :, -1]).max() < 1e-7 * np.abs(fd).max()
    eq = 1e-6  # and an initial-state column, against runs from perturbed starts
    c = r.columns.index("q0[4]")
    dq = np.zeros(chain.nv)
    dq[4] = eq
    mids = [np.array([chain.backbone(q, 3)[1, 1] for q in simulate(chain, q0 + s_ * dq, v0, (0.0, 0.05), **kw).q])
            for s_ in (1, -1)]
    fd = (mids[0] - mids[1]) / (2 * eq)
    assert np.abs(fd - dpm[:, :, c]).max() < 1e-7 * np.abs(fd).max()
    # a chosen subset of the initial columns: the same numbers as those columns of the full set
    sub = sensitivities(chain, q0, v0, (0.0, 0.05), initial=["v0[5]", "q0[2]"], params=[("chamber_area", 1)], **kw)
    assert sub.columns == ["v0[5]", "q0[2]", "chamber_area[1]"]
    full = [r.columns.index(c) for c in sub.columns]
    assert np.array_equal(sub.S, r.S[:, :, full])


def test_bad_input_is_refused_by_name():
    chain = arm()
    q0, v0 = start(chain)
    call = lambda **kw: sensitivities(chain, kw.pop("q0", q0), kw.pop("v0", v0), (0.0, 0.01),
                                      **{"method": "rk4", "dt": 1e-3, **kw})
    refused(lambda: call(params=[("stiffness", 0)]), "stiffness")
    refused(lambda: call(params=[("gravity", 3)]), "axis")
    stiff = Chain([Segment(**SEG, extensible=False) for _ in range(2)])
    refused(lambda: sensitivities(stiff, stiff.neutral(), np.zeros(stiff.nv), (0, 0.01), method="rk4", dt=1e-3,
                                  params=[("length", 1)]), "inextensible")
    refused(lambda: call(params=[("chamber_area", 3)]), "segment")
    refused(lambda: call(params=[("chamber_area", 0), ("chamber_area", 0)]), "twice")
    refused(lambda: call(params="chamber_area"), "params")
    refused(lambda: call(initial=False), "nothing to differentiate")
    refused(lambda: call(initial=["w0[1]"]), "initial[0]")
    refused(lambda: call(initial=["q0[1]", "q0[1]"]), "twice")
    refused(lambda: call(initial="q0[1]"), "initial")
    refused(lambda: call(q0=np.zeros(5)), "q0")
    refused(lambda: call(v0=np.zeros(4)), "v0")
    refused(lambda: call(method="radau5"), "method")
    refused(lambda: call(dt=None), "dt")
    refused(lambda: call(steps=[0.0, 0.005, 0.004, 0.01]), "steps")
    refused(lambda: call(steps=[0.0, 0.005]), "steps")
    refused(lambda: call(pressure=lambda t, q, v: np.zeros(9)), "pressure")
    from qchain.sim.budget import Budget, BudgetError

    refused(lambda: call(dt=1e-10), "max_steps", BudgetError)
    refused(lambda: call(budget=Budget(max_memory=1e4)), "max_memory", BudgetError)
    floating = Chain([Segment(**SEG)], base="floating")
    refused(lambda: sensitivities(floating, floating.neutral(), np.zeros(floating.nv), (0, 0.01), method="rk4",
                                  dt=1e-3), "floating")
    refused(lambda: tip_sensitivities(arm(2), call()), "nq")
    refused(lambda: tip_sensitivities(chain, call(), segment=3), "segment")
    refused(lambda: tip_sensitivities(chain, call(), segment=0, alpha=1.5), "alpha")
    refused(lambda: tip_sensitivities(chain, call(), segment=0, alpha=float("nan")), "alpha")


def test_a_run_leaving_the_domain_fails_with_its_samples_and_the_step():
    chain = arm(1)
    q0 = chain.neutral()
    v0 = np.array([0.0, 2e4, 0.0])  # a curvature rate (1/(m s)) that takes |kappa| r past 1 in about 3 ms
    r = sensitivities(chain, q0, v0, (0.0, 0.05), method="rk4", dt=1e-4)
    assert not r.success and r.status == -1 and "segment 0" in r.message and "step from" in r.message
    assert np.all(np.isfinite(r.S)) and r.t.size == r.S.shape[0] >= 1


def _tendon_arm(helical: bool, change=None):
    from qchain import Tendon

    tendons = [Tendon(radius=0.012, angle=0.0, end=1), Tendon(radius=0.01, angle=2.0, pitch=0.4 if helical else None)]
    return arm(change=change, tendons=tendons)


T_SINE = Sine(amplitude=[1.0, 0.5], frequency=4.0, phase=[0.0, 1.0], offset=[1.5, 1.0])  # N


@pytest.mark.parametrize("helical, params", [(True, [("youngs_modulus", 0), ("mass", 1), ("gravity", 2)]),
                                             (False, [("length", 1), ("damping", 2)])])
def test_tendon_tensions_sensitivities_against_differences_of_whole_runs(helical, params):
    """sensitivities(tension=): the run is simulate's with the same tensions, bit for bit, and
    the derivative of its samples (initial state and parameters) matches central differences
    of whole runs with the tensions on (the tendons' exact stiffness in the Jacobian)."""
    chain = _tendon_arm(helical)
    q0, v0 = start(chain)
    kw = dict(method="rk4", dt=1e-3, t_eval=T_EVAL, pressure=P_SINE, tension=T_SINE)
    r = sensitivities(chain, q0, v0, (0.0, 0.05), params=params, initial=["q0[1]", "q0[3]", "v0[7]"], **kw)
    tr = simulate(chain, q0, v0, (0.0, 0.05), **kw)
    assert r.success and np.array_equal(r.q, tr.q) and np.array_equal(r.v, tr.v)

    def samples(ch, q, v):
        s = simulate(ch, q, v, (0.0, 0.05), **kw)
        return np.concatenate([s.q, s.v], axis=1)

    def diff(run, h):  # fourth-order central difference: steps large enough that round-off stays below 1e-10
        return (8 * (run(h) - run(-h)) - (run(2 * h) - run(-2 * h))) / (12 * h)

    errs = {}
    for c, name in enumerate(r.columns):
        if name.startswith(("q0", "v0")):
            d = np.zeros(chain.nv)
            d[int(name[3:-1])] = 1.0
            fd = diff(lambda h: samples(chain, q0 + h * d, v0) if name[0] == "q" else samples(chain, q0, v0 + h * d), 1e-4)
        else:
            pname, j = name[:-1].split("[")
            j = int(j)
            value = -9.81 if pname == "gravity" else SEG[pname]
            fd = diff(lambda h: samples(_tendon_arm(helical, (pname, j, value + h)), q0, v0), 1e-4 * abs(value))
        an = r.S[:, :, c]
        errs[name] = np.abs(fd - an).max() / np.abs(an).max()
    assert max(errs.values()) < 1e-7, errs
    with pytest.raises(ValueError, match=r"tension\[1\] must be >= 0"):
        sensitivities(chain, q0, v0, (0.0, 0.05), **{**kw, "tension": np.array([1.0, -2.0])})
    if helical:
        with pytest.raises(ValueError, match="rest length's derivative with a helical tendon"):
            sensitivities(chain, q0, v0, (0.0, 0.05), params=[("length", 0)], **kw)
    with pytest.raises(ValueError, match="the chain has no tendons"):
        sensitivities(arm(), q0, v0, (0.0, 0.05), **kw)
