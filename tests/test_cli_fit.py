"""``qchain fit FIT.toml``: a fit file on synthetic static poses (a CSV) and a short lab bag
fits and writes fitted.toml (a scene with the fitted values), fit.json (the same values) and
fit.png (a PNG of the stated size); bad fit files are refused with the key, the value and the
bound named, exit code 2 and nothing written."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
import tomllib

import numpy as np
import pytest
from test_fit_dynamics import _lab_bag
from test_fit_statics import TRUTH, _poses, _scene
from test_recording_ros2 import recorded  # noqa: F401  (the module fixture: a recording and its bag)

from qchain.cli.main import main
from qchain.fit.report import FIGURE_HEIGHT, FIGURE_WIDTH

START = dict(E0=1.0e5, E1=1.0e5, A=4.0e-5)
KEYS = ["segments[0].youngs_modulus", "segments[1].youngs_modulus", "segments[1].chamber_area"]


def _static_csv(tmp_path, noise=0.0):
    """The true scene's equilibria (tip and first segment's end) as a CSV: pressures p0..p8, points in mm."""
    poses = _poses(tmp_path, noise=noise)
    head = [f"p{i}" for i in range(9)] + ["tip_x", "tip_y", "tip_z", "mid_x", "mid_y", "mid_z"]
    rows = [",".join(head)]
    for p, x in zip(poses.pressures, poses.points):
        rows.append(",".join(f"{v:.17g}" for v in list(p) + list(x.reshape(-1) * 1e3)))
    path = tmp_path / "poses.csv"
    path.write_text("\n".join(rows) + "\n")
    return path


STATIC_EXPERIMENT = """
[[experiments]]
static_csv = "poses.csv"
pressures = ["p0", "p1", "p2", "p3", "p4", "p5", "p6", "p7", "p8"]
points = [["tip_x", "tip_y", "tip_z"], ["mid_x", "mid_y", "mid_z"]]
where = [[-1, 1.0], [0, 1.0]]
scale = 1e-3
"""


def _spec(tmp_path, body: str, parameters: str | None = None, name="fit.toml"):
    if parameters is None:
        parameters = "".join(f'\n[[parameters]]\nkey = "{k}"\n' for k in KEYS)
    path = tmp_path / name
    path.write_text(f'scene = "arm.toml"\n{parameters}\n{body}')
    return path


def _png_size(path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def test_a_fit_file_of_static_poses_fits_back_and_writes_its_outputs(tmp_path, capsys):
    _scene(tmp_path, "arm.toml", **START)
    _static_csv(tmp_path)
    spec = _spec(tmp_path, STATIC_EXPERIMENT + '\n[fit]\nmax_nfev = 40\n\n[output]\nfolder = "results"\n')
    assert main(["fit", str(spec)]) == 0
    out = capsys.readouterr().out
    assert "segments[0].youngs_modulus" in out and "std error" in out
    folder = tmp_path / "results"
    assert sorted(p.name for p in folder.iterdir()) == ["fit.json", "fit.png", "fitted.toml"]
    data = json.loads((folder / "fit.json").read_text())
    values = {p["key"]: p["value"] for p in data["parameters"]}
    truth = {KEYS[0]: TRUTH["E0"], KEYS[1]: TRUTH["E1"], KEYS[2]: TRUTH["A"]}
    for k in KEYS:  # no noise: the hidden values come back
        assert values[k] == pytest.approx(truth[k], rel=1e-6)
    assert {p["key"]: p["start"] for p in data["parameters"]} == {KEYS[0]: 1.0e5, KEYS[1]: 1.0e5, KEYS[2]: 4.0e-5}
    assert data["experiments"][0]["kind"] == "static"
    assert data["experiments"][0]["rms_fitted_m"] < 1e-6 < 1e-3 < data["experiments"][0]["rms_start_m"]
    assert data["counters"]["nfev"] >= 1 and data["cpu_s"] > 0
    corr = np.array(data["correlation"], dtype=float)
    assert corr.shape == (3, 3) and np.allclose(np.diag(corr), 1.0) and np.allclose(corr, corr.T)
    # the fitted scene loads, with the fitted values exactly as fit.json has them
    from qchain.scene.reading import load_scene

    text = (folder / "fitted.toml").read_text()
    raw = tomllib.loads(text)
    assert raw["segments"][0]["youngs_modulus"] == values[KEYS[0]]
    assert raw["segments"][1]["youngs_modulus"] == values[KEYS[1]]
    assert raw["segments"][1]["chamber_area"] == values[KEYS[2]]
    scene = load_scene(folder / "fitted.toml")
    assert scene.segments[2].youngs_modulus == values[KEYS[1]]
    assert _png_size(folder / "fit.png") == (round(FIGURE_WIDTH * 80), round(FIGURE_HEIGHT * 80))


def test_a_bag_and_static_poses_together(tmp_path, capsys):
    """Two experiments of two kinds in one fit: the picture has a column each, fit.json an
    entry each, and the fit lowers both residuals."""
    _scene(tmp_path, "arm.toml", **START)
    _static_csv(tmp_path)
    bag = _lab_bag(tmp_path, noise=5e-4, duration=0.3)
    spec = _spec(tmp_path, STATIC_EXPERIMENT + f'\n[[experiments]]\nbag = "{bag.name}"\npressure_topic = "/pressures"\n'
                 'pose_topic = "/mocap/tip"\n\n[fit]\nmax_nfev = 4\n')
    assert main(["fit", str(spec)]) == 0
    folder = tmp_path / "fit-fit"  # the default: beside the fit file
    data = json.loads((folder / "fit.json").read_text())
    assert [e["kind"] for e in data["experiments"]] == ["static", "dynamic"]
    for e in data["experiments"]:
        assert e["rms_fitted_m"] < e["rms_start_m"]
    assert data["experiments"][1]["samples"] == 30
    assert _png_size(folder / "fit.png") == (round(2 * FIGURE_WIDTH * 80), round(FIGURE_HEIGHT * 80))


@pytest.mark.parametrize("case, body, parameters, words", [
    ("unknown key", STATIC_EXPERIMENT + "\n[fit]\nmax_nfv = 3\n", None, ["fit.max_nfv", "did you mean 'max_nfev'"]),
    ("unknown experiment key", STATIC_EXPERIMENT.replace("scale =", "scael ="), None,
     ["experiments[0].scael", "did you mean 'scale'"]),
    ("two sources", STATIC_EXPERIMENT.replace('scale = 1e-3', 'scale = 1e-3\ncsv = "poses.csv"'), None,
     ["experiments[0]", "exactly one of the keys bag, recording, csv, static_csv", "2: csv, static_csv"]),
    ("no source", STATIC_EXPERIMENT.replace('static_csv = "poses.csv"\n', ''), None,
     ["experiments[0]", "exactly one of the keys", "none of them"]),
    ("a key of another kind", STATIC_EXPERIMENT + 'pressure_topic = "/p"\n', None,
     ["experiments[0].pressure_topic", "keys of a static_csv experiment", "a key of bag experiments"]),
    ("a key the scene lacks", STATIC_EXPERIMENT, '[[parameters]]\nkey = "segments[5].mass"\n',
     ["parameters[0]", "segments[5].mass", "2 [[segments]] tables"]),
    ("not a fit parameter", STATIC_EXPERIMENT, '[[parameters]]\nkey = "segments[0].radius"\n',
     ["parameters[0]", "'segments[0].radius' is not a parameter a fit can change"]),
    ("bounds reversed", STATIC_EXPERIMENT, '[[parameters]]\nkey = "segments[0].mass"\nlower = 0.2\nupper = 0.1\n',
     ["parameters[0].upper", "a number above lower = 0.2", "found 0.1"]),
    ("a bound outside the format's", STATIC_EXPERIMENT,
     '[[parameters]]\nkey = "segments[0].youngs_modulus"\nlower = -5.0\n',
     ["parameters[0]", "lower bound -5 is below the scene format's 1 Pa"]),
    ("a start outside the bounds", STATIC_EXPERIMENT,
     '[[parameters]]\nkey = "segments[0].mass"\nupper = 0.1\nstart = 0.3\n',
     ["parameters[0]", "start value 0.3", "outside the bounds"]),
    ("a missing column", STATIC_EXPERIMENT.replace('"mid_z"]', '"mid_w"]'), None,
     ["experiments[0].static_csv", "no column 'mid_w'"]),
    ("a bad loss", STATIC_EXPERIMENT + '\n[fit]\nloss = "huberr"\n', None, ["fit.loss", "did you mean 'huber'"]),
    ("a bad covariance", STATIC_EXPERIMENT + '\n[fit]\ncovariance = "white"\n', None,
     ["fit.covariance", '"white"', '"inputs"']),
    ("too few draws", STATIC_EXPERIMENT + '\n[fit]\ninput_draws = 1\n', None, ["fit.input_draws", ">= 2", "1"]),
    ("a negative pressure noise", STATIC_EXPERIMENT + '\n[fit]\npressure_sigma = -3.0\n', None,
     ["fit.pressure_sigma", ">= 0", "-3"]),
    ("pressure noise for 2 chambers", STATIC_EXPERIMENT + '\n[fit]\npressure_sigma = [1.0, 2.0]\n', None,
     ["fit.pressure_sigma", "9 numbers (3 a segment x 3 segments)", "2 numbers"]),
    ("a zero cutoff", STATIC_EXPERIMENT + '\n[fit]\npressure_filter = 0.0\n', None,
     ["fit.pressure_filter", "> 0", "0"]),
])
def test_bad_fit_files_are_refused_by_key_and_write_nothing(tmp_path, capsys, case, body, parameters, words):
    _scene(tmp_path, "arm.toml", **START)
    _static_csv(tmp_path)
    spec = _spec(tmp_path, body + '\n[output]\nfolder = "results"\n' if "[output]" not in body else body, parameters)
    assert main(["fit", str(spec)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("qchain fit: error: ")
    for w in words:
        assert w in err, (case, err)
    assert not (tmp_path / "results").exists() and not (tmp_path / "fit-fit").exists()


def test_a_missing_scene_file_is_refused(tmp_path, capsys):
    _static_csv(tmp_path)
    spec = _spec(tmp_path, STATIC_EXPERIMENT)
    assert main(["fit", str(spec)]) == 2
    err = capsys.readouterr().err
    assert "scene: expected the scene file (a path relative to the fit file), found \"arm.toml\": no such file" in err
    assert not (tmp_path / "fit-fit").exists()


def test_a_missing_fit_file_is_refused(tmp_path, capsys):
    assert main(["fit", str(tmp_path / "none.toml")]) == 2
    assert "none.toml" in capsys.readouterr().err


def test_qchain_fit_as_a_process(tmp_path):
    """The command as a user runs it (under load: ``/work/shared/tools/under-load``): exit code 0
    and its outputs; a refused file exit code 2 with one error line."""
    _scene(tmp_path, "arm.toml", **START)
    _static_csv(tmp_path)
    spec = _spec(tmp_path, STATIC_EXPERIMENT + "\n[fit]\nmax_nfev = 40\n\n[output]\nplot = false\n")
    r = subprocess.run([sys.executable, "-m", "qchain", "fit", str(spec)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "wrote" in r.stdout and "fitted.toml" in r.stdout
    assert sorted(p.name for p in (tmp_path / "fit-fit").iterdir()) == ["fit.json", "fitted.toml"]
    bad = _spec(tmp_path, STATIC_EXPERIMENT.replace("static_csv", "static_cvs"), name="bad.toml")
    r = subprocess.run([sys.executable, "-m", "qchain", "fit", str(bad)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 2
    assert "did you mean 'static_csv'" in r.stderr and "Traceback" not in r.stderr


def test_docs_show_the_fit_files_keys_as_declared():
    """docs/fit.md holds the fit file's tables as :func:`qchain.fit.spec.markdown` renders them."""
    from pathlib import Path

    from qchain.fit.spec import markdown

    doc = (Path(__file__).parents[1] / "docs" / "fit.md").read_text()
    assert "\n".join(markdown()).strip() in doc


