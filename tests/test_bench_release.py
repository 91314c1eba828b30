"""The MuJoCo rod of benchmarks/bench_release.py against beam theory, independently of qchain.

The rod's material is made 100x stiffer (E = 5e7 Pa) so that its own weight bends it by only
L / 500: the small-load limit where Euler-Bernoulli theory holds. N = 40 links.
"""

import sys
from pathlib import Path

import numpy as np
import pytest

mujoco = pytest.importorskip("mujoco")

sys.path.insert(0, str(Path(__file__).parents[1] / "benchmarks"))

import bench_release as br  # noqa: E402

N = 40
STIFF = dict(br.SCENE, E=5e7)  # Pa: static tip deflection 0.39 mm
DT = 1e-5  # s: below the Euler stability limit of the fastest link mode (~2.2e-5 s at N = 40, E = 5e7)


def _tip_z(model, data):
    mujoco.mj_kinematics(model, data)
    return float(data.site_xpos[model.site("tip").id][2])


@pytest.fixture(scope="module")
def static_tip():
    """Tip height at rest: the rod released with stiffness-proportional hinge damping (the
    first mode about critically damped), stepped for 0.25 s until nothing moves."""
    c = br.constants(STIFF)
    beta = 2.0 * 0.7 / (2.0 * np.pi * c["f1"])  # s: damping ratio 0.7 on the first mode
    model, data = br.mujoco_model(N, DT, "Euler", STIFF, damping=beta)
    mujoco.mj_step(model, data, nstep=int(round(0.25 / DT)))
    speed = float(np.max(np.abs(data.qvel)))
    return _tip_z(model, data), speed


def test_the_model_is_the_rod():
    model, data = br.mujoco_model(N, DT, "RK4", STIFF)
    c = br.constants(STIFF)
    h = STIFF["L"] / N
    assert model.nv == N and model.njnt == N
    np.testing.assert_allclose(model.body_mass[1:].sum(), c["mass"], rtol=1e-12)
    np.testing.assert_allclose(model.jnt_stiffness, [2 * c["EI"] / h] + [c["EI"] / h] * (N - 1), rtol=1e-12)
    np.testing.assert_allclose(model.jnt_axis, np.tile([0.0, 1.0, 0.0], (N, 1)))
    np.testing.assert_allclose(data.site_xpos[model.site("tip").id], [STIFF["L"], 0.0, 0.0], atol=1e-15)
    # every link carries the rod's rotary inertia rho I h = m r^2 / 4 about y, plus m h^2 / 12
    m = STIFF["rho"] * c["A"] * h
    np.testing.assert_allclose(model.body_inertia[1:, 1], m * (STIFF["r"] ** 2 / 4 + h * h / 12), rtol=1e-10)


@pytest.mark.slow
def test_static_deflection_matches_euler_bernoulli(static_tip):
    z, speed = static_tip
    assert speed < 1e-6  # at rest
    w = br.constants(STIFF)["w_static"]  # q L^4 / (8 EI) = 0.392 mm
    # The chain's linear deflection is the trapezoidal rule of the exact integral:
    # w (1 + 1/N^2); measured -z / w - 1 = 6.2e-4 = 1 / N^2.
    assert -z == pytest.approx(w, rel=2.0 / N**2)
    assert -z == pytest.approx(w * (1 + 1.0 / N**2), rel=1e-4)


