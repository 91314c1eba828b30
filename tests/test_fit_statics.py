"""Static calibration (qchain.fit.fit on StaticPoses): synthetic equilibrium poses of a scene
with hidden parameters, fitted from a wrong start; the exact Jacobian against finite
differences; what statics cannot tell apart; the fitted scene written and read back."""

from __future__ import annotations

import tomllib
import warnings

import numpy as np
import pytest

from qchain.fit import fit
from qchain.fit.solve import FitWarning
from qchain.fit.statics import StaticPoses, static_residuals

SCENE = """
name = "two-table arm for calibration"
gravity = [0.0, 0.0, -9.81]

[[segments]]
length = 0.1
radius = 0.015
mass = 0.05
chamber_area = 4.5e-5
chamber_radius = 0.0085
youngs_modulus = {E0}
damping = 0.02

[[segments]]
count = 2
length = 0.1
radius = 0.015
mass = 0.05
chamber_area = {A}
chamber_radius = 0.0085
youngs_modulus = {E1}
damping = 0.02

[base]
type = "fixed"
position = [0.0, 0.0, 0.5]
rpy = [3.141592653589793, 0.0, 0.0]

[pressure]
type = "constant"
value = [0.0, 0.0, 0.0,  0.0, 0.0, 0.0,  0.0, 0.0, 0.0]

[simulation]
duration = 1.0
"""
TRUTH = dict(E0=1.3e5, E1=0.8e5, A=5.0e-5)
PRESSURES = np.array([[p1, p2, p3] * 3 for p1, p2, p3 in
                      [(0, 0, 0), (3e4, 0, 0), (0, 3e4, 0), (0, 0, 3e4), (2e4, 2e4, 0), (4e4, 1e4, 0),
                       (0, 2e4, 4e4), (3e4, 3e4, 3e4)]])


def _scene(tmp_path, name="arm.toml", **kw):
    path = tmp_path / name
    path.write_text(SCENE.format(**{**TRUTH, **kw}))
    return path


def _poses(tmp_path, noise=0.0, seed=0, where=((-1, 1.0), (0, 1.0))):
    """Equilibria of the true scene, measured at ``where`` with Gaussian noise (m)."""
    from qchain import equilibrium
    from qchain.scene.reading import load_scene

    chain = load_scene(_scene(tmp_path, "truth.toml")).build(reduce=False).chain
    rng = np.random.default_rng(seed)
    pts = np.array([chain.points(equilibrium(chain, p).q, where) for p in PRESSURES])
    return StaticPoses(PRESSURES, pts + noise * rng.normal(size=pts.shape), where=where, source="synthetic")


def test_the_static_jacobian_is_the_derivative_of_the_residuals(tmp_path):
    from qchain.scene.reading import load_scene

    chain = load_scene(_scene(tmp_path)).build(reduce=False).chain
    poses = _poses(tmp_path)
    pairs = [("youngs_modulus", 0), ("youngs_modulus", 2), ("chamber_area", 1), ("mass", 1), ("gravity", None)]
    r, J = static_residuals(chain, poses, pairs)
    assert np.abs(r).max() < 1e-9  # the true scene explains its own poses
    # central differences of the equilibria of chains rebuilt with each parameter moved
    from qchain import Chain, Segment, equilibrium

    def rebuilt(kind, seg, h):
        segs = []
        for j, s in enumerate(chain.segments):
            kw = dict(length=s.length, radius=s.radius, mass=s.mass, chamber_area=s.chamber_area,
                      chamber_radius=s.chamber_radius, youngs_modulus=s.youngs_modulus, damping=s.damping,
                      nodes=len(s.alpha_nodes))
            if kind != "gravity" and j == seg:
                kw[kind] += h
            segs.append(Segment(**kw))
        g = np.array(chain.gravity)
        if kind == "gravity":
            g[seg] += h
        return Chain(segs, base="fixed", base_placement=chain.base_placement, gravity=g)

    cols = [("youngs_modulus", 0), ("youngs_modulus", 2), ("chamber_area", 1), ("mass", 1),
            ("gravity", 0), ("gravity", 1), ("gravity", 2)]
    for c, (kind, seg) in enumerate(cols):
        x0 = getattr(chain.segments[seg], kind) if kind != "gravity" else chain.gravity[seg]
        h = 1e-4 * (abs(x0) or 1.0)  # the equilibria are solved to ~1e-9: a smaller step is noise
        fd = []
        for s in (+1, -1):
            ch = rebuilt(kind, seg, s * h)
            fd.append(np.concatenate([ch.points(equilibrium(ch, p, tol=1e-13).q, poses.where).ravel()
                                      for p in PRESSURES]))
        fd = (fd[0] - fd[1]) / (2 * h)
        assert np.abs(J[:, c] - fd).max() <= 1e-6 * np.abs(fd).max() + 1e-12, (kind, seg)


