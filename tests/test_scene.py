"""Scene files: every validation error and its message, the example scenes, schedules,
prescribed base motions, planar detection and node sizing."""

import copy
import math
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from qchain import Chain, QchainError
from qchain.scene import BEND_MARGIN, SceneError, SineMotion, load_scene, parse_scene
from qchain.model.segment import DEFAULT_NODES, nodes_for_tolerance
from qchain.arm.statics import equilibrium
from qchain.sim.simulation import DEFAULT_METHOD
from support import SEGMENT

EXAMPLE_SCENES = sorted((Path(__file__).parents[1] / "examples" / "scenes").glob("*.toml"))


def base_scene():
    """A valid two-segment scene as a dict (written to TOML by :func:`to_toml`)."""
    return {
        "name": "test",
        "segments": [dict(SEGMENT), dict(SEGMENT, length=0.08)],
        "pressure": {"type": "constant", "value": [1e4, 0, 0, 0, 2e4, 2e4]},
        "simulation": {"duration": 0.1},
    }


def _toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def to_toml(d, prefix=""):
    """A small TOML writer: scalars and arrays, tables, arrays of tables."""
    lines = []
    tables = []
    for k, v in d.items():
        if isinstance(v, dict):
            tables.append((k, v))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            tables.append((k, v))
        else:
            lines.append(f"{k} = {_toml_value(v)}")
    for k, v in tables:
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            lines.append(f"\n[{name}]")
            lines.append(to_toml(v, prefix=name + "."))
        else:
            for item in v:
                lines.append(f"\n[[{name}]]")
                lines.append(to_toml(item, prefix=name + "."))
    return "\n".join(lines)


def write(tmp_path, d, name="scene.toml"):
    p = tmp_path / name
    p.write_text(to_toml(d))
    return p


def problems_of(tmp_path, d):
    path = write(tmp_path, d)
    with pytest.raises(SceneError) as exc:
        load_scene(path)
    err = exc.value
    assert str(path) in str(err)
    return err


# --------------------------------------------------------------------------------------
# valid scenes


@pytest.mark.parametrize("path", EXAMPLE_SCENES, ids=[p.stem for p in EXAMPLE_SCENES])
def test_every_example_scene_loads_and_builds(path):
    scene = load_scene(path)
    model = scene.build()
    ch = model.chain
    assert ch.n == scene.n == len(model.nodes)
    assert model.q0.shape == (ch.nq,) and model.v0.shape == (ch.nv,)
    assert ch.forward_dynamics(model.q0, model.v0, None if model.pressure is None else model.pressure(0.0)).shape == (ch.nv,)
    text = "\n".join(scene.describe(model))
    assert f"free dofs = {ch.nv_active}" in text
    for r in model.reductions:
        assert r in text
    assert scene.output_folder.name == path.stem


def test_defaults_and_count_expansion(tmp_path):
    d = base_scene()
    d["segments"][0]["count"] = 3
    d["pressure"]["value"] = [1e4, 0, 0] * 4
    scene = load_scene(write(tmp_path, d, "arm.toml"))
    assert scene.n == 4
    assert [s.length for s in scene.segments] == [0.1, 0.1, 0.1, 0.08]
    assert scene.segments[1].source == "segments[0] (copy 2 of 3)"
    assert scene.segments[3].source == "segments[1]"
    assert scene.base.type == "fixed"
    assert np.array_equal(scene.gravity, [0, 0, -9.81])
    assert scene.method == DEFAULT_METHOD == "radau5" and scene.rtol == 1e-6 and scene.atol == 1e-8 and scene.dt is None
    assert scene.max_step == math.inf and scene.reduce is True and scene.node_tolerance is None
    assert scene.sample_rate == 100.0 and scene.output_folder == Path("out/arm") and scene.plots == ("tip",)
    assert np.array_equal(scene.q_e0, [[0.1, 0, 0]] * 3 + [[0.08, 0, 0]])
    assert np.array_equal(scene.v_e0, np.zeros((4, 3)))
    model = scene.build()
    assert model.nodes == [DEFAULT_NODES] * 4
    assert "fixed base: no base coordinates" in model.reductions


def test_method_names_ignore_case(tmp_path):
    d = base_scene()
    d["simulation"]["method"] = "dop853"
    assert load_scene(write(tmp_path, d)).method == "DOP853"


@pytest.mark.parametrize("given, method, solver", [("radau", "Radau", "scipy's solve_ivp in Python"),
                                                   ("RADAU5", "radau5", "(compiled)")])
def test_a_scene_says_which_solver_its_method_is(tmp_path, given, method, solver):
    """``radau`` is scipy's Radau, not the compiled radau5: what ``qchain info`` and ``qchain
    run`` print says which."""
    d = base_scene()
    d["simulation"]["method"] = given
    scene = load_scene(write(tmp_path, d))
    line = next(x for x in scene.describe(scene.build()) if x.startswith("simulation:"))
    assert scene.method == method and solver in line, line