def test_first_natural_frequency(static_tip):
    z_rest, _ = static_tip
    c = br.constants(STIFF)  # Euler-Bernoulli f1 = 31.3 Hz
    model, data = br.mujoco_model(N, DT, "Euler", STIFF)
    every = 10
    zs = []
    for _ in range(int(round(0.2 / (DT * every)))):  # about 6 periods of free oscillation about rest
        mujoco.mj_step(model, data, nstep=every)
        zs.append(_tip_z(model, data))
    s = np.array(zs) - z_rest
    t = DT * every * np.arange(1, len(s) + 1)
    k = np.flatnonzero((s[:-1] < 0) & (s[1:] >= 0))  # upward zero crossings
    tc = t[k] - s[k] * (t[k + 1] - t[k]) / (s[k + 1] - s[k])
    assert len(tc) >= 5
    f = (len(tc) - 1) / (tc[-1] - tc[0])
    # rotary inertia (Rayleigh beam) lowers it by ~0.4 %, the discretisation a little more:
    # measured f / f1 - 1 = -0.67 %
    assert f == pytest.approx(c["f1"], rel=0.02)
    # amplitude: released from straight, it swings about rest by about the static deflection
    # (measured 1.03 w: the higher modes add a little)
    assert np.max(np.abs(s)) == pytest.approx(c["w_static"], rel=0.1)


def test_release_run_samples_the_tip():
    res = br.mujoco_run(10, "RK4", 1e-3, 0.05)
    assert res["ok"], res["status"]
    assert res["tips"].shape == (6, 3)
    np.testing.assert_allclose(res["tips"][0], [br.SCENE["L"], 0.0, 0.0], atol=1e-15)
    assert np.all(res["tips"][:, 1] == 0.0)  # planar
    assert np.all(np.diff(res["tips"][:, 2]) < 0)  # it falls
    unstable = br.mujoco_run(10, "Euler", 5e-3, 0.2)  # far above the explicit stability limit
    assert not unstable["ok"] and unstable["status"].startswith("unstable")
    a = np.zeros((3, 3))
    b = a + [0.0, 3e-3, 4e-3]
    assert br.tip_rms(a, b) == pytest.approx(5e-3)
    np.testing.assert_allclose(br.richardson(a, b), (4 * b - a) / 3)


def test_order_and_extrapolation_of_a_known_series():
    """Tracks x_N = x* + c / N^p: the observed order is p and Richardson at p returns x*."""
    rng = np.random.default_rng(1)
    exact, c = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    for p in (1.0, 2.0):
        x = {N: exact + c / N**p for N in (100, 200, 400)}
        assert br.observed_order(x[100], x[200], x[400]) == pytest.approx(p, abs=1e-12)
        np.testing.assert_allclose(br.richardson(x[200], x[400], p), exact, atol=1e-14)


def test_reference_cache_is_keyed_by_its_parameters(tmp_path):
    calls = []

    def compute(value):
        def f():
            calls.append(value)
            return np.full((3, 3), value), 0.5
        return f

    tips, cpu, hit = br.cached_track(tmp_path, "track", dict(N=100, dt=1e-5), compute(1.0))
    assert not hit and calls == [1.0] and cpu == 0.5
    tips2, cpu2, hit2 = br.cached_track(tmp_path, "track", dict(N=100, dt=1e-5), compute(2.0))
    assert hit2 and calls == [1.0] and cpu2 == 0.5
    np.testing.assert_array_equal(tips2, tips)
    tips3, _, hit3 = br.cached_track(tmp_path, "track", dict(N=100, dt=5e-6), compute(3.0))  # another step
    assert not hit3 and calls == [1.0, 3.0] and np.all(tips3 == 3.0)
    _, _, hit4 = br.cached_track(None, "track", dict(N=100, dt=1e-5), compute(4.0))  # no cache: always computed
    assert not hit4 and calls[-1] == 4.0