def test_points_in_the_wrong_unit_are_refused_before_the_fit(tmp_path, capsys):
    """The CSV's millimetres read as metres: the experiment against the arm's reach, exit code 2,
    no output folder left behind."""
    _scene(tmp_path, "arm.toml", **START)
    _static_csv(tmp_path)
    spec = _spec(tmp_path, STATIC_EXPERIMENT.replace("scale = 1e-3", "scale = 1.0"))
    assert main(["fit", str(spec)]) == 2
    err = capsys.readouterr().err
    assert "m from the base, and the arm is 0.3 m long" in err and "mm for m?" in err
    assert not (tmp_path / "fit-fit").exists()


def test_a_csv_of_motion_is_read_as_read_csv_reads_it(tmp_path):
    """A ``csv`` experiment: its keys handed to read_csv (window, scale, columns) as given."""
    from qchain.fit import read_csv
    from qchain.fit.spec import load_fit_spec

    _scene(tmp_path, "arm.toml", **START)
    t = np.arange(0.0, 1.0, 0.01)
    rows = ["time,x,y,z," + ",".join(f"p{i}" for i in range(9))]
    for k, tk in enumerate(t):
        rows.append(f"{tk:.6f},{10 * np.sin(tk):.6f},0.5,{-300 + k * 0.1:.6f}," + ",".join(["1000"] * 9))
    (tmp_path / "motion.csv").write_text("\n".join(rows) + "\n")
    spec = _spec(tmp_path, '[[experiments]]\ncsv = "motion.csv"\ntime = "time"\npoints = [["x", "y", "z"]]\n'
                 'pressures = ["p0", "p1", "p2", "p3", "p4", "p5", "p6", "p7", "p8"]\nscale = 1e-3\n'
                 'start = 0.2\nstop = 0.6\n')
    got = load_fit_spec(spec).experiments[0]
    want = read_csv(tmp_path / "motion.csv", time="time", points=[("x", "y", "z")],
                    pressures=[f"p{i}" for i in range(9)], scale=1e-3, start=0.2, stop=0.6)
    np.testing.assert_array_equal(got.t, want.t)
    np.testing.assert_array_equal(got.points, want.points)
    assert got.t.size == 41 and got.points[0, 0, 1] == 0.5e-3