def test_flat_and_nested_vectors_agree(tmp_path):
    d = base_scene()
    flat = load_scene(write(tmp_path, d, "flat.toml"))
    d["pressure"]["value"] = [[1e4, 0, 0], [0, 2e4, 2e4]]
    nested = load_scene(write(tmp_path, d, "nested.toml"))
    assert np.array_equal(flat.pressure(0.3), nested.pressure(0.3))
    assert np.array_equal(flat.pressure(0.3), [1e4, 0, 0, 0, 2e4, 2e4])


def test_pressure_schedules(tmp_path):
    d = base_scene()
    d["pressure"] = {"type": "step", "time": 0.2, "after": [1, 2, 3, 4, 5, 6], "before": [6, 5, 4, 3, 2, 1]}
    s = load_scene(write(tmp_path, d)).pressure
    assert np.array_equal(s(0.1), [6, 5, 4, 3, 2, 1]) and np.array_equal(s(0.2), [1, 2, 3, 4, 5, 6])
    d["pressure"] = {"type": "ramp", "t0": 1.0, "t1": 3.0, "end": [2e4] * 6}
    s = load_scene(write(tmp_path, d)).pressure
    assert np.allclose(s(2.0), [1e4] * 6) and np.array_equal(s(0.5), np.zeros(6)) and np.array_equal(s(9), [2e4] * 6)
    d["pressure"] = {"type": "table", "times": [0.0, 1.0, 3.0],
                     "values": [[0] * 6, [1e4] * 6, [[3e4, 0, 0], [0, 0, 3e4]]]}
    s = load_scene(write(tmp_path, d)).pressure
    assert np.allclose(s(2.0), [2e4, 5e3, 5e3, 5e3, 5e3, 2e4]) and np.array_equal(s(5.0), [3e4, 0, 0, 0, 0, 3e4])
    amp = [1e4, 2e4, 3e4, 4e4, 5e4, 6e4]
    d["pressure"] = {"type": "sine", "amplitude": amp, "offset": [7e4] * 6, "frequency": 2.0,
                     "phase": [0.1, 0.2, 0.3, 0.4, 0.5, 0.6], "segment_phase": -0.5}
    s = load_scene(write(tmp_path, d)).pressure
    t = 0.37
    ph = np.array([0.1, 0.2, 0.3, 0.4 - 0.5, 0.5 - 0.5, 0.6 - 0.5])
    assert np.allclose(s(t), 7e4 + np.array(amp) * np.sin(2 * np.pi * 2.0 * t + ph), rtol=1e-15, atol=0)


# --------------------------------------------------------------------------------------
# every validation error


def _set(path, value):
    """Mutation setting a dotted path (``a.b[1].c``) in the scene dict; value DELETE removes it."""

    def apply(d):
        keys = []
        for part in path.split("."):
            if "[" in part:
                name, idx = part[:-1].split("[")
                keys += [name, int(idx)]
            else:
                keys.append(part)
        node = d
        for k in keys[:-1]:
            if isinstance(k, str) and k not in node:
                node[k] = {}
            node = node[k]
        if value is DELETE:
            del node[keys[-1]]
        else:
            node[keys[-1]] = value
        return d

    return apply


DELETE = object()