def test_sweep_measures_time_convergence_against_its_finest_run():
    """A sweep's ``time_conv_m`` is each run's RMS distance to the finest successful run (not
    to its neighbour, which can share its error); it stops after neighbours within ``STOP``
    and after a run over the budget."""
    offsets = {1e-1: 1e-3, 3e-2: 0.9e-3, 1e-2: 2e-4, 1e-3: 1e-6, 1e-4: 0.0, 1e-5: 0.0}  # m, along the track
    base = np.zeros((4, 3))

    def runner(v, fail=()):
        return dict(tips=base + offsets[v], cost=1e-3, repeats=1, ok=v not in fail, status="ok")

    rows = br.sweep(runner, list(offsets), "rtol", budget=10.0, T=1.0)
    # 1e-3 and 1e-4 are neighbours within STOP (1e-6 m * sqrt(3) apart < 5e-6): 1e-5 never runs
    assert [r["value"] for r in rows] == [1e-1, 3e-2, 1e-2, 1e-3, 1e-4]
    conv = [r["time_conv_m"] for r in rows]
    # 1e-1 is 0.17 mm from its neighbour (within 0.2 mm), yet 1.7 mm from the finest
    np.testing.assert_allclose(conv[:4], np.sqrt(3) * np.array([1e-3, 0.9e-3, 2e-4, 1e-6]), rtol=1e-12)
    assert br.tip_rms(rows[0]["tips"], rows[1]["tips"]) < br.CONVERGED < conv[0]
    assert np.isnan(conv[4])  # the finest has no finer run
    failed = br.sweep(lambda v: runner(v, fail=(1e-4,)), list(offsets), "rtol", budget=10.0, T=1.0)
    # a failed run is neither measured nor the finest: the last successful run is
    assert np.isnan(failed[4]["time_conv_m"]) and failed[-1]["value"] == 1e-5
    assert failed[3]["time_conv_m"] == pytest.approx(np.sqrt(3) * 1e-6)
    costly = br.sweep(lambda v: dict(runner(v), cost=20.0), list(offsets), "rtol", budget=10.0, T=1.0)
    assert len(costly) == 1 and np.isnan(costly[0]["time_conv_m"])


def test_headline_ratio_is_judged_on_runs_timed_side_by_side(monkeypatch):
    """``side_by_side`` times each headline run in turn with MuJoCo's and takes the median of
    the rounds' ratios, which cancels a drift of the machine's speed that the sweep costs,
    taken minutes apart, carry; the headline's verdict reads that ratio."""
    drift = iter(np.repeat([1.0, 2.0, 1.5, 1.2, 1.8], 2))  # the machine's speed, round by round

    def rerun(r, T, fixed):
        return lambda: r["cost"] * next(drift)

    monkeypatch.setattr(br, "_rerun", rerun)
    best = {"reduced": dict(cost=0.4), "mujoco": dict(cost=1.0)}
    side = br.side_by_side(best, 1.0, (), rounds=5)
    assert side["reduced"]["ratio"] == pytest.approx(0.4) and side["reduced"]["q3"] == pytest.approx(0.4)
    assert side["reduced"]["mujoco"] == pytest.approx(1.5)  # the median cost, drift and all
    assert br.side_by_side({"reduced": dict(cost=0.4), "mujoco": None}, 1.0, ()) == {}
    row = dict(code="qchain", model="n=10", method="radau5", setting="rtol=0.1", rms_error_m=9e-4, max_error_m=2e-3,
               time_conv_m=1e-4, cpu_per_sim_s=0.6, role="sweep", ok=True)
    mj = dict(row, code="mujoco", cpu_per_sim_s=1.0)
    lines = br.headline([row, mj], {"reduced": row, "mujoco": mj}, ratios={"qchain reduced": 0.5}, side=side)
    verdict = next(line for line in lines if "ratio qchain reduced" in line)
    assert "0.4 side by side" in verdict and "sweeps' costs give 0.6" in verdict and "target <= 0.5: met" in verdict


