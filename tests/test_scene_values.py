"""Scene files' values against the declared format (qchain.scene.format): every key refuses a value
of the wrong type or outside its range by name, fuzzed scenes give one clean error or a finite
model, budgets name the key that makes the cost."""

import math
import os
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from helpers import deadline
from qchain import QchainError
from qchain.checks import bounds as B
from qchain.scene import SceneError, load_scene, parse_scene
from qchain.scene import format as F
from qchain.sim.budget import BudgetError
from support import (
    NOT_NUMBERS,
    ONE_SEGMENT_SCENE,
    ROOT,
    SCENE,
    base_scene,
    in_range,
    outside,
    segments_in_range,
    to_toml,
)


@given(duration=st.floats(1e-3, 50.0), rate=st.floats(0.5, 2000.0))
@settings(max_examples=200, deadline=None, derandomize=True, database=None)
def test_the_sample_budget_counts_what_sample_times_makes(duration, rate):
    """The budget counted one sample more than the run makes (a 'max_samples = 2' refused
    a run of two)."""
    from qchain.scene import parse_scene

    sc = parse_scene(ONE_SEGMENT_SCENE.replace("NAME", "n").replace("duration = 0.05", f"duration = {duration!r}")
                     .replace("sample_rate = 200.0", f"sample_rate = {rate!r}"))
    assert sc.cost().samples == len(sc.sample_times())


def test_values_next_to_a_bound_are_shown_with_all_their_digits():
    from qchain.scene import SceneError, parse_scene

    text = ONE_SEGMENT_SCENE.replace("NAME", "b").replace("value = [2e4, 0.0, 0.0]", "value = [-101325.0001, 0, 0]")
    text += "[initial]\nq_e = [1.0000001, 0, 0]\n"
    with pytest.raises(SceneError) as err:
        parse_scene(text)
    msg = str(err.value)
    assert "found -101325.0001 Pa at index 0" in msg and "found 1.0000001" in msg, msg
    moving = ONE_SEGMENT_SCENE.replace("NAME", "m") + ('[base]\ntype = "prescribed"\n[base.motion]\ntype = "translation"\n'
                                           'axis = [1e-200, 0, 0]\namplitude = 0.01\nfrequency = 1.0\n')
    sc = parse_scene(moving)
    assert np.allclose(sc.base.motion.axis, [1.0, 0.0, 0.0])


def test_a_raised_segment_budget_is_refused_by_memory_before_a_million_segments_are_made():
    text = SCENE.replace("count = 2", "count = 1000000").replace("[simulation]", "[budget]\nmax_segments = 1000000\n"
                                                                   "[simulation]")
    with deadline(10, "a million segments"):  # it took minutes (every segment made, then refused)
        with pytest.raises(SceneError) as exc:
            parse_scene(text, "s.toml")
    (p,) = exc.value.problems
    assert p.key == "segments" and p.expected.startswith("at most 2 GiB of output arrays and solver matrices "
                                                         "(budget.max_memory; raise it in [budget]"), p
    assert "with the 1000000 segments up to segments[0]" in p.found


def test_minus_zero_is_zero_in_the_scene_and_its_description(tmp_path):
    text = SCENE.replace("[[segments]]", "[model]\nnode_tolerance = 1e-6\nmax_bend = -0.0\n[[segments]]")
    text = text.replace('type = "constant"', 'type = "step"\ntime = -0.0').replace("value =", "after =")
    sc = parse_scene(text, "s.toml")
    assert math.copysign(1.0, sc.max_bend) == 1.0 and math.copysign(1.0, sc.pressure_spec["time"]) == 1.0
    assert "-0 rad" not in "\n".join(sc.describe())


@pytest.mark.parametrize("q_e", ["[[0.1, 3.0, 0.0], [0.1, 0.0, 0.0]]", None])
def test_paper_coordinates_at_the_straight_pose_are_refused_at_load(q_e, tmp_path):
    """Was numpy warnings, then 'array must not contain infs or NaNs', exit 1."""
    text = SCENE.replace("[pressure]", "[initial]\n" + (f"q_e = {q_e}\n" if q_e else "") + "[pressure]")
    text = text.replace("[[segments]]", '[[segments]]\ncoords = "paper"', 1)
    if q_e is None:
        text = text.replace("[initial]\n", "")
    with pytest.raises(SceneError) as exc:
        parse_scene(text)
    keys = [p.key for p in exc.value.problems]
    assert "initial.q_e[0][2]" in keys, exc.value.problems
    assert 'coords = "curvature"' in str(exc.value)


# fixed examples (CI sees the same ones every run), no example database written in the repository
FUZZ = settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True,
                database=None)