ERRORS = [
    # (mutations, expected message fragment)
    ([_set("segmnts", 1)], "segmnts: expected one of the keys name, description, gravity, model, segments, base, "
                           "pressure, initial, simulation, output, budget, contact, obstacles, loads, payload, tendons, tension "
                           "(did you mean "
                           "'segments'?), found the unknown key 'segmnts'"),
    ([_set("segments[0].raduis", 0.01)], "segments[0].raduis: expected one of the keys count, length, radius,"),
    ([_set("segments[0].raduis", 0.01)], "(did you mean 'radius'?), found the unknown key 'raduis'"),
    ([_set("segments[0].radius", "big")], 'segments[0].radius: expected a number >= 1e-06 and <= 10 (m), found a string "big"'),
    ([_set("segments[0].radius", True)], "segments[0].radius: expected a number >= 1e-06 and <= 10 (m), found a boolean true"),
    ([_set("segments[1].radius", -0.01)], "segments[1].radius: expected a number >= 1e-06 and <= 10 (m), found -0.01"),
    ([_set("segments[1].mass", 0)], "segments[1].mass: expected a number >= 1e-09 and <= 1e+06 (kg), found 0"),
    ([_set("segments[0].youngs_modulus", DELETE)],
     "segments[0].youngs_modulus: expected a number >= 1 and <= 1e+12 (Pa), found nothing (the key is required)"),
    ([_set("segments[0].damping", -1e-3)], "segments[0].damping: expected a number >= 0 and <= 100 (s), found -0.001"),
    ([_set("segments[0].count", 0)], "segments[0].count: expected an integer >= 1, found 0"),
    ([_set("segments[0].count", 2.5)], "segments[0].count: expected an integer >= 1, found a float 2.5"),
    ([_set("segments[0].nodes", 0)], "segments[0].nodes: expected an integer >= 1 and <= 100, found 0"),
    ([_set("segments[0].coords", "polar")], 'segments[0].coords: expected one of "curvature", "paper", found a string "polar"'),
    ([_set("segments[0].actuation", "volum")], "(did you mean 'volume'?)"),
    ([_set("segments[0].extensible", "no")], 'segments[0].extensible: expected true or false, found a string "no"'),
    ([_set("segments[1].chamber_radius", 0.012)],
     "segments[1].chamber_radius: expected chambers inside the segment: chamber_radius + sqrt(chamber_area/pi) "
     "<= radius = 0.015 m, found 0.012 + 0.0037847 = 0.0157847 m"),
    ([_set("segments", [])], "segments: expected a non-empty array of tables [[segments]], found an array []"),
    ([_set("segments", DELETE), _set("pressure", DELETE)],
     "segments: expected an array of tables [[segments]], base to tip, found nothing (the key is required)"),
    ([_set("gravity", [0, -9.81])], "gravity: expected an array of 3 numbers (m/s^2), found 2 numbers [0, -9.81]"),
    ([_set("gravity", [0, "x", 1])], 'gravity[1]: expected a finite number, found a string "x"'),
    ([_set("model.reduce", 1)], "model.reduce: expected true or false, found an integer 1"),
    ([_set("model.node_tolerance", 2.0)], "model.node_tolerance: expected a number > 0 and < 1, found 2.0"),
    ([_set("model.node_tolerance", -1e-8)], "model.node_tolerance: expected a number > 0 and < 1, found -1e-08"),
    ([_set("model.max_bend", 1.0)], "model.max_bend: expected model.node_tolerance beside it"),
    ([_set("model.max_bend", -1.0), _set("model.node_tolerance", 1e-8)],
     "model.max_bend: expected a number >= 0 and <= 1000 (rad), found -1.0"),
    ([_set("base.type", "flying")], 'base.type: expected one of "fixed", "floating", "prescribed" (did you mean '
                                    "'floating'?), found a string \"flying\""),
    ([_set("base.velocity", [1, 0, 0])],
     "base.velocity: expected only the keys type, position, rpy with base.type = 'fixed', found the key 'velocity'"),
    ([_set("base.rpy", [0, 0])], "base.rpy: expected an array of 3 numbers (rad), found 2 numbers [0, 0]"),
    ([_set("base.type", "prescribed")], "base.motion: expected a table, found nothing"),
    ([_set("base.type", "prescribed"), _set("base.motion", {"type": "wobble", "axis": [1, 0, 0], "amplitude": 0.1,
                                                             "frequency": 1.0})],
     'base.motion.type: expected one of "translation", "rotation", found a string "wobble"'),
    ([_set("base.type", "prescribed"), _set("base.motion", {"type": "rotation", "axis": [0, 0, 0], "amplitude": 0.1,
                                                             "frequency": 1.0})],
     "base.motion.axis: expected a non-zero direction, found [0, 0, 0]"),
    ([_set("base.type", "prescribed"), _set("base.motion", {"type": "rotation", "axis": [0, 1, 0], "amplitude": 0.1,
                                                             "frequency": -1.0})],
     "base.motion.frequency: expected a number >= 0 and <= 10000 (Hz), found -1.0"),
    ([_set("pressure.type", "pulse")], 'pressure.type: expected one of "constant", "step", "ramp", "sine", "table", '
                                       'found a string "pulse"'),
    ([_set("pressure.value", [1e4, 0, 0, 0, 0])],
     "pressure.value: expected 6 numbers (3 a segment x 2 segments), flat or as 2 arrays of 3, Pa, found 5 numbers"),
    ([_set("pressure.value", [[1e4, 0, 0], [0, 0]])],
     "pressure.value[1]: expected an array of 3 numbers (segment 1), found 2 numbers [0, 0]"),
    ([_set("pressure.value", [[1e4, 0, 0]])], "pressure.value: expected 6 numbers (3 a segment x 2 segments), flat or "
                                               "as 2 arrays of 3, Pa, found 1 arrays"),
    ([_set("pressure.value", [0, 0, 0, 0, -2e5, 0])],
     "pressure.value: expected gauge pressures >= -101325 and <= 1e+09 Pa (a vacuum to 1 GPa), found -200000 Pa at index 4 "
     "(segment 1, chamber 2)"),
    ([_set("pressure.values", [[0] * 6])], "pressure.values: expected one of the keys type, value (did you mean 'value'?), found the unknown key 'values'"),
    ([_set("pressure", {"type": "table", "times": [0.0, 0.5, 0.4], "values": [[0] * 6] * 3})],
     "pressure.times[2]: expected a time > times[1] = 0.5 s (strictly increasing), found 0.4"),
    ([_set("pressure", {"type": "table", "times": [0.0, 0.5], "values": [[0] * 6] * 3})],
     "pressure.values: expected 2 pressure vectors, one for each of the 2 times, found 3"),
    ([_set("pressure", {"type": "table", "times": [0.0, 0.5], "values": [[0] * 6, [0] * 7]})],
     "pressure.values[1]: expected 6 numbers"),
    ([_set("pressure", {"type": "ramp", "t0": 1.0, "t1": 1.0, "end": [0] * 6})],
     "pressure.t1: expected a time > t0 = 1 s, found 1.0"),
    ([_set("pressure", {"type": "step", "after": [0] * 6})],
     "pressure.time: expected a number >= -1e+12 and <= 1e+12 (s), found nothing (the key is required)"),
    ([_set("pressure", {"type": "sine", "amplitude": [1e4] * 6})],
     "pressure.frequency: expected a frequency (Hz), a number or one a chamber, found nothing"),
    ([_set("pressure", {"type": "sine", "amplitude": [2e5] * 6, "frequency": 1.0})],
     "pressure.offset: expected offset - |amplitude| >= -101325 Pa (a vacuum) in every chamber, found -200000 Pa at "
     "index 0 (segment 0, chamber 1)"),
    ([_set("pressure", {"type": "sine", "amplitude": [1e4] * 6, "frequency": [1.0] * 5 + [-1.0]})],
     "pressure.frequency: expected values >= 0 and <= 10000 Hz, found -1 at index 5"),
    ([_set("initial.q_e", [[0.1, 80.0, 0.0], [0.08, 0.0, 0.0]])],
     "initial.q_e[0]: expected a configuration inside the model (l > 0, |kappa| r_s < 1), found (0.1, 80, 0): segment 0:"),
    ([_set("initial.q_e", [[-0.1, 0.0, 0.0], [0.08, 0.0, 0.0]])], "initial.q_e[0]: expected a configuration inside"),
    ([_set("initial.v", [0.0] * 5)], "initial.v: expected 6 numbers"),
    ([_set("initial.q", [0.0] * 6)], "initial.q: expected one of the keys q_e, v, found the unknown key 'q'"),
    ([_set("segments[1].extensible", False), _set("initial.q_e", [[0.1, 0.0, 0.0], [0.09, 0.0, 0.0]])],
     "initial.q_e[1][0]: expected l = length = 0.08 m (segment 1 is inextensible), found 0.09"),
    ([_set("segments[1].extensible", False), _set("initial.v", [0.0, 0.0, 0.0, 0.1, 0.0, 0.0])],
     "initial.v[1][0]: expected 0 (segment 1 is inextensible), found 0.1"),
    ([_set("simulation", DELETE)], "simulation: expected a table, found nothing"),
    ([_set("simulation.duration", DELETE)], "simulation.duration: expected a number >= 1e-12 and <= 1e+12 (s), found nothing (the key is required)"),
    ([_set("simulation.duration", -1.0)], "simulation.duration: expected a number >= 1e-12 and <= 1e+12 (s), found -1.0"),
    ([_set("simulation.method", "RK23")], 'simulation.method: expected one of "radau5", "dopri5", "rk4", "midpoint", '
                                          '"RK45", "DOP853", "Radau", "BDF", found a string "RK23"'),
    ([_set("simulation.method", "rk4")], "simulation.dt: expected a step > 0 (s): method 'rk4' takes fixed steps, found nothing"),
    ([_set("simulation.dt", 1e-3)], "simulation.dt: expected no dt: method 'radau5' chooses its own steps"),
    ([_set("simulation.method", "midpoint"), _set("simulation.dt", 1.0)],
     "simulation.dt: expected a step <= duration = 0.1 s, found 1.0"),
    ([_set("simulation.rtol", 0.0)], "simulation.rtol: expected a number >= 1e-15 and <= 1, found 0.0"),
    ([_set("output.plots", ["tips"])], "output.plots[0]: expected one of tip, arm, energy, pressure, momentum (did you "
                                       "mean 'tip'?), found \"tips\""),
    ([_set("output.plots", ["momentum"])], "output.plots: expected 'momentum' only with a floating base"),
    ([_set("output.plots", "tip")], "output.plots: expected an array of names from tip, arm, energy, pressure, "
                                    'momentum, found a string "tip"'),
    ([_set("output.sample_rate", 0)], "output.sample_rate: expected a number > 0 and <= 1e+09 (Hz), found 0"),
    ([_set("output.save", "yes")], 'output.save: expected true or false, found a string "yes"'),
    ([_set("output.folder", 3)], "output.folder: expected a string, found an integer 3"),
]


