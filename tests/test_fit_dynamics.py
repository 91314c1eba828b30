"""Dynamic calibration (qchain.fit.fit on Measurements): a run of a scene with hidden
parameters, its tip measured with mocap-like noise and its pressures, written as a ROS 2 bag
as a lab would record it, read back and fitted from a wrong start; the exact Jacobian
against differences of whole runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_fit_statics import SCENE, TRUTH, _scene

from qchain.fit import fit, read_bag
from qchain.fit.dynamics import dynamic_residuals
from qchain.fit.fitting import _model_params
from qchain.fit.parameters import column_map, fit_parameters
from qchain.recording.ros2 import BagWriter, stamp

T0 = 1_700_000_000.0
KEYS = ["segments[0].youngs_modulus", "segments[1].youngs_modulus", "segments[1].chamber_area"]


def _pressures(t):
    """Chamber 1 of every segment swept, the others steady: a 1 Hz swing."""
    p = np.zeros((t.size, 9))
    p[:, 0::3] = (2e4 * (1 - np.cos(2 * np.pi * t)))[:, None]
    p[:, 1::3] = 1e4
    return p


def _true_run(tmp_path: Path, duration: float, **scene):
    """The true scene (``scene``: its values changed) run from rest at its first pressures'
    equilibrium: ``(chain, t_p, table, t, traj)``, pressures at 50 Hz on ``t_p``, samples at
    100 Hz on ``t`` (dopri5, rtol 1e-10)."""
    from qchain import equilibrium, simulate
    from qchain.scene.reading import load_scene
    from qchain.sim.inputs import Table

    chain = load_scene(_scene(tmp_path, "truth.toml", **scene)).build(reduce=False).chain
    t_p = np.arange(0.0, duration + 1e-9, 0.02)
    table = Table(t_p, _pressures(t_p))
    q0 = equilibrium(chain, table(0.0)).q
    t = np.arange(0.005, duration, 0.01)
    traj = simulate(chain, q0, np.zeros(chain.nv), (0.0, duration), pressure=table, method="dopri5", rtol=1e-10,
                    atol=1e-12, t_eval=t)
    return chain, t_p, table, t, traj


def _lab_bag(tmp_path: Path, noise: float, seed: int = 0, duration: float = 1.0) -> Path:
    """The true scene run from rest, its tip at 100 Hz with ``noise`` (m), pressures at 50 Hz."""
    chain, t_p, table, t, traj = _true_run(tmp_path, duration)
    tip = np.array([chain.points(q, [(-1, 1.0)])[0] for q in traj.q])
    tip += noise * np.random.default_rng(seed).normal(size=tip.shape)
    path = tmp_path / f"lab-{seed}.mcap"
    with open(path, "wb") as fh:
        w = BagWriter(fh)
        for k, tk in enumerate(t_p):
            w.write("/pressures", "sensor_msgs/msg/JointState", T0 + tk,
                    {"header": {"stamp": stamp(T0 + tk)}, "name": [f"p{i}" for i in range(9)],
                     "effort": list(table.values[k])})
        for k, tk in enumerate(t):
            w.write("/mocap/tip", "geometry_msgs/msg/PoseStamped", T0 + tk,
                    {"header": {"stamp": stamp(T0 + tk), "frame_id": "world"},
                     "pose": {"position": dict(zip("xyz", map(float, tip[k]))),
                              "orientation": {"w": 1.0}}})
        w.finish()
    return path


def test_the_dynamic_jacobian_is_the_derivative_of_the_residuals(tmp_path):
    import tomllib

    from qchain.scene.reading import load_scene

    meas = read_bag(_lab_bag(tmp_path, noise=0.0, duration=0.3), pressure_topic="/pressures",
                    pose_topic="/mocap/tip")
    raw = tomllib.loads(_scene(tmp_path).read_text())
    params = fit_parameters(raw, KEYS + ["segments[*].mass", "gravity[2]"])
    pairs = _model_params(params)

    def residuals(x):
        from qchain.batch.sweep_spec import apply_values
        from qchain.fit.parameters import scene_values
        from qchain.scene.reading import parse_scene
        import tomli_w

        chain = parse_scene(tomli_w.dumps(apply_values(raw, scene_values(params, x)))).build(reduce=False).chain
        return dynamic_residuals(chain, meas, pairs, column_map(params, pairs), rtol=1e-11, atol=1e-13)

    x0 = np.array([p.start for p in params])
    r, J = residuals(x0)
    # the true scene explains its own noise-free run, to the bag's clock: stamps of 1.7e9 s held in
    # float64 are 2.4e-7 s apart, and the tip moves at up to 0.2 m/s
    assert np.abs(r).max() < 1e-7
    for j in range(len(params)):
        # each run takes its own adaptive steps (rtol 1e-11): a step of 1e-3 keeps that noise
        # below 1e-5 of the difference, and the truncation error (h^2) below 1e-6
        h = 1e-3 * abs(x0[j])
        e = np.zeros_like(x0)
        e[j] = h
        fd = (residuals(x0 + e)[0] - residuals(x0 - e)[0]) / (2 * h)
        assert np.abs(J[:, j] - fd).max() <= 1e-5 * np.abs(fd).max(), params[j].key


def test_a_lab_bag_fits_back_to_the_hidden_parameters(tmp_path):
    meas = read_bag(_lab_bag(tmp_path, noise=5e-4), pressure_topic="/pressures", pose_topic="/mocap/tip")
    scene = _scene(tmp_path, E0=1.0e5, E1=1.0e5, A=4.0e-5)
    rep = fit(scene, [meas], KEYS)
    res = rep.result
    truth = np.array([TRUTH["E0"], TRUTH["E1"], TRUTH["A"]])
    assert res.success and np.all(np.isfinite(res.stderr))
    assert np.all(np.abs(res.x - truth) <= 3 * res.stderr), (res.x, truth, res.stderr)
    assert 4e-4 < res.sigma < 6e-4


def test_the_fits_noise_options_are_checked_where_they_enter(tmp_path):
    from qchain.fit import MeasurementError

    meas = read_bag(_lab_bag(tmp_path, noise=0.0, duration=0.3), pressure_topic="/pressures",
                    pose_topic="/mocap/tip")
    scene = _scene(tmp_path)
    with pytest.raises(ValueError, match=r"covariance must be 'inputs', 'iid' or 'hac', got 'white'"):
        fit(scene, [meas], KEYS, covariance="white")
    with pytest.raises(ValueError, match=r"input_draws must be an integer >= 2, got 1"):
        fit(scene, [meas], KEYS, input_draws=1)
    with pytest.raises(ValueError, match=r"pressure_sigma must be finite and >= 0 .*, got -300"):
        fit(scene, [meas], KEYS, pressure_sigma=-300.0)
    for bad in (0.0, 30.0):  # the pressures are sampled at 50 Hz: Nyquist 25 Hz
        with pytest.raises(MeasurementError, match=r"pressure_filter: cutoff .* must lie in \(0, 25\) Hz"):
            fit(scene, [meas], KEYS, pressure_filter=bad)


# ---------------------------------------------------------------------------------------
# full coordinates as the measurement
# ---------------------------------------------------------------------------------------


def _coordinate_run(tmp_path, noise_l: float, noise_u: float, seed: int = 0, duration: float = 1.0, **scene):
    """The true scene run from rest; its coordinates at 100 Hz with noise (m for l, 1/m for ux,
    uy), its pressures at 50 Hz: a Measurements of coordinates."""
    from qchain.fit import Measurements

    chain, _, table, t, traj = _true_run(tmp_path, duration, **scene)
    rng = np.random.default_rng(seed)
    sd = np.tile([noise_l, noise_u, noise_u], chain.n)
    q = traj.q + sd * rng.normal(size=traj.q.shape)
    return Measurements(t=t, pressures=table, coordinates=q, source=f"coordinates-{seed}")


def test_the_coordinate_jacobian_is_the_derivative_of_the_residuals(tmp_path):
    import tomllib

    from qchain.batch.sweep_spec import apply_values
    from qchain.fit.measurements import coordinate_scale
    from qchain.fit.parameters import scene_values
    from qchain.scene.reading import parse_scene
    import tomli_w

    meas = _coordinate_run(tmp_path, 0.0, 0.0, duration=0.3)
    raw = tomllib.loads(_scene(tmp_path).read_text())
    params = fit_parameters(raw, KEYS + ["segments[*].mass", "segments[0].damping", "gravity[2]"])
    pairs = _model_params(params)
    chain0 = parse_scene(tomli_w.dumps(raw)).build(reduce=False).chain
    from dataclasses import replace

    meas = replace(meas, coordinate_scale=coordinate_scale(chain0, meas)[0])  # held for the whole fit

    def residuals(x):
        chain = parse_scene(tomli_w.dumps(apply_values(raw, scene_values(params, x)))).build(reduce=False).chain
        return dynamic_residuals(chain, meas, pairs, column_map(params, pairs), rtol=1e-11, atol=1e-13)

    x0 = np.array([p.start for p in params])
    r, J = residuals(x0)
    assert r.shape == (meas.n_samples * 9,) and J.shape == (r.size, len(params))
    assert np.abs(r).max() < 1e-8  # the true scene explains its own noise-free coordinates
    for j in range(len(params)):
        h = 1e-3 * abs(x0[j]) if x0[j] != 0 else 1e-3
        e = np.zeros_like(x0)
        e[j] = h
        fd = (residuals(x0 + e)[0] - residuals(x0 - e)[0]) / (2 * h)
        assert np.abs(fd).max() > 0, params[j].key
        assert np.abs(J[:, j] - fd).max() <= 1e-5 * np.abs(fd).max(), params[j].key


def test_measured_coordinates_fit_back_to_the_hidden_parameters(tmp_path):
    # noise: 0.1 mm on a segment's length, 0.05 1/m on a curvature (0.25 mm at a 0.1 m segment's tip)
    meas = _coordinate_run(tmp_path, 1e-4, 0.05, seed=3)
    scene = _scene(tmp_path, E0=1.0e5, E1=1.0e5, A=4.0e-5)
    rep = fit(scene, [meas], KEYS, covariance="iid")
    res = rep.result
    truth = np.array([TRUTH["E0"], TRUTH["E1"], TRUTH["A"]])
    assert res.success and np.all(np.isfinite(res.stderr))
    assert np.all(np.abs(res.x - truth) <= 2 * res.stderr), (res.x, truth, res.stderr)
    assert np.all(res.stderr < 0.05 * truth)  # the coordinates do fix them
    # the report reads coordinate experiments: RMS, the model's coordinates, the picture
    (before, after), = [rms for rms in __import__("qchain.fit.report", fromlist=["x"]).experiment_rms(rep)]
    assert after < before
    qf = rep.predicted_coordinates("fitted")[0]
    assert qf.shape == meas.coordinates.shape and rep.predicted("fitted") == [None]
    assert np.sqrt(np.mean((qf - meas.coordinates)[:, 1::3] ** 2)) < 0.08  # about the 0.05 1/m noise
    d = rep.to_dict()
    assert d["experiments"][0]["coordinates"] == 9 and d["experiments"][0]["points"] == 0
    assert any("9 coordinates" in line for line in rep.summary())
    rep.plot(tmp_path / "fit.png")
    assert (tmp_path / "fit.png").stat().st_size > 1000


def test_bad_measured_coordinates_are_refused_where_they_enter(tmp_path):
    from qchain.fit import MeasurementError, Measurements

    meas = _coordinate_run(tmp_path, 0.0, 0.0, duration=0.1)
    scene = _scene(tmp_path)
    q = meas.coordinates.copy()
    q[4, 2] = np.nan
    with pytest.raises(MeasurementError, match=r"coordinate 2 of sample 4 \(t = 0\.045 s\) is nan"):
        Measurements(t=meas.t, pressures=meas.pressures, coordinates=q, source="lab")
    with pytest.raises(MeasurementError, match=r"coordinates must have shape \(10, nq\)"):
        Measurements(t=meas.t, pressures=meas.pressures, coordinates=q[:5], source="lab")
    short = Measurements(t=meas.t, pressures=meas.pressures, coordinates=meas.coordinates[:, :6], source="lab")
    with pytest.raises(MeasurementError, match=r"lab: 6 coordinates a sample, the model has nq = 9"):
        fit(scene, [short], KEYS)
    with pytest.raises(MeasurementError, match=r"coordinate_scale must be one number or 9 .*got -1"):
        Measurements(t=meas.t, pressures=meas.pressures, coordinates=meas.coordinates, coordinate_scale=-1)


def test_an_inextensible_arms_held_lengths_are_left_out_and_said(tmp_path):
    from qchain.fit import Measurements
    from qchain.fit.measurements import coordinate_scale
    from qchain.scene.reading import load_scene

    path = tmp_path / "inext.toml"
    path.write_text(SCENE.format(**TRUTH).replace("damping = 0.02", "damping = 0.02\nextensible = false"))
    chain = load_scene(path).build(reduce=False).chain
    assert not chain.active[0::3].any()
    meas = _coordinate_run(tmp_path, 0.0, 0.0, duration=0.1)
    w, held = coordinate_scale(chain, meas)
    assert held == ["segment 0, l", "segment 1, l", "segment 2, l"]
    assert np.all(w[0::3] == 0) and np.allclose(w[1::3], 0.1 ** 2 / 2)
    m2 = Measurements(t=meas.t, pressures=meas.pressures, coordinates=meas.coordinates, coordinate_scale=0.0 + 1e-2)
    w2, _ = coordinate_scale(chain, m2)
    assert np.all(w2[0::3] == 0) and np.all(w2[1::3] == 1e-2)