def put(d: dict, table: str, key: str, value) -> dict:
    """``d`` with ``value`` at ``table.key`` (``segments[]``, ``obstacles[]``, ``loads[]`` meaning
    the first of them, made if missing)."""
    if table == "":
        d[key] = value
    elif table.endswith("[]"):
        d.setdefault(table[:-2], [{}])[0][key] = value
    elif table == "base.motion":
        d.setdefault("base", {"type": "prescribed"})["motion"][key] = value
    else:
        d.setdefault(table, {})[key] = value
    return d


def dotted(table: str, key: str) -> str:
    return key if table == "" else f"{table[:-2] + '[0]' if table.endswith('[]') else table}.{key}"


#: a valid obstacle of each type, far from base_scene's arm, and a valid load
FAR_OBSTACLES = {
    "halfspace": {"type": "halfspace", "point": [0.0, 0.0, -1.0]},
    "sphere": {"type": "sphere", "center": [0.0, 0.0, 5.0], "radius": 0.1},
    "capsule": {"type": "capsule", "a": [1.0, 0.0, 0.0], "b": [2.0, 0.0, 0.0], "radius": 0.1},
    "cylinder": {"type": "cylinder", "a": [1.0, 0.0, 0.0], "b": [1.0, 0.0, 1.0], "radius": 0.1},
    "box": {"type": "box", "center": [1.0, 0.0, 0.0], "half_extents": [0.1, 0.2, 0.3]},
}
LOAD = {"segment": 1, "alpha": 1.0, "force": [0.0, 0.0, -0.5]}
#: a valid tension schedule of each kind for one tendon
TENSIONS = {"constant": {"type": "constant", "value": [1.0]}, "step": {"type": "step", "time": 0.05, "after": [1.0]},
            "ramp": {"type": "ramp", "t0": 0.0, "t1": 0.05, "end": [1.0]},
            "sine": {"type": "sine", "amplitude": [0.5], "offset": [1.0], "frequency": 2.0},
            "table": {"type": "table", "times": [0.0, 0.05], "values": [[0.0], [1.0]]}}


def context_for(table: F.KeyTable, f: F.Field) -> dict:
    """A valid scene in which ``f`` is a key that belongs (its base or pressure type)."""
    if table is F.PRESSURE:
        return base_scene(kind=f.when[0] if f.when else "constant")
    if table is F.MOTION:
        return base_scene(base="prescribed")
    if table is F.BASE and f.when:
        return base_scene(base=f.when[0])
    if table is F.OBSTACLE:
        d = base_scene()
        d["obstacles"] = [dict(FAR_OBSTACLES[f.when[0] if f.when else "sphere"])]
        return d
    if table is F.LOAD:
        d = base_scene()
        d["loads"] = [dict(LOAD)]
        return d
    if table is F.PAYLOAD:
        d = base_scene()
        d["payload"] = {"mass": 0.05}
        return d
    if table is F.TENDONS:
        d = base_scene()
        d["tendons"] = [{"radius": 0.005}]
        return d
    if table is F.TENSION:
        d = base_scene()
        d["tendons"] = [{"radius": 0.005}]
        d["tension"] = dict(TENSIONS[f.when[0] if f.when else "constant"])
        return d
    if table is F.SIMULATION and f.key == "dt":
        d = base_scene()
        d["simulation"]["method"] = "rk4"
        return d
    return base_scene()


FIELDS = [(t, f) for t in F.TABLES for f in t.fields]


def problems(text: str, path="scene.toml") -> SceneError:
    with deadline(20):
        with pytest.raises(SceneError) as exc:
            parse_scene(text, path)
    return exc.value


def test_docs_scene_format_is_generated_from_the_schema():
    doc = (ROOT / "docs" / "scene-format.md").read_text(encoding="utf-8")
    assert doc == F.markdown(), "regenerate it: .venv/bin/python -m qchain.scene.format > docs/scene-format.md"


def test_the_format_docs_example_is_a_valid_scene():
    scene = parse_scene(F.EXAMPLE, "example.toml")
    model = scene.build()
    assert model.chain.n == 3
    assert np.all(np.isfinite(model.chain.forward_dynamics(model.q0, model.v0, scene.pressure(0.0))))


def test_every_table_of_the_scene_module_is_declared():
    from qchain.scene import scene

    assert scene._TOP_KEYS == F.TOP.keys()
    top_tables = {f.key for f in F.TOP.fields if f.kind in ("table", "tables")}
    declared = {t.path.split(".")[0].rstrip("[]") for t in F.TABLES if t.path}
    assert top_tables == declared