def test_the_example_fit_file_reads_the_bag_calibrate_writes(examples, tmp_path):
    """examples/fit/calibrate-fit.toml, laid out as in the repository with the bag
    examples/calibrate.py writes (1 s of it): a valid fit file of calibrate.py's keys."""
    import shutil
    from pathlib import Path

    from qchain.fit.spec import load_fit_spec

    root = Path(__file__).parents[1]
    for rel in ("examples/fit/calibrate-fit.toml", "examples/scenes/calibrate.toml"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(root / rel, tmp_path / rel)
    cal = examples("calibrate")
    (tmp_path / "out/calibrate").mkdir(parents=True)
    cal.record_lab_bag(tmp_path / "examples/scenes/calibrate.toml", 1.0, tmp_path / "out/calibrate/lab_run.mcap")
    from qchain.fit import MeasurementWarning

    with pytest.warns(MeasurementWarning, match="1 measured samples outside"):  # the mocap's last sample
        spec = load_fit_spec(tmp_path / "examples/fit/calibrate-fit.toml")
    assert spec.keys == cal.KEYS
    assert spec.folder == tmp_path / "out/calibrate/fit"
    assert spec.experiments[0].n_samples >= 99 and spec.options["f_scale"] == cal.MOCAP_NOISE


def test_a_recording_and_a_qchain_bags_tf_are_read_as_their_readers_read_them(tmp_path, recorded):  # noqa: F811
    """``recording`` and ``bag`` with ``tf`` (a bag qchain wrote): the experiments the readers
    give for the same arguments."""
    from qchain.fit import read_bag, read_qchain
    from qchain.fit.spec import load_fit_spec

    rec, bag, _ = recorded
    n = rec.info.n_segments
    _scene(tmp_path, "arm.toml", **START)
    spec = _spec(tmp_path, f'[[experiments]]\nrecording = "{rec.path}"\nstop = 0.05\n\n'
                 f'[[experiments]]\nbag = "{bag}"\npressure_topic = "/qchain/pressures"\n'
                 f'tf = ["world", "segment_{n}_tip"]\n')
    got = load_fit_spec(spec).experiments
    want = [read_qchain(rec.path, stop=0.05), read_bag(bag, pressure_topic="/qchain/pressures",
                                                       tf=("world", f"segment_{n}_tip"))]
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g.t, w.t)
        np.testing.assert_array_equal(g.points, w.points)
        np.testing.assert_array_equal(g.pressures.values, w.pressures.values)
    assert got[0].t[-1] <= 0.05 < rec.t[-1]