def test_a_wrong_start_fits_back_to_the_hidden_parameters(tmp_path):
    scene = _scene(tmp_path, E0=1.0e5, E1=1.0e5, A=4.0e-5)  # the wrong first guess
    poses = _poses(tmp_path, noise=5e-4)
    rep = fit(scene, [poses], ["segments[0].youngs_modulus", "segments[1].youngs_modulus",
                               "segments[1].chamber_area"])
    res = rep.result
    truth = np.array([TRUTH["E0"], TRUTH["E1"], TRUTH["A"]])
    assert res.success and np.all(np.isfinite(res.stderr))
    assert np.all(np.abs(res.x - truth) <= 3 * res.stderr), (res.x, truth, res.stderr)
    assert 3e-4 < res.sigma < 7e-4  # the noise, 0.5 mm
    out = rep.write_scene(tmp_path / "fitted.toml")
    text = out.read_text()
    assert text.startswith("# fitted by qchain.fit from") and "segments[1].chamber_area =" in text
    back = tomllib.loads(text)
    assert back["segments"][1]["youngs_modulus"] == pytest.approx(res.x[1], rel=1e-9)
    from qchain.scene.reading import load_scene

    load_scene(out).build()  # the fitted scene is a scene


def test_statics_cannot_tell_stiffness_from_weight_and_gain_together(tmp_path):
    """Scaling E, the masses and the chamber areas together leaves every static pose as it
    is: the fit names the three."""
    scene = _scene(tmp_path, E0=1.0e5, E1=1.0e5, A=4.5e-5)  # every table alike: [*] keys apply
    poses = _poses(tmp_path, noise=1e-4)
    with pytest.warns(FitWarning, match=r"the data cannot tell apart segments\[\*\]\.youngs_modulus, "
                                        r"segments\[\*\]\.mass, segments\[\*\]\.chamber_area"):
        rep = fit(scene, [poses], ["segments[*].youngs_modulus", "segments[*].mass", "segments[*].chamber_area"],
                  max_nfev=5)
    assert rep.result.unidentifiable == [["segments[*].youngs_modulus", "segments[*].mass",
                                          "segments[*].chamber_area"]]
    assert np.all(np.isinf(rep.result.stderr))


def test_measurements_in_millimetres_are_refused(tmp_path):
    from qchain.fit.measurements import MeasurementError

    poses = _poses(tmp_path)
    mm = StaticPoses(poses.pressures, 1e3 * poses.points, where=poses.where, source="lab.csv")
    with pytest.raises(MeasurementError, match=r"lab.csv: the point measured in pose \d is .* m from the base, and the "
                                               r"arm is 0\.3 m long: units that do not match \(mm for m\?\)"):
        fit(_scene(tmp_path), [mm], ["segments[0].youngs_modulus"])
    with pytest.raises(MeasurementError, match="too few for 9 parameters"):
        fit(_scene(tmp_path), [StaticPoses(poses.pressures[:1], poses.points[:1, :1], source="one")],
            [f"segments[{i}].{k}" for i in (0, 1) for k in ("youngs_modulus", "mass", "damping", "length")]
            + ["gravity[2]"])