@pytest.mark.parametrize("mutations, message", ERRORS, ids=[f"{i}" for i in range(len(ERRORS))])
def test_each_problem_is_reported_with_key_expected_and_found(tmp_path, mutations, message):
    d = base_scene()
    for m in mutations:
        d = m(d)
    err = problems_of(tmp_path, d)
    assert message in str(err), str(err)
    assert len(err.problems) == 1, str(err)


def test_all_problems_are_listed_in_one_error(tmp_path):
    d = base_scene()
    d["segments"][0]["radius"] = -1.0
    d["simulation"]["method"] = "euler"
    d["output"] = {"plots": ["tip", "spectrum"]}
    d["colour"] = "red"
    err = problems_of(tmp_path, d)
    assert isinstance(err, QchainError) and isinstance(err, ValueError)
    keys = [p.key for p in err.problems]
    assert keys == ["colour", "segments[0].radius", "simulation.method", "output.plots[1]"]
    text = str(err)
    assert text.startswith(f"{tmp_path / 'scene.toml'}: 4 problems:\n")
    for p in err.problems:
        assert f"  {p.key}: expected {p.expected}, found {p.found}" in text


def test_syntax_errors_and_missing_files(tmp_path):
    p = tmp_path / "bad.toml"
    p.write_text("[simulation]\nduration = \n")
    with pytest.raises(SceneError, match=r"bad.toml: \(file\): expected valid TOML, found a syntax error: Invalid value"):
        load_scene(p)
    with pytest.raises(SceneError, match=r"nowhere.toml: \(file\): expected an existing scene file, found no such file"):
        load_scene(tmp_path / "nowhere.toml")
    with pytest.raises(SceneError, match=r"expected a scene file, found a folder"):
        load_scene(tmp_path)