def test_coordinates_through_the_fit_file_are_read_as_their_readers_read_them(tmp_path, recorded):  # noqa: F811
    """``measure = "coordinates"`` on a recording and ``coordinates`` columns in a CSV, each
    with a ``coordinate_scale``: the experiments read_qchain and read_csv give for the same
    arguments (coordinates, scale, no points where none were asked)."""
    from qchain.fit import read_csv, read_qchain
    from qchain.fit.spec import load_fit_spec

    rec, _, _ = recorded
    _scene(tmp_path, "arm.toml", **START)
    t = np.arange(0.0, 0.5, 0.01)
    names = [f"q{i}" for i in range(6)]
    rows = ["time," + ",".join(names) + "," + ",".join(f"p{i}" for i in range(9))]
    for k, tk in enumerate(t):
        q = [0.1 + 0.01 * k, 0.5 * np.sin(tk), 0.0, 0.1, -0.2 * tk, 0.3]
        rows.append(f"{tk:.6f}," + ",".join(f"{v:.9g}" for v in q) + "," + ",".join(["1000"] * 9))
    (tmp_path / "coords.csv").write_text("\n".join(rows) + "\n")
    spec = _spec(tmp_path, f'[[experiments]]\nrecording = "{rec.path}"\nmeasure = "coordinates"\nstop = 0.05\n'
                 'coordinate_scale = 0.02\n\n'
                 '[[experiments]]\ncsv = "coords.csv"\ntime = "time"\ncoordinates = ["q0", "q1", "q2", "q3", "q4", "q5"]\n'
                 'pressures = ["p0", "p1", "p2", "p3", "p4", "p5", "p6", "p7", "p8"]\nstop = 0.3\n')
    got = load_fit_spec(spec).experiments
    want = [read_qchain(rec.path, measure="coordinates", stop=0.05, coordinate_scale=0.02),
            read_csv(tmp_path / "coords.csv", time="time", coordinates=names,
                     pressures=[f"p{i}" for i in range(9)], stop=0.3)]
    for g, w in zip(got, want):
        np.testing.assert_array_equal(g.t, w.t)
        assert g.points is None and w.points is None
        np.testing.assert_array_equal(g.coordinates, w.coordinates)
        np.testing.assert_array_equal(np.asarray(g.coordinate_scale, dtype=float),
                                      np.asarray(w.coordinate_scale, dtype=float))
    assert got[1].coordinates.shape == (31, 6) and got[1].coordinates[10, 0] == 0.2
    np.testing.assert_array_equal(got[0].coordinates, rec.q[rec.t <= 0.05])