def test_extensible_rod_is_the_rod_with_slides():
    """Reference C's chain: a slide (EA/h, 2 EA/h at the clamp) before every hinge."""
    model, data = br.mujoco_model(N, DT, "RK4", STIFF, extensible=True)
    c = br.constants(STIFF)
    h = STIFF["L"] / N
    assert model.nv == 2 * N and model.njnt == 2 * N
    slides = model.jnt_type == mujoco.mjtJoint.mjJNT_SLIDE
    hinges = model.jnt_type == mujoco.mjtJoint.mjJNT_HINGE
    assert slides.sum() == N and hinges.sum() == N
    np.testing.assert_allclose(model.jnt_stiffness[slides], [2 * c["EA"] / h] + [c["EA"] / h] * (N - 1), rtol=1e-12)
    np.testing.assert_allclose(model.jnt_stiffness[hinges], [2 * c["EI"] / h] + [c["EI"] / h] * (N - 1), rtol=1e-12)
    np.testing.assert_allclose(model.jnt_axis[slides], np.tile([1.0, 0.0, 0.0], (N, 1)))
    np.testing.assert_allclose(model.body_mass[1:].sum(), c["mass"], rtol=1e-12)
    np.testing.assert_allclose(data.site_xpos[model.site("tip").id], [STIFF["L"], 0.0, 0.0], atol=1e-15)


def test_extensible_rod_hanging_stretches_as_the_continuum():
    """Gravity along the rod (+x): at rest, slide i carries the links beyond it, and the tip
    moves by the continuum's rho g L^2 / (2 E) (exact for this chain: the clamp's 2 EA/h makes
    the discrete sum N^2 / 2 exactly). MuJoCo's own forces must balance there (qacc = 0)."""
    model, data = br.mujoco_model(N, DT, "RK4", br.SCENE, extensible=True)
    model.opt.gravity[:] = (br.SCENE["g"], 0.0, 0.0)
    c = br.constants(br.SCENE)
    h, m = br.SCENE["L"] / N, br.SCENE["rho"] * c["A"] * br.SCENE["L"] / N
    slides = np.flatnonzero(model.jnt_type == mujoco.mjtJoint.mjJNT_SLIDE)
    tension = (N - np.arange(N)) * m * br.SCENE["g"]
    data.qpos[model.jnt_qposadr[slides]] = tension / model.jnt_stiffness[slides]
    mujoco.mj_forward(model, data)
    assert np.max(np.abs(data.qacc)) < 1e-9  # m/s^2, rad/s^2: at rest to rounding
    stretch = br.SCENE["rho"] * br.SCENE["g"] * br.SCENE["L"] ** 2 / (2 * br.SCENE["E"])  # 3.9e-4 m
    assert data.site_xpos[model.site("tip").id][0] - br.SCENE["L"] == pytest.approx(stretch, rel=1e-12)
    data.qpos[model.jnt_qposadr[slides]] *= 1.01  # every slide 1 % beyond: only the clamp's net force
    mujoco.mj_forward(model, data)  # changes (-1 % of the weight), pulling the whole chain back at g / 100
    np.testing.assert_allclose(data.qacc[model.jnt_dofadr[slides]], [-0.01 * br.SCENE["g"]] + [0.0] * (N - 1),
                               atol=1e-9)


@pytest.mark.parametrize("n", [5, 10])
def test_release_bend_bounds_the_segments_bend_of_a_converged_release(n):
    """``release_bend(n)``, the bend the benchmark's nodes are sized for (twice the root
    segment's static bend), against the largest segment bend of a converged release (qchain's
    planar extensible rod, radau5 at rtol 1e-8): the release stays within it, and the bound is
    not vacuous (the release reaches more than half of it)."""
    import bench_cosserat as bc

    bound = br.release_bend(n)
    res = bc.qchain_run(n, 1.0, "radau5", scene=br.SCENE, extensible=True, planar=True,
                        node_tolerance=br.NODE_TOLERANCE, max_bend=bound, rtol=1e-8, atol=1e-10)
    assert res["ok"], res["status"]
    assert 0.5 * bound < res["max_bend"] <= bound
    assert res["nodes"] == 3  # 1e-6 at 0.157 rad (n = 10) and 0.314 rad (n = 5); 4 at l0 / r_s