@pytest.mark.parametrize("table, f", FIELDS, ids=[dotted(t.path, f.key) for t, f in FIELDS])
def test_every_declared_key_refuses_a_value_of_the_wrong_type_by_name(table, f):
    """Each key of the declaration, given a value of a type it does not take (an inline
    table, or a string for a table), gives a problem naming that key."""
    d = put(context_for(table, f), table.path, f.key, "x" if f.kind in ("table", "tables") else {"x": 1})
    err = problems(to_toml(d))
    key = dotted(table.path, f.key)
    assert any(p.key == key or p.key.startswith(key + "[") for p in err.problems), str(err)


NUMERIC = [(t, f) for t, f in FIELDS if f.range is not None and f.kind in
           ("number", "integer", "vector", "matrix", "per_segment", "number_or_per_segment", "times", "rows")]


def bad_value(f: F.Field):
    """A value that ``f`` must refuse, of the shape it takes."""
    entry = st.one_of(outside(f.range), NOT_NUMBERS)
    if f.kind in ("number", "integer"):
        return entry
    size = f.size or 6
    if f.kind == "rows":
        return st.lists(entry, min_size=6, max_size=6).map(lambda row: [[0.0] * 6, row])
    if f.kind == "times":
        return st.lists(entry, min_size=2, max_size=2)
    if f.kind == "matrix":  # one bad entry in an otherwise valid matrix (zeros)
        return st.tuples(st.integers(0, size * size - 1), entry).map(
            lambda ie: [[ie[1] if size * i + j == ie[0] else 0.0 for j in range(size)] for i in range(size)])
    return st.tuples(st.integers(0, size - 1), entry).map(lambda ie: [ie[1] if i == ie[0] else 0.5
                                                                      for i in range(size)])


@pytest.mark.slow
@FUZZ
@given(data=st.data())
def test_fuzzed_scene_values_give_one_clean_error_naming_the_key(data):
    table, f = data.draw(st.sampled_from(NUMERIC), label="field")
    value = data.draw(bad_value(f), label="value")
    d = put(context_for(table, f), table.path, f.key, value)
    if table is F.SIMULATION and f.key == "max_step":
        d["simulation"]["method"] = "dopri5"
    if table is F.MODEL and f.key == "max_bend":
        d["model"]["node_tolerance"] = 1e-6
    err = problems(to_toml(d))
    key = dotted(table.path, f.key)
    assert any(p.key == key or p.key.startswith(key + "[") for p in err.problems), str(err)
    assert "Traceback" not in str(err)


TREES = st.recursive(
    st.one_of(st.none().map(lambda _: "none"), st.booleans(), st.integers(-(10**25), 10**25),
              st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=12)),
    lambda inner: st.lists(inner, max_size=5) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=20,
)
PLACES = [(t.path, f.key) for t in F.TABLES for f in t.fields] + [("", "extra"), ("segments[]", "extra")]


@pytest.mark.slow
@FUZZ
@given(place=st.sampled_from(PLACES), tree=TREES, kind=st.sampled_from(F.PRESSURE_KINDS),
       base=st.sampled_from(("fixed", "floating", "prescribed")))
def test_any_toml_value_anywhere_gives_a_scene_or_a_scene_error(place, tree, kind, base):
    """Whatever TOML value sits at whatever key (nested arrays and tables, mixed types, NaN,
    huge integers, long strings), the file loads or raises ``SceneError`` listing keyed
    problems: never another exception, never a hang."""
    d = base_scene(kind=kind, base=base)
    table, key = place
    if table == "base.motion" and base != "prescribed":
        table = ""
    put(d, table, key, tree)
    with deadline(20):
        try:
            scene = parse_scene(to_toml(d), "tree.toml")
        except SceneError as err:
            assert err.problems and all(p.key and p.expected and p.found for p in err.problems), str(err)
        else:
            assert scene.n >= 1


def test_a_file_with_many_problems_lists_fifty_and_keeps_them_all():
    d = base_scene()
    for k in range(120):
        d[f"unknown{k}"] = k
    err = problems(to_toml(d))
    assert len(err.problems) == 120
    assert str(err).count("\n  unknown") == 50 and "... and 70 more (SceneError.problems lists them all)" in str(err)