# --------------------------------------------------------------------------------------
# prescribed base motions


@pytest.mark.parametrize("kind", ["translation", "rotation"])
def test_sine_motion_twist_and_acceleration_are_exact(kind):
    mount = pin.SE3(pin.rpy.rpyToMatrix(0.3, -0.2, 1.1), np.array([0.1, -0.2, 0.5]))
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    m = SineMotion(kind=kind, axis=axis, amplitude=0.3, frequency=1.7, phase=0.4, mount=mount)
    X0, V0, A0 = m(0.0)
    assert X0.isApprox(m.placement_at(0.3 * math.sin(0.4)), 1e-14)
    for t in (0.0, 0.13, 0.61):
        X, V, A = m(t)
        h = 1e-6
        # body twist: log of the relative placement over a central step
        V_fd = pin.log6(m(t - h)[0].actInv(m(t + h)[0])).vector / (2 * h)
        A_fd = (m(t + h)[1] - m(t - h)[1]) / (2 * h)
        assert np.allclose(V, V_fd, rtol=0, atol=1e-8 * max(1.0, np.abs(V).max()))
        assert np.allclose(A, A_fd, rtol=0, atol=1e-6 * max(1.0, np.abs(A).max()))
        if kind == "translation":
            assert np.allclose(X.rotation, mount.rotation) and np.allclose(V[3:], 0) and np.allclose(A[3:], 0)
        else:
            assert np.allclose(X.translation, mount.translation) and np.allclose(V[:3], 0) and np.allclose(A[:3], 0)
    ch = Chain([_segment()], base="prescribed", base_motion=m)
    X, V, A = ch.base_state(0.2)
    assert X.isApprox(m(0.2)[0]) and np.array_equal(V, m(0.2)[1])


def _segment(**kw):
    from qchain import Segment

    return Segment(**{**SEGMENT, **kw})


def test_prescribed_scene_builds_the_motion(tmp_path):
    d = base_scene()
    d["base"] = {"type": "prescribed", "position": [0, 0, 1.0], "rpy": [math.pi, 0, 0],
                 "motion": {"type": "translation", "axis": [0, 0, 2.0], "amplitude": 0.05, "frequency": 2.0,
                            "phase": 0.5}}
    scene = load_scene(write(tmp_path, d))
    m = scene.base.motion
    assert np.allclose(m.axis, [0, 0, 1])
    X, V, _ = scene.model.chain.base_state(0.1)
    s = 0.05 * math.sin(2 * math.pi * 2.0 * 0.1 + 0.5)
    assert np.allclose(X.translation, [0, 0, 1.0 - s])  # the mount frame's z points down
    assert np.allclose(V[:3], [0, 0, 0.05 * 4 * math.pi * math.cos(2 * math.pi * 2.0 * 0.1 + 0.5)])


def test_floating_scene_initial_state(tmp_path):
    d = base_scene()
    d["base"] = {"type": "floating", "position": [1, 2, 3], "rpy": [0.1, 0.2, 0.3], "velocity": [0.1, 0, 0],
                 "angular_velocity": [0, 0.5, 0]}
    d["initial"] = {"q_e": [[0.1, 2.0, 0.0], [0.08, 0.0, 0.0]], "v": [0, 0.5, 0, 0, 0, 0]}
    model = load_scene(write(tmp_path, d)).build()
    X = pin.XYZQUATToSE3(model.q0[:7])
    assert X.isApprox(pin.SE3(pin.rpy.rpyToMatrix(0.1, 0.2, 0.3), np.array([1.0, 2, 3])))
    assert np.array_equal(model.v0, [0.1, 0, 0, 0, 0.5, 0, 0, 0.5, 0, 0, 0, 0])
    assert np.array_equal(model.q0[7:], [0.1, 2.0, 0, 0.08, 0, 0])


# --------------------------------------------------------------------------------------
# planar detection (the trajectories are compared in test_reduction.py)


def planar_scene():
    d = base_scene()
    d["base"] = {"type": "fixed", "rpy": [0.0, 1.2, 0.0]}  # turned about y: gravity stays in the base x-z plane
    d["initial"] = {"q_e": [[0.1, 3.0, 0.0], [0.08, -2.0, 0.0]], "v": [0.0, 1.0, 0.0, 0.0, 0.0, 0.0]}
    return d