@pytest.mark.slow
def test_two_standard_errors_cover_the_truth_in_repeated_noisy_experiments(tmp_path):
    """40 synthetic experiments (0.5 mm noise, seeds 0-39), each fitted from the same wrong
    start: each parameter within 2 standard errors of the truth in at least 85 % of them (95 %
    for a linear model; the modulus enters a pose as 1/E, and at 0.5 mm noise the standard
    errors are 2-6 % of the values, where that curvature shows), and the z-scores' RMS within
    0.75-1.35 (standard errors neither inflated nor too small)."""
    scene = _scene(tmp_path, E0=1.0e5, E1=1.0e5, A=4.0e-5)
    truth = np.array([TRUTH["E0"], TRUTH["E1"], TRUTH["A"]])
    z = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FitWarning)
        for seed in range(40):
            res = fit(scene, [_poses(tmp_path, noise=5e-4, seed=seed)],
                      ["segments[0].youngs_modulus", "segments[1].youngs_modulus", "segments[1].chamber_area"]).result
            assert res.success
            z.append((res.x - truth) / res.stderr)
    z = np.abs(np.array(z))
    assert np.all((z <= 2).mean(axis=0) >= 0.85), (z <= 2).mean(axis=0)
    rms = np.sqrt((z ** 2).mean(axis=0))
    assert np.all((rms > 0.75) & (rms < 1.35)), rms


def test_pressure_noise_enters_static_standard_errors_and_they_cover_the_truth(tmp_path):
    """Static poses whose held pressures were read with a sensor noise and their points with
    0.1 mm, fitted with that noise given (``pressure_sigma``: the inputs' term from the
    equilibria's exact pressure derivative, :func:`qchain.fit.statics.static_input_draws`):
    the standard errors grow with the pressure noise (1 kPa against 250 Pa), and at 1 kPa 2
    standard errors cover the truth in at least 85 % of 20 synthetic sets."""
    from qchain import equilibrium
    from qchain.scene.reading import load_scene

    chain = load_scene(_scene(tmp_path, "truth.toml")).build(reduce=False).chain
    where = ((-1, 1.0), (0, 1.0))
    true_p = PRESSURES + 2e4  # away from zero: a sensor reads a held pressure +- its noise
    pts = np.array([chain.points(equilibrium(chain, p).q, where) for p in true_p])
    scene = _scene(tmp_path, E0=1.0e5, E1=1.0e5, A=4.0e-5)
    keys = ["segments[0].youngs_modulus", "segments[1].youngs_modulus", "segments[1].chamber_area"]
    truth = np.array([TRUTH["E0"], TRUTH["E1"], TRUTH["A"]])
    s_x = 1e-4
    hits, se = np.zeros(3), {250.0: [], 1000.0: []}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FitWarning)
        for s_p, sets in ((1000.0, 20), (250.0, 6)):
            for seed in range(sets):
                rng = np.random.default_rng(100 + seed)
                poses = StaticPoses(true_p + s_p * rng.normal(size=true_p.shape),
                                    pts + s_x * rng.normal(size=pts.shape), where=where, source=f"set {seed}")
                res = fit(scene, [poses], keys, covariance="inputs", pressure_sigma=s_p, input_draws=100).result
                assert res.success
                se[s_p].append(res.stderr)
                if s_p == 1000.0:
                    hits += np.abs(res.x - truth) <= 2 * res.stderr
    assert np.all(hits / 20 >= 0.85), hits / 20
    # the moduli and the gain of the tables the pressures bend most feel the noise most (E1, A:
    # about 3x); segment 0's modulus, fixed mostly by the mid point, least
    grow = np.median(se[1000.0], axis=0) / np.median(se[250.0], axis=0)
    assert np.all(grow > 1.1) and np.all(grow[1:] > 2.5), grow