@pytest.mark.slow
@settings(max_examples=150, deadline=None, derandomize=True, database=None)
@given(data=st.data())
def test_valid_fuzzed_scenes_build_finite_models_and_describe_without_nan(data):
    """Scenes with every segment value drawn inside its declared range either load (and
    build a model with finite dynamics, described without NaN) or are refused by a
    cross-key check (chambers that do not fit, the budget) -- nothing else."""
    d = base_scene(kind=data.draw(st.sampled_from(F.PRESSURE_KINDS)),
                   base=data.draw(st.sampled_from(("fixed", "floating", "prescribed"))))
    for j in range(len(d["segments"])):
        s = data.draw(segments_in_range(fit=st.floats(0.01, 1.2)))  # some chambers too large, refused by name
        d["segments"][j] = {k: float(x) for k, x in s.items()}
    d["gravity"] = data.draw(st.lists(st.floats(-1e4, 1e4), min_size=3, max_size=3))
    d["simulation"]["duration"] = data.draw(st.floats(1e-3, 10.0))
    d["output"] = {"sample_rate": data.draw(in_range(B.SAMPLE_RATE, low=1.0, high=1e4))}
    with deadline(30):
        try:
            scene = parse_scene(to_toml(d), "fuzz.toml")
        except SceneError as err:
            assert all(p.key and p.expected for p in err.problems)
            return
        model = scene.build(reduce=False)
        text = "\n".join(scene.describe(model)).lower()
    assert not re.search(r"\b(nan|inf)\b", text), text
    ch = model.chain
    p = np.zeros(ch.nu) if scene.pressure is None else scene.pressure(0.0)
    try:
        a = ch.forward_dynamics(model.q0, model.v0, p)
    except QchainError as err:
        assert "not positive definite" in str(err) or "not finite" in str(err), str(err)
    else:
        assert np.all(np.isfinite(a))


NESTED_600 = "x = " + "[" * 600 + "]" * 600 + "\n"
INLINE_600 = "x = " + "{a = " * 600 + "1" + "}" * 600 + "\n"


def _scene(mutate) -> str:
    d = base_scene()
    mutate(d)
    return to_toml(d)


# (scene text, the key named, a fragment of what was expected): every scene-file case of issue 18
ISSUE_SCENES = {
    "arrays nested 600 deep": (NESTED_600 + to_toml(base_scene()), "(file)", "nested at most 32 deep"),
    "inline tables nested 600 deep": (INLINE_600 + to_toml(base_scene()), "(file)", "nested at most 32 deep"),
    "count = 10**12": (_scene(lambda d: d["segments"][0].update(count=10**12)), "segments[0].count",
                       "at most budget.max_segments = 1000 segments"),
    "nodes = 1000000": (_scene(lambda d: d["segments"][0].update(nodes=1000000)), "segments[0].nodes",
                        "an integer >= 1 and <= 100"),
    "radius = 1e300": (_scene(lambda d: d["segments"][0].update(radius=1e300)), "segments[0].radius",
                       "a number >= 1e-06 and <= 10 (m)"),
    "length = 1e300": (_scene(lambda d: d["segments"][0].update(length=1e300)), "segments[0].length",
                       "a number >= 1e-05 and <= 100 (m)"),
    "max_step = 1e-300": (_scene(lambda d: d["simulation"].update(max_step=1e-300)), "simulation.max_step",
                          "at most 10000000 steps (budget.max_steps; raise it in [budget]"),
    "rk4 dt = 1e-300": (_scene(lambda d: d["simulation"].update(method="rk4", dt=1e-300)), "simulation.dt",
                        "at most 10000000 steps (budget.max_steps"),
    "sample_rate = 1e9": (_scene(lambda d: d.update(output={"sample_rate": 1e9})), "output.sample_rate",
                          "at most 1000000 output samples (budget.max_samples"),
    "sine frequency = 1e300": (
        _scene(lambda d: d.update(pressure=dict(base_scene("sine")["pressure"], frequency=1e300))),
        "pressure.frequency", "a number >= 0 and <= 10000 (Hz)"),
    "sine frequency 1e4 Hz for 1e4 s": (
        _scene(lambda d: (d.update(pressure=dict(base_scene("sine")["pressure"], frequency=1e4)),
                          d["simulation"].update(duration=1e4), d.update(output={"sample_rate": 1.0}))),
        "pressure.frequency", "at most 10000000 steps"),
    "base motion 1e4 Hz for 1e4 s": (
        _scene(lambda d: (d.update(base=base_scene(base="prescribed")["base"]),
                          d["base"]["motion"].update(frequency=1e4), d["simulation"].update(duration=1e4),
                          d.update(output={"sample_rate": 1.0}))),
        "base.motion.frequency", "at most 10000000 steps"),
    "base velocity 1e300": (_scene(lambda d: d.update(base={"type": "floating", "velocity": [1e300, 0.0, 0.0]})),
                            "base.velocity[0]", "a number >= -1000 and <= 1000 (m/s)"),
    "duration = 1e300": (_scene(lambda d: d["simulation"].update(duration=1e300)), "simulation.duration",
                         "a number >= 1e-12 and <= 1e+12 (s)"),
    "duration = 1e9 at 100 Hz": (_scene(lambda d: d["simulation"].update(duration=1e9)), "output.sample_rate",
                                 "at most 1000000 output samples"),
    "folder with a NUL": (_scene(lambda d: d.update(output={"folder": "out/a\0b"})), "output.folder",
                          "without a NUL character"),
    "folder component of 300 bytes": (_scene(lambda d: d.update(output={"folder": "out/" + "x" * 300})),
                                      "output.folder", "path components of at most 255 bytes"),
    "initial l = 1e300": (_scene(lambda d: d.update(initial={"q_e": [[1e300, 0, 0], [0.08, 0, 0]]})),
                          "initial.q_e[0][0]", "l <= 10 x length"),
    "initial rate 1e300": (_scene(lambda d: d.update(initial={"v": [1e300, 0, 0, 0, 0, 0]})), "initial.v[0]",
                           "a number >= -1e+06 and <= 1e+06"),
    "integer too large for a float": ("[simulation]\nduration = 1" + "0" * 400 + "\n" + "\n".join(
        to_toml(base_scene()).split("\n")[:-1]).replace("[simulation]\n\"duration\" = 0.1", ""),
        "simulation.duration", "a number >= 1e-12"),
}