@pytest.mark.parametrize(
    "mutation, reason",
    [
        (None, None),
        (_set("base.rpy", [0.3, 0.0, 0.0]), "gravity has a component"),
        (_set("gravity", [0.0, 1.0, -9.81]), "gravity has a component"),
        (_set("pressure.value", [1e4, 0, 0, 0, 2e4, 1e4]), "pressure.value: chambers 2 and 3 differ in segment 1"),
        (_set("pressure", {"type": "sine", "amplitude": [1e4] * 6, "offset": [1e4] * 6, "frequency": 1.0,
                           "phase": [0, 1, 1, 0, 1, 1.5]}), "the sines of chambers 2 and 3 differ in segment 1"),
        (_set("pressure", {"type": "sine", "amplitude": [1e4, 0, 0] * 2, "offset": [1e4] * 6, "frequency": 1.0,
                           "phase": [0, 1, 2, 0, 1, 2]}), None),  # zero amplitude: phases do not matter
        (_set("pressure", {"type": "table", "times": [0, 1], "values": [[0] * 6, [0, 1, 2, 0, 0, 0]]}),
         "pressure.values: chambers 2 and 3 differ in segment 0"),
        (_set("initial.q_e", [[0.1, 3.0, 0.1], [0.08, -2.0, 0.0]]), "segment 0: initial uy or its rate is not 0"),
        (_set("initial.v", [0.0, 1.0, 0.0, 0.0, 0.0, 1e-3]), "segment 1: initial uy or its rate is not 0"),
        (_set("segments[1].coords", "paper"), "segment 1 in paper coordinates"),
        (_set("base", {"type": "prescribed", "motion": {"type": "rotation", "axis": [0, 1, 0], "amplitude": 0.2,
                                                         "frequency": 1.0}}), None),
        (_set("base", {"type": "prescribed", "motion": {"type": "rotation", "axis": [1, 0, 0], "amplitude": 0.2,
                                                         "frequency": 1.0}}), "the base turns about (1, 0, 0)"),
        (_set("base", {"type": "prescribed", "motion": {"type": "translation", "axis": [1, 0, 1], "amplitude": 0.2,
                                                         "frequency": 1.0}}), None),
        (_set("base", {"type": "prescribed", "motion": {"type": "translation", "axis": [0, 1, 0], "amplitude": 0.2,
                                                         "frequency": 1.0}}), "the base translates along (0, 1, 0)"),
        (_set("base", {"type": "floating", "velocity": [1, 0, 1], "angular_velocity": [0, 1, 0]}), None),
        (_set("base", {"type": "floating", "angular_velocity": [0, 0, 1]}), "the floating base's initial twist"),
    ],
)
def test_planar_detection(tmp_path, mutation, reason):
    d = planar_scene()
    if mutation is not None:
        d = mutation(d)
    if "paper" in str(d["segments"][1].get("coords")):
        d["initial"]["q_e"][1] = [0.08, math.pi, 2.0]  # the same shape in (l, psi, kappa)
    scene = load_scene(write(tmp_path, d))
    assert scene.planar_obstacle() == reason or reason in scene.planar_obstacle()
    model = scene.build()
    assert model.chain.planar is (reason is None)
    if reason is None:
        assert any(r.startswith("planar: uy locked at 0 in every segment") for r in model.reductions)
        assert model.chain.nv_active == model.chain.nv - scene.n
    else:
        assert any(k.startswith("planar: not applicable: ") and reason in k for k in model.kept)
    full = scene.build(reduce=False)
    assert not full.chain.planar and full.chain.nv_active == full.chain.nv
    assert "planar: not tried (reduce = false)" in full.kept


# --------------------------------------------------------------------------------------
# node sizing


def test_nodes_from_tolerance_and_the_estimated_bend(tmp_path):
    d = base_scene()
    d["model"] = {"node_tolerance": 1e-9}
    d["pressure"] = {"type": "step", "time": 0.01, "after": [5e4, 0, 0, 0, 3e4, 3e4]}
    scene = load_scene(write(tmp_path, d))
    model = scene.build()
    # the estimate: BEND_MARGIN x the largest static bend under the step's pressures, any segment
    segs = [s.segment() for s in scene.segments]
    ch = Chain(segs, planar=False)
    eq = equilibrium(ch, [5e4, 0, 0, 0, 3e4, 3e4])
    assert eq.success
    static = np.array([np.hypot(*eq.q[ch.q_slice(j)][1:]) * eq.q[ch.q_slice(j)][0] for j in range(2)])
    assert np.allclose(model.max_bend, BEND_MARGIN * static.max(), rtol=1e-6)
    expect = [nodes_for_tolerance(s, th, 1e-9) for s, th in zip(segs, model.max_bend)]
    assert model.nodes == expect
    assert [s.node_count for s in model.chain.segments] == expect
    note = [r for r in model.reductions if r.startswith("nodes: ")]
    assert len(note) == 1 and "node_tolerance = 1e-09" in note[0] and "2 x the largest static bend" in note[0]
    # max_bend given: used as it is; an explicit node count wins
    d["model"]["max_bend"] = 2.0
    d["segments"][1]["nodes"] = 9
    model = load_scene(write(tmp_path, d)).build()
    assert model.nodes == [nodes_for_tolerance(segs[0], 2.0, 1e-9), 9]
    # reduce = false: the default count
    assert load_scene(write(tmp_path, d)).build(reduce=False).nodes == [DEFAULT_NODES, 9]