def test_the_fit_tables_noise_options_reach_fit(tmp_path, monkeypatch):
    """``[fit]`` covariance, pressure_filter, pressure_sigma and input_draws are handed to
    qchain.fit.fit as given; a cutoff above a motion's Nyquist frequency is refused by key."""
    import qchain.fit.fitting as fitting

    _scene(tmp_path, "arm.toml", **START)
    _static_csv(tmp_path)
    bag = _lab_bag(tmp_path, noise=5e-4, duration=0.3)
    motion = f'\n[[experiments]]\nbag = "{bag.name}"\npressure_topic = "/pressures"\npose_topic = "/mocap/tip"\n'
    seen = {}

    def fake(scene, experiments, keys, **kw):  # records what it is given, then stops the command (exit 2)
        from qchain.fit import MeasurementError

        seen.update(kw)
        raise MeasurementError("stopped here by the test")

    monkeypatch.setattr(fitting, "fit", fake)
    spec = _spec(tmp_path, STATIC_EXPERIMENT + motion + '\n[fit]\ncovariance = "hac"\npressure_filter = 10.0\n'
                 'pressure_sigma = [100.0, 200.0, 300.0, 100.0, 200.0, 300.0, 100.0, 200.0, 300.0]\n'
                 'input_draws = 7\n')
    assert main(["fit", str(spec)]) == 2
    assert seen["covariance"] == "hac" and seen["pressure_filter"] == 10.0 and seen["input_draws"] == 7
    np.testing.assert_array_equal(seen["pressure_sigma"], [100.0, 200.0, 300.0] * 3)
    bad = _spec(tmp_path, STATIC_EXPERIMENT + motion + '\n[fit]\npressure_filter = 30.0\n', name="bad.toml")
    from qchain.errors import FitSpecError
    from qchain.fit.spec import load_fit_spec

    with pytest.raises(FitSpecError, match=r"fit.pressure_filter.*a cutoff below 25 Hz .*experiments\[1\].*30"):
        load_fit_spec(bad)