@pytest.mark.parametrize("case", list(ISSUE_SCENES), ids=list(ISSUE_SCENES))
def test_issue_18_scene_cases_are_refused_naming_key_and_bound(case):
    text, key, expected = ISSUE_SCENES[case]
    err = problems(text)
    hits = [p for p in err.problems if p.key == key]
    assert hits, str(err)
    assert any(expected in p.expected for p in hits), str(err)


def test_raising_the_budget_in_the_file_lets_the_run_through():
    d = base_scene()
    d["simulation"].update(method="rk4", dt=1e-8, duration=0.5)
    err = problems(to_toml(d))
    assert "simulation.dt" in str(err) and "budget.max_steps" in str(err)
    d["budget"] = {"max_steps": 10**9, "max_samples": 10**6}
    scene = parse_scene(to_toml(d), "scene.toml")
    assert scene.budget.max_steps == 10**9
    with pytest.raises(BudgetError, match=r"budget.max_steps: expected at most 1000000000 steps"):
        scene.simulate(duration=100.0)  # 1e10 steps: refused before it starts, naming the bound


def test_the_memory_budget_names_the_key_that_makes_the_cost():
    d = base_scene()
    d["budget"] = {"max_memory": 1e5}
    d["segments"][0]["count"] = 30  # nv = 93: the solver's matrices dominate
    d["pressure"] = {"type": "constant", "value": [0.0] * 93}
    err = problems(to_toml(d))
    assert [p.key for p in err.problems] == ["segments"], str(err)
    assert "at most 97.7 KiB of output arrays and solver matrices (budget.max_memory" in err.problems[0].expected
    d = base_scene()
    d["budget"] = {"max_memory": 1e5}
    d["simulation"]["duration"] = 100.0  # 10002 samples dominate
    err = problems(to_toml(d))
    assert [p.key for p in err.problems] == ["output.sample_rate"], str(err)
    assert "1e+04 samples" in err.problems[0].found


def test_nesting_inside_strings_and_comments_is_not_nesting():
    d = base_scene()
    d["name"] = "[" * 200 + "{" * 200
    text = "# " + "[" * 500 + "\n" + to_toml(d)
    assert parse_scene(text, "s.toml").name == "[" * 200 + "{" * 200


def test_scene_simulate_checks_its_duration_and_budget_before_running():
    scene = parse_scene(to_toml(base_scene()), "s.toml")
    with pytest.raises(TypeError, match="duration must be a real number"):
        scene.simulate(duration="10")
    with pytest.raises(ValueError, match=r"duration must be >= 1e-12 and <= 1e\+12 s, got 1e\+300 s"):
        scene.simulate(duration=1e300)
    with pytest.raises(BudgetError, match=r"budget.max_samples: expected at most 1000000 output samples.*"
                                          r"raise it in the scene's \[budget\] table"):
        scene.simulate(duration=1e9)
    with pytest.raises(BudgetError):
        scene.sample_times(1e9)