def test_floating_base_bend_is_estimated_without_gravity(tmp_path):
    d = base_scene()
    d["model"] = {"node_tolerance": 1e-8}
    d["base"] = {"type": "floating"}
    d["pressure"] = {"type": "constant", "value": [3e4, 0, 0, 0, 0, 0]}
    scene = load_scene(write(tmp_path, d))
    theta, how = scene.estimate_bend()
    ch = Chain([s.segment() for s in scene.segments], gravity=(0, 0, 0))
    eq = equilibrium(ch, [3e4, 0, 0, 0, 0, 0])
    bend0 = np.hypot(*eq.q[1:3]) * eq.q[0]
    assert theta == pytest.approx([BEND_MARGIN * bend0] * 2, rel=1e-6)
    assert how == "2 x the largest static bend under peak pressures, any segment"


def test_sample_times(tmp_path):
    d = base_scene()
    d["simulation"]["duration"] = 0.105
    d["output"] = {"sample_rate": 40.0}
    scene = load_scene(write(tmp_path, d))
    assert np.allclose(scene.sample_times(), [0, 0.025, 0.05, 0.075, 0.1, 0.105])
    assert np.allclose(scene.sample_times(0.05), [0, 0.025, 0.05])


def test_parse_scene_from_text():
    text = to_toml(copy.deepcopy(base_scene()))
    scene = parse_scene(text)
    assert scene.path is None and scene.output_folder == Path("out/scene") and scene.text == text
    with pytest.raises(SceneError, match=r"^<scene>: simulation.duration"):
        parse_scene(text.replace("duration = 0.1", "duration = 0"))


def test_a_tendon_scene_runs_as_simulate_on_the_same_chain_and_tensions():
    """examples/scenes/hanging_tendons.toml against the same arm built in Python
    (examples/tendon_arm.py's): the scene's run is simulate's with Chain(tendons=...) and
    tension=Ramp, sample for sample, and records the ramp's tensions; the full model is
    kept (planar and inextensible reductions are not tried with tendons)."""
    from qchain import Segment, Tendon, simulate
    from qchain.sim.inputs import Ramp

    scene = load_scene(Path(__file__).parent.parent / "examples" / "scenes" / "hanging_tendons.toml")
    model = scene.build()
    ch = model.chain
    assert not ch.planar and all(s.extensible for s in ch.segments) and ch.nt == 2
    traj = scene.simulate(duration=0.3)
    seg = Segment(length=0.2, radius=0.02, mass=0.08, chamber_area=1e-4, chamber_radius=0.01, youngs_modulus=2e5,
                  damping=0.15)
    down = pin.SE3(pin.rpy.rpyToMatrix(np.pi, 0.0, 0.0), np.array([0.0, 0.0, 0.5]))
    ref_chain = Chain([seg] * 3, base_placement=down, tendons=[Tendon(radius=0.015, angle=0.0, end=1),
                                                               Tendon(radius=0.012, angle=np.pi / 2, pitch=1.2)])
    ramp = Ramp(0.0, 0.5, np.array([5.0, 4.0]), np.zeros(2))
    ref = simulate(ref_chain, ref_chain.neutral(), np.zeros(ref_chain.nv), (0.0, 0.3), tension=ramp, method="radau5",
                   rtol=1e-7, atol=1e-9, t_eval=traj.t)
    np.testing.assert_allclose(traj.q, ref.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(traj.tension, np.array([ramp(t) for t in traj.t]), rtol=0, atol=1e-15)
    assert np.abs(traj.q[-1] - traj.q[0]).max() > 1e-3  # the tensions moved the arm


def test_tendons_without_tension_leave_the_run_as_without_tendons(tmp_path):
    """A scene's tendons at 0 N (no [tension]) do no work: the run is the tendonless scene's
    (both unreduced: tendons keep the full model and size the node count for the largest bend)."""
    text = (Path(__file__).parent.parent / "examples" / "scenes" / "step_response.toml").read_text()
    plain = parse_scene(text, tmp_path / "a.toml").simulate(duration=0.1, reduce=False)
    slack = parse_scene(text + "\n[[tendons]]\nradius = 0.01\npitch = 0.3\n", tmp_path / "b.toml")
    assert slack.build().chain.nt == 1 and slack.tension is None
    traj = slack.simulate(duration=0.1, reduce=False)
    np.testing.assert_allclose(traj.q, plain.q, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(traj.tension, np.zeros((len(traj.t), 1)))


#: a damping matrix in curvature coordinates (l, ux, uy) coupling l and ux, not uy
D_LUX = [[5.0, 0.02, 0.0], [0.02, 1e-3, 0.0], [0.0, 0.0, 1e-3]]


def _drag_scene(**seg):
    """base_scene with a hanging-free arm in a medium: drag and ``seg`` on both segments,
    pressures equal in chambers 2 and 3 (planar applies), damping 0."""
    d = base_scene()
    d["segments"] = [dict(SEGMENT, damping=0.0, **seg), dict(SEGMENT, length=0.08, damping=0.0, **seg)]
    d["pressure"] = {"type": "constant", "value": [2e4, 0, 0, 0, 1e4, 1e4]}
    d["simulation"] = {"duration": 0.2, "method": "radau5", "rtol": 1e-8, "atol": 1e-10}
    return d


def test_a_scene_with_drag_and_a_damping_matrix_runs_as_simulate_on_the_same_chain(tmp_path):
    """Issue 32: drag_linear, drag_quadratic and damping_matrix from a scene file give the
    run of simulate on the same chain built in Python (the planar one the scene builds,
    sample for sample); the drag takes energy the undragged scene keeps; the axial coupling
    of the matrix keeps the automatic inextensible reduction off."""
    from qchain import Segment, simulate
    from qchain.sim.inputs import Constant

    d = _drag_scene(drag_linear=0.5, drag_quadratic=20.0, damping_matrix=D_LUX)
    scene = load_scene(write(tmp_path, d))
    model = scene.build()
    assert model.chain.planar and all(s.extensible for s in model.chain.segments)
    assert any("damping_matrix couples l to ux or uy" in k for k in model.kept), model.kept
    traj = scene.simulate()
    segs = [Segment(**dict(SEGMENT, length=L, damping=0.0), drag_linear=0.5, drag_quadratic=20.0,
                    damping_matrix=np.array(D_LUX)) for L in (0.1, 0.08)]
    ch = Chain(segs, planar=True)
    p = Constant(np.array([2e4, 0, 0, 0, 1e4, 1e4]))
    ref = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, 0.2), pressure=p, method="radau5",
                   rtol=1e-8, atol=1e-10, t_eval=traj.t)
    np.testing.assert_allclose(traj.q, ref.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(traj.v, ref.v, rtol=0, atol=1e-10)
    # the same scene without its damping law moves differently: the keys were not dropped
    plain = load_scene(write(tmp_path, _drag_scene(), "plain.toml")).simulate()
    assert np.abs(plain.v[-1] - traj.v[-1]).max() > 1e-3


def test_the_planar_reduction_of_a_dragged_arm_is_the_full_models_run(tmp_path):
    """The isotropic drag and a damping matrix that leaves uy alone keep the scene symmetric:
    the planar run equals the full one to the integrator's tolerance, uy stays 0."""
    d = _drag_scene(drag_linear=0.5, drag_quadratic=20.0, damping_matrix=D_LUX)
    scene = load_scene(write(tmp_path, d))
    planar, full = scene.simulate(), scene.simulate(reduce=False)
    assert scene.build().chain.planar and not scene.build(reduce=False).chain.planar
    np.testing.assert_allclose(planar.q, full.q, rtol=0, atol=1e-7)
    assert np.abs(full.q[:, 2::3]).max() < 1e-9


@pytest.mark.parametrize("seg, kept, reduction", [
    (dict(damping_matrix=[[2.0, 0.0, 0.0], [0.0, 1e-3, 1e-4], [0.0, 1e-4, 1e-3]]),
     "planar: not applicable: segments 0-1: damping_matrix couples uy to l or ux", None),
    (dict(drag_quadratic=20.0),
     "inextensible: not applicable: segments 0-1: the medium's drag loads the axial mode (not estimated)", None),
    (dict(damping_matrix=D_LUX),
     "inextensible: not applicable: segments 0-1: damping_matrix couples l to ux or uy (not estimated)", None),
    (dict(damping_matrix=D_LUX, extensible=False), None,
     "segments 0-1: damping_matrix's entries coupling l to ux, uy dropped with the axial mode (extensible = false)"),
])
def test_a_damping_law_the_reductions_cannot_keep_refuses_them_or_is_said(tmp_path, seg, kept, reduction):
    """A damping matrix coupling uy refuses the planar reduction; drag, or a matrix coupling l
    to the bends, refuses the automatic inextensible one (neither is in its static
    estimate); the file's own extensible = false says what of the matrix it drops."""
    model = load_scene(write(tmp_path, _drag_scene(**seg))).build()
    if kept is not None:
        assert kept in model.kept, model.kept
    if reduction is not None:
        assert reduction in model.reductions, model.reductions
    if "couples uy" in (kept or ""):
        assert not model.chain.planar


def test_the_node_count_of_a_dragged_segment_is_not_cut_below_the_default(tmp_path):
    """node_tolerance sizes M_xi alone; the drag is integrated on the same nodes, so a
    segment with drag keeps DEFAULT_NODES where the sizing would give fewer."""
    d = _drag_scene()
    d["model"] = {"node_tolerance": 1e-2}
    assert min(load_scene(write(tmp_path, d)).build().nodes) < DEFAULT_NODES  # the sizing alone cuts
    d["segments"][1]["drag_linear"] = 0.5
    model = load_scene(write(tmp_path, d, "drag.toml")).build()
    assert model.nodes[1] == DEFAULT_NODES and model.nodes[0] < DEFAULT_NODES
    assert any(f"segment 1 keep {DEFAULT_NODES} (the default)" in r for r in model.reductions), model.reductions