def test_load_scene_refuses_what_is_not_a_readable_regular_file(tmp_path):
    fifo = tmp_path / "fifo.toml"
    os.mkfifo(fifo)
    with deadline(10):
        with pytest.raises(SceneError, match=r"fifo.toml: \(file\): expected a regular scene file, found a FIFO"):
            load_scene(fifo)
    with pytest.raises(SceneError, match=r"expected a regular scene file, found a device"):
        load_scene("/dev/zero")
    big = tmp_path / "big.toml"
    big.write_text("# padding\n" * (F.MAX_SCENE_BYTES // 10 + 10))
    with pytest.raises(SceneError, match=r"expected a scene file of at most 8388608 bytes"):
        load_scene(big)
    latin = tmp_path / "latin.toml"
    latin.write_bytes(b'name = "caf\xe9"\n')
    with pytest.raises(SceneError, match=r"expected a readable UTF-8 text file"):
        load_scene(latin)
    with pytest.raises(TypeError, match=r"load_scene: path must be a str or os.PathLike naming a scene file, got None"):
        load_scene(None)


def test_parse_scene_refuses_text_that_is_not_text():
    with pytest.raises(TypeError,
                       match=r"parse_scene: text must be the TOML text of a scene \(a str\), got an int 123"):
        parse_scene(123)
    with pytest.raises(TypeError, match=r"parse_scene: path must be None, a str or os.PathLike"):
        parse_scene("", path=3.5)
    assert parse_scene(to_toml(base_scene()).encode(), "b.toml").n == 2
    with pytest.raises(SceneError, match=r"expected UTF-8 text"):
        parse_scene(b"name = '\xff'")


# ----------------------------------------------------------------------------------------
# [[tendons]] and [tension] (qchain/scene/tendons.py): bad values named by key, value, bound


def _tendon_scene(mutate) -> str:
    """base_scene with one tendon and a constant tension of 1 N, then ``mutate``d."""
    d = base_scene()
    d["tendons"] = [{"radius": 0.005}]
    d["tension"] = {"type": "constant", "value": [1.0]}
    mutate(d)
    return to_toml(d)


TENDON_ERRORS = {
    "radius 0": (lambda d: d["tendons"][0].update(radius=0),
                 "tendons[0].radius: expected a number > 0 and <= 10 (m), found 0"),
    "radius 20 m": (lambda d: d["tendons"][0].update(radius=20.0),
                    "tendons[0].radius: expected a number > 0 and <= 10 (m), found 20.0"),
    "pitch too short": (lambda d: d["tendons"][0].update(pitch=1e-5),
                        "tendons[0].pitch: expected a number (m) with |pitch| >= 0.0001 and <= 1e+06 m, found 1e-05"),
    "pitch too long, left-handed": (lambda d: d["tendons"][0].update(pitch=-2e6),
                                    "tendons[0].pitch: expected a number (m) with |pitch| >= 0.0001 and <= 1e+06 m, "
                                    "found -2000000.0"),
    "pitch nan": (lambda d: d["tendons"][0].update(pitch=math.nan), "tendons[0].pitch: expected a number (m) with "
                  "|pitch| >= 0.0001 and <= 1e+06 m, found nan"),
    "pitch boolean": (lambda d: d["tendons"][0].update(pitch=True), "tendons[0].pitch: expected a number (m) with "
                      "|pitch| >= 0.0001 and <= 1e+06 m, found a boolean true"),
    "angle nan": (lambda d: d["tendons"][0].update(angle=math.nan),
                  "tendons[0].angle: expected a finite number >= -1000 and <= 1000 (rad), found nan"),
    "end past the tip": (lambda d: d["tendons"][0].update(end=2),
                         "tendons[0].end: expected a segment index < 2 (the arm's segments, count expanded), found 2"),
    "end negative": (lambda d: d["tendons"][0].update(end=-1), "tendons[0].end: expected an integer >= 0, found -1"),
    "unknown key": (lambda d: d["tendons"][0].update(rdius=0.01),
                    "tendons[0].rdius: expected one of the keys radius, angle, pitch, end (did you mean 'radius'?)"),
    "not an array of tables": (lambda d: d.update(tendons={"radius": 0.01}),
                               "tendons: expected an array of tables [[tendons]], found a table {radius = 0.01}"),
    "negative tension": (lambda d: d["tension"].update(value=[-1.0]),
                         "tension.value[0]: expected a number >= 0 and <= 1e+09 (N), found -1.0"),
    "tension over the bound": (lambda d: d["tension"].update(value=[2e9]),
                               "tension.value[0]: expected a number >= 0 and <= 1e+09 (N), found 2000000000.0"),
    "two tensions for one tendon": (lambda d: d["tension"].update(value=[1.0, 2.0]),
                                    "tension.value: expected an array of 1 tension (N), one a tendon, found 2 numbers "
                                    "[1.0, 2.0]"),
    "tension without tendons": (lambda d: d.pop("tendons"), "tension: expected no [tension] without [[tendons]]"),
    "ramp backwards": (lambda d: d.update(tension={"type": "ramp", "t0": 0.1, "t1": 0.05, "end": [1.0]}),
                       "tension.t1: expected a time > t0 = 0.1 s, found 0.05"),
    "table times not increasing": (lambda d: d.update(tension={"type": "table", "times": [0.0, 0.0],
                                                               "values": [[0.0], [1.0]]}),
                                   "tension.times[1]: expected a time > times[0] = 0 s (strictly increasing), found 0"),
    "table rows missing": (lambda d: d.update(tension={"type": "table", "times": [0.0, 0.1], "values": [[0.0]]}),
                           "tension.values: expected 2 tension arrays, one for each of the 2 times, found 1 arrays"),
    "table negative": (lambda d: d.update(tension={"type": "table", "times": [0.0, 0.1], "values": [[0.0], [-3.0]]}),
                       "tension.values[1][0]: expected a number >= 0 and <= 1e+09 (N), found -3.0"),
    "kind": (lambda d: d.update(tension={"type": "triangle"}),
             'tension.type: expected one of "constant", "step", "ramp", "sine", "table", found a string "triangle"'),
    "sine pushes": (lambda d: d.update(tension={"type": "sine", "amplitude": [2.0], "offset": [1.5], "frequency": 1.0}),
                    "tension.offset: expected offset - |amplitude| >= 0 N (a tendon cannot push) for every tendon, "
                    "found -0.5 N for tendon 0"),
    "sine over the bound": (lambda d: d.update(tension={"type": "sine", "amplitude": [5e8], "offset": [6e8],
                                                        "frequency": 1.0}),
                            "tension.offset: expected offset + |amplitude| <= 1e+09 N for every tendon, found "
                            "1.1e+09 N for tendon 0"),
    "sine without frequency": (lambda d: d.update(tension={"type": "sine", "amplitude": [1.0], "offset": [1.0]}),
                               "tension.frequency: expected a frequency (Hz), a number or one a tendon, found nothing"),
    "sine phases for two tendons": (lambda d: d.update(tension={"type": "sine", "amplitude": [1.0], "offset": [1.0],
                                                                "frequency": 1.0, "phase": [0.0, 1.0]}),
                                    "tension.phase: expected a number (rad) or an array of 1 numbers (rad), one a tendon, found 2 "
                                    "numbers [0.0, 1.0]"),
    "step without after": (lambda d: d.update(tension={"type": "step", "time": 0.1}),
                           "tension.after: expected an array of 1 tension (N), one a tendon, found nothing (the key is "
                           "required)"),
}


@pytest.mark.parametrize("case", list(TENDON_ERRORS), ids=list(TENDON_ERRORS))
def test_tendon_and_tension_values_are_refused_naming_key_value_and_bound(case):
    mutate, message = TENDON_ERRORS[case]
    err = problems(_tendon_scene(mutate))
    assert len(err.problems) == 1, str(err)  # one problem, not a cascade
    assert message in str(err.problems[0]), str(err)


def test_a_valid_tendon_scene_reads_into_tendons_and_a_schedule():
    from qchain import Tendon

    text = _tendon_scene(lambda d: (d["tendons"].append({"radius": 0.004, "angle": 1.0, "pitch": -0.5, "end": 0}),
                                    d.update(tension={"type": "step", "time": 0.05, "after": [2.0, 3.0]})))
    scene = parse_scene(text, "tendons.toml")
    a, b = scene.tendons
    assert (a.radius, a.angle, a.pitch, a.end) == (0.005, 0.0, None, None)
    assert (b.radius, b.angle, b.pitch, b.end) == (0.004, 1.0, -0.5, 0)
    assert all(isinstance(td, Tendon) for td in scene.tendons)
    np.testing.assert_array_equal(scene.tension(0.0), [0.0, 0.0])
    np.testing.assert_array_equal(scene.tension(0.06), [2.0, 3.0])
    assert scene.build().chain.nt == 2


def test_a_sine_of_tensions_reads_into_the_sine_schedule():
    """``[tension]`` of type ``sine``: one frequency for all or one a tendon, the phase, the
    offset; the schedule equals :class:`qchain.sim.inputs.Sine` with the same numbers."""
    from qchain.sim.inputs import Sine

    text = _tendon_scene(lambda d: (d["tendons"].append({"radius": 0.004, "angle": 1.0}),
                                    d.update(tension={"type": "sine", "amplitude": [1.0, -0.5], "offset": [2.0, 0.5],
                                                      "frequency": [2.0, 0.0], "phase": 0.3})))
    scene = parse_scene(text, "tendons.toml")
    ref = Sine(amplitude=[1.0, -0.5], frequency=[2.0, 0.0], phase=[0.3, 0.3], offset=[2.0, 0.5])
    for t in (0.0, 0.07, 0.31):
        np.testing.assert_array_equal(scene.tension(t), ref(t))
    assert scene.tension(0.125)[0] == pytest.approx(2.0 + np.sin(0.5 * np.pi + 0.3))


def _damping_scene(mutate) -> str:
    """base_scene with no stiffness-proportional damping, then ``mutate``d."""
    d = base_scene()
    for s in d["segments"]:
        s["damping"] = 0.0
    mutate(d)
    return to_toml(d)


EYE = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
DAMPING_ERRORS = {
    "drag_linear negative": (lambda d: d["segments"][0].update(drag_linear=-1.0),
                             "segments[0].drag_linear: expected a number >= 0 and <= 10000 (N s/m^2), found -1.0"),
    "drag_quadratic over the bound": (lambda d: d["segments"][1].update(drag_quadratic=1e6),
                                      "segments[1].drag_quadratic: expected a number >= 0 and <= 100000 (kg/m^2), "
                                      "found 1000000.0"),
    "drag_linear nan": (lambda d: d["segments"][0].update(drag_linear=math.nan),
                        "segments[0].drag_linear: expected a finite number >= 0 and <= 10000 (N s/m^2), found nan"),
    "drag in paper coordinates": (lambda d: d["segments"][0].update(coords="paper", drag_quadratic=2.0),
                                  'segments[0].drag_quadratic: expected drag_quadratic only with coords = "curvature" '
                                  "(it is given and applied in curvature coordinates), found drag_quadratic = 2.0 "
                                  "with coords = 'paper'"),
    "matrix not symmetric": (lambda d: d["segments"][0].update(damping_matrix=[[1.0, 0.1, 0.0], [0.0, 1.0, 0.0],
                                                                               [0.0, 0.0, 1.0]]),
                             "segments[0].damping_matrix: expected a symmetric matrix (entry [0][1] equal to [1][0] "
                             "within 1e-12 relative), found [0][1] = 0.1, [1][0] = 0.0"),
    "matrix not positive semi-definite": (
        lambda d: d["segments"][0].update(damping_matrix=[[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
        "segments[0].damping_matrix: expected a positive semi-definite matrix (it dissipates: every eigenvalue >= 0 "
        "within 1e-12 of its largest entry), found ((1, 2, 0), (2, 1, 0), (0, 0, 1)), with an eigenvalue -1"),
    "matrix entry nan": (lambda d: d["segments"][1].update(damping_matrix=[[1.0, 0.0, 0.0], [0.0, math.nan, 0.0],
                                                                           [0.0, 0.0, 1.0]]),
                         "segments[1].damping_matrix[1][1]: expected a finite number, found a float nan"),
    "matrix entry over the bound": (lambda d: d["segments"][0].update(damping_matrix=[[1e16, 0.0, 0.0],
                                                                                      [0.0, 1.0, 0.0],
                                                                                      [0.0, 0.0, 1.0]]),
                                    "segments[0].damping_matrix[0][0]: expected a number >= -1e+15 and <= 1e+15 "
                                    "(N s/m, N m s, N m^3 s), found 1e+16"),
    "matrix of two rows": (lambda d: d["segments"][0].update(damping_matrix=EYE[:2]),
                           "segments[0].damping_matrix: expected 3 arrays of 3 numbers, one a row (N s/m, N m s, N m^3 s), "
                           "found an array [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]"),
    "matrix and damping": (lambda d: d["segments"][0].update(damping=0.01, damping_matrix=EYE),
                           "segments[0].damping: expected 0 with damping_matrix (the matrix replaces beta K(q0)), "
                           "found 0.01"),
    "matrix in paper coordinates": (lambda d: d["segments"][0].update(coords="paper", damping_matrix=EYE),
                                    'segments[0].damping_matrix: expected damping_matrix only with coords = '
                                    '"curvature" (it is given and applied in curvature coordinates), found '
                                    "damping_matrix = ((1, 0, 0), (0, 1, 0), (0, 0, 1)) with coords = 'paper'"),
}


@pytest.mark.parametrize("case", list(DAMPING_ERRORS), ids=list(DAMPING_ERRORS))
def test_drag_and_damping_matrix_values_are_refused_naming_key_value_and_bound(case):
    mutate, message = DAMPING_ERRORS[case]
    err = problems(_damping_scene(mutate))
    assert len(err.problems) == 1, str(err)  # one problem, not a cascade
    assert message in str(err.problems[0]), str(err)


def test_valid_drag_and_damping_matrix_reach_the_segments():
    """The keys reach qchain.Segment: the matrix (read as rows) is the segment's D, the drag
    coefficients its c_1, c_2; a segment without them keeps beta K(q0) and no drag."""
    D = [[5.0, 0.02, 0.0], [0.02, 1e-3, 0.0], [0.0, 0.0, 2e-3]]
    scene = parse_scene(_damping_scene(lambda d: d["segments"][0].update(damping_matrix=D, drag_linear=0.5,
                                                                          drag_quadratic=24.0)))
    seg0, seg1 = (s.segment() for s in scene.segments)
    np.testing.assert_array_equal(seg0.dissipation_matrix(seg0.neutral()), D)
    assert (seg0.drag_linear, seg0.drag_quadratic) == (0.5, 24.0)
    assert seg1.damping_matrix is None and (seg1.drag_linear, seg1.drag_quadratic) == (0.0, 0.0)
