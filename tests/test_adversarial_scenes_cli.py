"""Bad input tried again (issue 18, "done when"): a fresh set of bad scene files, command
lines and sweep files, each of which once ended in a hang, an errno exit 1, a silent
acceptance or a message naming nothing. Now each is refused before anything runs, with exit
code 2 and a line naming the flag or key, the value and the bound.

The generator that found them (1036 cases run as processes) is not part of the suite; these
are its representative failures, run in this process (``qchain.cli.main``).
"""

import math
import os
import re
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from helpers import SEGMENTS_TOML, deadline
from qchain.checks import bounds as B
from qchain.cli.main import main
from qchain.cli.checks import BadInput, check_flag_values, check_viewer_url, flag_ranges
from qchain.scene import SceneError, load_scene, parse_scene
from qchain.batch.sweep_spec import (
    DEFAULT_MAX_RUNS, Axis, SweepError, SweepSpec, address_problem, apply_values, check_results_folder, load_sweep,
    runs_problem)

FAST = settings(max_examples=60, deadline=2000, derandomize=True, database=None)

SCENE = """
name = "adversarial"
""" + SEGMENTS_TOML + """[pressure]
type = "constant"
value = [1e4, 0, 0, 0, 2e4, 2e4]
[simulation]
duration = 0.02
method = "rk4"
dt = 1e-3
[output]
sample_rate = 100.0
plots = []
"""


@pytest.fixture
def scene(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    p = tmp_path / "scene.toml"
    p.write_text(SCENE)
    return p


def run(argv, capsys, seconds=30):
    with deadline(seconds, f"qchain {' '.join(map(str, argv))[:80]}"):
        code = main([str(a) for a in argv])
    got = capsys.readouterr()
    return code, got.out, got.err


def error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if ": error: " in line]
    assert len(lines) == 1, err
    return lines[0]


# --------------------------------------------------------------------------------------
# flags: every numeric flag in its declared range, checked before the scene is read


@pytest.mark.parametrize("flag, value, bound", [
    ("--duration", "nan", ">= 1e-12 and <= 1e+12 (s)"),
    ("--duration", "-inf", ">= 1e-12 and <= 1e+12 (s)"),
    ("--duration", "1e13", ">= 1e-12 and <= 1e+12 (s)"),
    ("--duration", "-0", ">= 1e-12 and <= 1e+12 (s)"),
    ("--rerun-rate", "nan", "> 0 and <= 1e+09 (Hz)"),  # was accepted and ignored
    ("--rerun-rate", "-5", "> 0 and <= 1e+09 (Hz)"),
    ("--rerun-rate", "0", "> 0 and <= 1e+09 (Hz)"),
    ("--viewer-timeout", "0", "> 0 and <= 3600 (s)"),
])
def test_numeric_flags_outside_their_range_are_refused_naming_flag_bound_and_value(flag, value, bound, scene,
                                                                                  capsys):
    code, out, err = run(["run", scene, "--no-record", "--no-progress", f"{flag}={value}"], capsys)
    assert code == 2, err
    line = error_line(err)
    assert line.startswith(f"qchain run: error: argument {flag}: expected a number {bound}, found "), line
    assert line.endswith(f"found {float(value):g}"), line
    assert "simulated" not in out and "scene:" not in out


def test_a_duration_over_the_budget_names_the_flag(scene, capsys):
    code, out, err = run(["run", scene, "--no-record", "--no-progress", "--duration", "1e5"], capsys)
    assert code == 2
    assert error_line(err).startswith("qchain run: error: --duration 100000 s: the run would exceed its budget"), err
    assert "budget.max_steps: expected at most 10000000 steps" in err


@given(value=st.floats(allow_nan=True, allow_infinity=True))
@FAST
def test_check_flag_values_refuses_exactly_what_is_outside_the_range(value):
    class Args:
        duration = value
        rerun_rate = None
        viewer_timeout = None

    inside = math.isfinite(value) and B.DURATION.contains(value)
    try:
        check_flag_values(Args())
    except BadInput as err:
        assert not inside
        assert str(err) == f"argument --duration: expected {B.DURATION.what()}, found {value:g}"
    else:
        assert inside
    assert set(flag_ranges()) == {"duration", "rerun_rate", "viewer_timeout"}


# --------------------------------------------------------------------------------------
# viewers and addresses


@pytest.mark.parametrize("url, words", [
    ("rerun+http://127.0.0.1:70000/proxy", "a port from 1 to 65535"),  # was a warning, the run went on
    ("rerun+http://127.0.0.1:0/proxy", "a port from 1 to 65535"),
    ("rerun+http://127.0.0.1:abc/proxy", "a port from 1 to 65535"),
    ("", "found an empty string"),  # was taken as no viewer at all
    ("file:///etc/passwd", "a URL of scheme rerun+http"),
    ("rerun+http://" + "a" * 100000, "naming a host"),  # was "encoding with 'idna' codec failed"
    ("not a url", "without spaces"),
])
def test_a_viewer_url_that_cannot_name_a_viewer_is_refused_before_the_run(url, words, scene, capsys):
    code, out, err = run(["run", scene, "--no-record", "--no-progress", "--connect", url], capsys)
    assert code == 2
    line = error_line(err)
    assert line.startswith("qchain run: error: argument --connect: expected ") and words in line, line
    assert len(line) < 400 and "simulated" not in out


def test_serve_and_connect_together_are_refused_instead_of_serving_for_ever(scene, capsys):
    """It used to warn about the viewer, run, then serve a viewer until Ctrl-C."""
    code, out, err = run(["run", scene, "--no-record", "--serve", "--connect", "rerun+http://127.0.0.1:9/proxy"],
                         capsys, seconds=20)
    assert code == 2
    assert error_line(err) == "qchain run: error: argument --connect: not allowed with --serve (they exclude each " \
                              "other: serve a viewer here, or stream to a running one)"
    assert "simulated" not in out


@pytest.mark.parametrize("bind", ["999.1.1.1", "", "a b"])
def test_an_address_to_serve_on_that_is_no_address_is_refused(bind, scene, capsys):
    code, out, err = run(["run", scene, "--no-record", "--serve", "--bind", bind], capsys, seconds=20)
    assert code == 2
    assert error_line(err) == f"qchain run: error: argument --bind: expected an IPv4 address (127.0.0.1, 0.0.0.0) " \
                              f"or a host name, found {bind!r}"


@pytest.mark.parametrize("bind, why", [
    ("::1", "expected an IPv4 address (IPv6 is not served), found '::1': use 127.0.0.1 (this machine) or 0.0.0.0"),
    ("[::1]", "expected an IPv4 address (IPv6 is not served), found '[::1]'"),
    ("no-such-host.invalid", "the host name 'no-such-host.invalid' has no IPv4 address"),
])
def test_an_address_the_viewer_cannot_be_served_on_is_refused_before_the_run(bind, why, scene, capsys):
    """Once accepted, then a warning that Rerun could not start (no free port on ::1, or
    'invalid socket address syntax' for a name) and a run without its viewer."""
    code, out, err = run(["run", scene, "--no-record", "--serve", "--bind", bind], capsys, seconds=30)
    assert code == 2 and "simulated" not in out
    assert error_line(err).startswith(f"qchain run: error: argument --bind: {why}"), err


def test_a_host_name_to_serve_on_is_resolved_to_its_ipv4_address():
    from qchain.recording.rerun_sink import listen_address

    assert listen_address("localhost") == "127.0.0.1"
    assert listen_address("127.0.0.1") == "127.0.0.1" and listen_address("0.0.0.0") == "0.0.0.0"


def test_the_web_front_says_nothing_of_a_client_that_sends_garbage(capfd):
    """A local client sending a request with a huge Content-Length and hanging up once put
    socketserver's traceback (BrokenPipeError) on a serving run's stderr."""
    import socket
    import struct

    from qchain.recording.web_viewer import LoopbackFront

    upstream = socket.create_server(("127.0.0.1", 0))  # answers nothing: the requests never get that far
    front = LoopbackFront("127.0.0.1", 0, upstream.getsockname()[1], 1)
    try:
        for payload in (b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 99999999999\r\n\r\nabc",
                        b"\x16\x03\x01garbage\r\n\r\n", b"GET /" + b"a" * 70000 + b" HTTP/1.1\r\n\r\n") * 3:
            c = socket.create_connection(("127.0.0.1", front.port), timeout=5)
            c.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # hang up with a reset
            c.sendall(payload)
            c.close()
        time.sleep(1.0)  # the server's threads answer into the reset connections
    finally:
        front.close()
        upstream.close()
    err = capfd.readouterr().err
    assert "Traceback" not in err and "Exception occurred" not in err, err


@given(url=st.text(max_size=60) | st.builds(lambda h, p: f"rerun+http://{h}:{p}/proxy", st.text(max_size=20),
                                              st.integers(-10, 100000)))
@FAST
def test_check_viewer_url_says_one_line_or_accepts_a_usable_url(url):
    from urllib.parse import urlsplit

    try:
        check_viewer_url("argument --connect", url)
    except BadInput as err:
        assert str(err).startswith("argument --connect: expected ") and "\n" not in str(err)
    else:
        parts = urlsplit(url)
        assert parts.scheme in ("rerun+http", "rerun+https", "rerun", "http", "https") and parts.hostname
        assert parts.port is None or 1 <= parts.port <= 65535


def test_the_viewer_timeout_reaches_the_probe(scene, capsys, monkeypatch):
    import qchain.cli.main as cli

    seen = []
    monkeypatch.setattr(cli, "viewer_silence", lambda url, timeout: seen.append(timeout) or "nothing there")
    code, out, err = run(["run", scene, "--no-record", "--no-plots", "--no-progress", "--connect",
                          "rerun+http://127.0.0.1:9/proxy", "--viewer-timeout", "0.25"], capsys)
    assert code == 0, err
    assert seen == [0.25]
    assert "warning: no Rerun viewer answers at rerun+http://127.0.0.1:9/proxy (nothing there)" in err


# --------------------------------------------------------------------------------------
# output paths


@pytest.mark.parametrize("flag", ["--out", "--mcap", "--rrd"])
def test_an_empty_output_path_is_refused_not_taken_as_the_working_folder(flag, scene, capsys):
    code, out, err = run(["run", scene, "--no-progress", flag, ""], capsys)
    assert code == 2
    assert error_line(err) == f"qchain run: error: argument {flag}: expected a path, found an empty string"
    assert not (scene.parent / "trajectory.npz").exists()


@pytest.mark.parametrize("path, kind", [("/dev/null", "a device"), ("/dev/full", "a device"), ("loop.mcap", None),
                                        ("folder", "a folder")])
def test_a_recording_path_that_is_no_file_is_refused_before_the_run(path, kind, scene, capsys):
    """/dev/null, /dev/full and a loop of links ran the whole arm, then failed with exit 1."""
    if path == "loop.mcap":
        os.symlink(scene.parent / path, scene.parent / path)
    if path == "folder":
        (scene.parent / path).mkdir()
    code, out, err = run(["run", scene, "--no-plots", "--no-progress", "--mcap", path], capsys)
    assert code == 2
    line = error_line(err)
    want = f"is {kind}: expected a regular file" if kind else "cannot be used: Too many levels of symbolic links"
    assert line.startswith(f"qchain run: error: --mcap path {path} ") and want in line, line
    assert "simulated" not in out


@pytest.mark.parametrize("where", ["--out", "output.folder"])
def test_a_folder_path_the_system_cannot_take_is_a_bad_input_naming_it(where, scene, capsys):
    """A path over PATH_MAX and a 300-byte component ended in ``[Errno 36]`` and exit code 1."""
    long = "/".join(["d" * 200] * 25)
    if where == "--out":
        argv = ["run", scene, "--no-record", "--no-progress", "--out", "x" * 300]
    else:
        scene.write_text(SCENE.replace("plots = []", f'plots = []\nfolder = "{long}"'))
        argv = ["run", scene, "--no-record", "--no-progress"]
    code, out, err = run(argv, capsys)
    assert code == 2
    line = error_line(err)
    if where == "--out":
        assert line.startswith("qchain run: error: --out xxxx") and "File name too long" in line, line
    else:
        assert f"output.folder: expected a folder path of at most 4095 bytes, found {len(long)} bytes" in line, line
    assert len(line) < 600 and "simulated" not in out


# --------------------------------------------------------------------------------------
# scene files


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


# --------------------------------------------------------------------------------------
# sweeps


SWEEP_HEAD = 'scene = "scene.toml"\nfolder = "res"\n'
AXIS = '[[axes]]\nkey = "segments[0].damping"\nvalues = [0.01, 0.02]\n'


def sweep_file(tmp_path, text):
    (tmp_path / "scene.toml").write_text(SCENE)
    p = tmp_path / "study.toml"
    p.write_text(text)
    return p


@pytest.mark.parametrize("text, key, found", [
    (SWEEP_HEAD + '[[axes]]\nkey = "segments[0].damping"\nrange = [0.0, 1.0]\nnum = 1000000000\n', "axes",
     "a grid of 1e+09 runs: 1000000000 (segments[0].damping) values"),
    (SWEEP_HEAD + "".join(f'[[axes]]\nkey = "{k}"\nvalues = {[0.01 * j for j in range(1, 11)]}\n' for k in (
        "gravity[0]", "gravity[1]", "gravity[2]", "segments[0].damping", "segments[1].damping", "segments[0].mass")),
     "axes", "a grid of 1e+06 runs: 10 (gravity[0]) x 10 (gravity[1])"),
    (SWEEP_HEAD + '[sampling]\nkind = "random"\nn = 1000000000\n' + AXIS, "sampling.n", "n = 1000000000"),
    (SWEEP_HEAD + '[sampling]\nkind = "lhs"\nn = 9223372036854775807\n' + AXIS, "sampling.n", "n = 9223372036854775807"),
])
def test_a_sweep_of_too_many_runs_is_refused_before_any_is_made(text, key, found, tmp_path):
    """A grid of 1e9 runs, or n = 1e9, was made run by run (minutes, gigabytes) or ended in
    numpy's 'array is too big'."""
    p = sweep_file(tmp_path, text)
    with deadline(10, "a huge sweep"):
        with pytest.raises(SweepError) as exc:
            load_sweep(p)
    (prob,) = exc.value.problems
    assert prob.key == key and prob.expected == f"at most [sampling] max_runs = {DEFAULT_MAX_RUNS} runs (raise it " \
                                                "to allow more)", prob
    assert prob.found.startswith(found), prob.found


def test_raising_max_runs_lets_a_larger_sweep_through_and_the_api_checks_it_too(tmp_path):
    text = SWEEP_HEAD + '[sampling]\nkind = "random"\nn = 200000\nmax_runs = 300000\n' + AXIS
    spec = load_sweep(sweep_file(tmp_path, text))
    assert spec.n == 200000 and spec.max_runs == 300000
    with pytest.raises(ValueError, match=r"sampling.n: expected at most \[sampling\] max_runs = 100000 runs"):
        SweepSpec(scene=spec.scene, axes=spec.axes, sampling="random", n=200000)
    with deadline(5, "a grid counted"):
        with pytest.raises(ValueError, match=r"axes: expected at most .* a grid of 1e\+12 runs"):
            SweepSpec(scene=spec.scene, axes=[Axis("segments[0].damping", range=(0, 1), num=10**6),
                                              Axis("segments[1].damping", range=(0, 1), num=10**6)])


@given(sizes=st.lists(st.integers(1, 10**4), min_size=0, max_size=5), limit=st.integers(1, 10**8))
@FAST
def test_runs_problem_counts_the_grid_without_making_it(sizes, limit):
    axes = [Axis(f"segments[0].{k}", range=(0.0, 1.0), num=n) for k, n in zip(
        ["damping", "mass", "radius", "length", "youngs_modulus"], sizes)]
    got = runs_problem("grid", None, axes, limit)
    assert (got is None) == (math.prod(sizes) <= limit)


def test_each_segment_is_not_expanded_past_the_segment_budget(tmp_path):
    """count = 2**62 with ``{each_segment = ...}`` asked for a list of 2**62 entries: out of memory."""
    raw = {"segments": [{"count": 2**62}], "pressure": {"value": {"each_segment": [0, 0, 0]}}}
    with deadline(5, "each_segment"):
        out = apply_values(raw, {})
    assert out["pressure"]["value"] == {"each_segment": [0, 0, 0]}
    assert apply_values({"segments": [{"count": 2}], "pressure": {"value": {"each_segment": [1, 2, 3]}}},
                        {})["pressure"]["value"] == [1, 2, 3, 1, 2, 3]
    text = SWEEP_HEAD + '[set]\n"segments[0].count" = 4611686018427387904\n' \
                        '"pressure.value" = { each_segment = [0, 0, 0] }\n' + AXIS
    with deadline(20, "a sweep with 2**62 segments"):
        assert main(["sweep", str(sweep_file(tmp_path, text)), "--dry-run"]) == 2


@pytest.mark.parametrize("make, found", [
    (lambda p: os.mkfifo(p), "expected a regular sweep file, found a FIFO"),  # hung
    (lambda p: os.symlink("/dev/zero", p), "expected a regular sweep file, found a device"),  # hung
    (lambda p: p.write_text("x = " + "[" * 600 + "]" * 600 + "\n"), "nested at most 32 deep"),  # RecursionError
    (lambda p: p.write_bytes(b'scene = "sc\xe9ne.toml"\n'), "expected a readable UTF-8 text file"),
    (lambda p: p.write_bytes(b"#" * (9 * 2**20)), "expected a sweep file of at most 8388608 bytes"),
])
def test_a_sweep_file_that_is_not_a_text_file_is_refused_at_once(make, found, tmp_path):
    p = tmp_path / "study.toml"
    make(p)
    with deadline(10, "reading a sweep file"):
        with pytest.raises(SweepError) as exc:
            load_sweep(p)
    assert str(exc.value).startswith(f"{p}: (file): ") and found in str(exc.value), str(exc.value)


@pytest.mark.parametrize("top, table, key, words", [
    ('folder = ""', "", "folder", "a folder path"),  # wrote the results into the working folder
    ('name = "../../x"', "", "name", "no NUL, / or \\"),
    ('metrics = "no_such_module_here:f"', "", "metrics", "module 'no_such_module_here' cannot be imported"),  # rows failed
    ("", "[engine]\nworkers = 100000", "engine.workers", "an integer >= 1 and <= 1024"),  # one process a worker
    ("", '[engine]\ndask = "not an address"', "engine.dask", "a Dask scheduler's address"),  # waited 30 s or more
    ("", '[engine]\ndask = "tcp://127.0.0.1:70000"', "engine.dask", "a bad port (Port out of range"),
])
def test_sweep_file_values_are_checked_where_they_enter(top, table, key, words, tmp_path):
    p = sweep_file(tmp_path, f'scene = "scene.toml"\n{top}\n{AXIS}{table}\n')
    with deadline(20, "a sweep file"):
        with pytest.raises(SweepError) as exc:
            load_sweep(p)
    hits = [pr for pr in exc.value.problems if pr.key == key]
    assert hits and words in f"{hits[0].expected} {hits[0].found}", str(exc.value)


def test_dask_addresses():
    for good in ("tcp://127.0.0.1:8786", "127.0.0.1:8786", "tls://scheduler.example.org:8786", "inproc://x"):
        assert address_problem(good) is None, good
    for bad in ("", "tcp://:8786", "udp://1.2.3.4:1", "tcp://127.0.0.1:0", "tcp://h:abc"):
        assert address_problem(bad), bad


@pytest.mark.parametrize("files, name, words", [
    ({"sweep.json": b"\x00garbage{"}, "sweep.json", "not JSON"),
    ({"sweep.json": "[1, 2, 3]"}, "sweep.json", "a JSON object with the sweep's fingerprint"),
    ({"sweep.json": None}, "sweep.json", "a regular file, found a folder"),
    ({"runs.jsonl": '{"x": 1}\n'}, "runs.jsonl, line 1", "a JSON object with 'run', a whole run number below 2"),
    ({"runs.jsonl": '{"run": 0}\n{"run": 99}\n'}, "runs.jsonl, line 2", "below 2, found {run = 99}"),
    ({"runs.jsonl": b"\xff\xfe\n"}, "runs.jsonl, line 1", "one JSON object a finished run"),
    ({"summary.parquet": None}, "summary.parquet", "a regular file, found a folder"),
    ({"runs": b"a file"}, "runs", "a folder, found a file"),
])
def test_check_results_folder_names_the_file_a_sweep_cannot_resume_from(files, name, words, tmp_path):
    res = tmp_path / "res"
    res.mkdir()
    for f, data in files.items():
        if data is None:
            (res / f).mkdir()
        elif isinstance(data, bytes):
            (res / f).write_bytes(data)
        else:
            (res / f).write_text(data)
    with pytest.raises(SweepError) as exc:
        check_results_folder(res, n_runs=2)
    (p,) = exc.value.problems
    assert p.key == str(res / name) and words in f"{p.expected}, found {p.found}", p
    check_results_folder(tmp_path / "missing")  # a new sweep: nothing to check


@pytest.mark.parametrize("flags, words", [
    (["--workers", "100000"], "--workers must be an integer >= 1 and <= 1024, got 100000"),  # hung starting processes
    (["--workers", "0"], "--workers must be an integer >= 1 and <= 1024, got 0"),
    (["--retries", "101"], "--retries must be an integer >= 0 and <= 100, got 101"),
    (["--dask", "not an address"], "--dask 'not an address': not an address"),  # waited 45 s for a scheduler
    (["--dask", "tcp://127.0.0.1:70000"], "--dask 'tcp://127.0.0.1:70000': a bad port"),  # exit 1 after 30 s
    (["--out", ""], "argument --out: expected a path, found an empty string"),  # wrote into the working folder
])
def test_sweep_command_flags_are_refused_before_anything_runs(flags, words, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    p = sweep_file(tmp_path, SWEEP_HEAD + AXIS)
    code, out, err = run(["sweep", p, *flags], capsys, seconds=20)
    assert code == 2 and words in error_line(err), err
    assert not (tmp_path / "res").exists() and "runs;" not in out  # nothing was made or run


def test_a_results_folder_a_sweep_cannot_resume_from_is_refused_before_any_run(tmp_path, capsys, monkeypatch):
    """A damaged ``runs.jsonl`` ended in a JSONDecodeError, KeyError or TypeError; a run
    number out of range was taken as a finished run."""
    monkeypatch.chdir(tmp_path)
    p = sweep_file(tmp_path, SWEEP_HEAD + AXIS)
    (tmp_path / "res").mkdir()
    (tmp_path / "res" / "runs.jsonl").write_text('{"run": 0}\n{"run": 7}\n')
    code, _, err = run(["sweep", p, "--workers", "1", "--no-progress"], capsys)
    line = error_line(err)
    assert code == 2 and "runs.jsonl, line 2" in line and "found {run = 7}" in line, err
    assert sorted(x.name for x in (tmp_path / "res").iterdir()) == ["runs.jsonl"]  # nothing written, nothing lost


def test_the_python_sweep_refuses_engine_arguments_where_they_enter(tmp_path):
    from qchain import sweep
    from qchain.batch.workers import LocalPool, resolve_workers

    (tmp_path / "scene.toml").write_text(SCENE)
    axes = {"segments[0].damping": [0.01, 0.02]}
    for kw, words in (({"workers": 10**9}, "workers must be None or -1 (every core), an int >= 1 and <= 1024"),
                      ({"workers": True}, "workers must be None or -1"),
                      ({"retries": -1}, "retries must be an int >= 0 and <= 100, got an int -1"),
                      ({"client": 3.5}, "client must be None, a scheduler address")):
        with deadline(10, f"sweep({kw})"), pytest.raises((TypeError, ValueError)) as exc:
            sweep(tmp_path / "scene.toml", axes, folder=tmp_path / "res", **kw)
        assert words in str(exc.value), (kw, str(exc.value))
    assert not (tmp_path / "res").exists()
    with pytest.raises(ValueError, match="<= 1024 or a qchain.batch.workers.LocalPool, got an int 1000000000"):
        LocalPool(10**9)
    assert resolve_workers(2) == 2 and resolve_workers(-1) >= 1


def test_a_scene_name_with_a_newline_or_an_escape_stays_on_its_error_line(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    p = tmp_path / "a\nqchain info: error: fake\x1b[31m.toml"
    p.write_text(SCENE.replace("length = 0.1", "length = -1"))
    code, _, err = run(["info", p], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "\x1b" not in err, err
    assert "a\\nqchain info: error: fake\\x1b[31m.toml" in err, err


# --------------------------------------------------------------------------------------
# the summary's wall time is the simulation's


def test_the_wall_time_excludes_finishing_the_recording(scene, capsys, monkeypatch):
    """A viewer that stalls the recording's close (up to ~10 s) made the run look that slow."""
    from qchain import logging as qlog

    close = qlog.RunLogger.close

    def slow_close(self, *args, **kwargs):
        time.sleep(1.5)
        return close(self, *args, **kwargs)

    monkeypatch.setattr(qlog.RunLogger, "close", slow_close)
    code, out, err = run(["run", scene, "--no-plots", "--no-progress", "--mcap", scene.parent / "r.mcap"], capsys,
                         seconds=60)
    assert code == 0, err
    m = re.search(r"simulated 0\.02 s in ([0-9.e+-]+) s wall time", out)
    assert m and float(m[1]) < 1.0, out
    assert load_scene(scene).duration == 0.02


# --------------------------------------------------------------------------------------
# outputs that would lose data, a stdout that cannot be written, text shown raw


OUT_SCENE = SCENE.replace("plots = []", 'plots = ["tip"]\nsave = true')


@pytest.fixture
def out_scene(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    p = tmp_path / "scene.toml"
    p.write_text(OUT_SCENE)
    return p


@pytest.mark.parametrize("flag, name", [("--mcap", "trajectory.npz"), ("--mcap", "tip.png"),
                                        ("--rrd", "trajectory.npz")])
def test_a_recording_at_a_planned_output_is_refused_before_the_run(flag, name, out_scene, capsys):
    """`--out o --mcap o/trajectory.npz` ran, then the plots and trajectory.npz overwrote the recording."""
    out = out_scene.parent / "o"
    argv = ["run", out_scene, "--out", out, flag, out / name, "--no-progress"]
    if flag == "--rrd":
        argv.append("--no-record")
    code, stdout, err = run(argv, capsys)
    line = error_line(err)
    assert code == 2 and flag in line and name in line and "same file" in line, err
    assert "simulated" not in stdout and not (out / name).exists(), stdout


@pytest.mark.parametrize("name, make", [("tip.png", "dir"), ("trajectory.npz", "fifo")])
def test_a_planned_output_that_is_no_regular_file_is_refused_before_the_run(name, make, out_scene, capsys):
    """A folder at o/tip.png failed after the run ([Errno 21]); a device at o/trajectory.npz took the data."""
    out = out_scene.parent / "o"
    out.mkdir()
    if make == "dir":
        (out / name).mkdir()
    else:
        os.mkfifo(out / name)
    code, stdout, err = run(["run", out_scene, "--out", out, "--no-record", "--no-progress"], capsys)
    line = error_line(err)
    assert code == 2 and "--out" in line and name in line and "expected a regular file" in line, err
    assert "simulated" not in stdout


def _mcap_samples(path):
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    return summary.statistics.message_count if summary is not None else 0


@pytest.mark.parametrize("how", ["closed", "full", "pipe"])
def test_a_stdout_that_cannot_be_written_loses_no_recording(how, scene, tmp_path):
    """stdout closed (`>&-`) ended in 'NoneType has no attribute flush', /dev/full in [Errno 28], a closed pipe in
    EPIPE: exit 1 and no recording."""
    import subprocess
    import sys

    mcap = tmp_path / "r.mcap"
    cmd = [sys.executable, "-m", "qchain", "run", str(scene), "--no-plots", "--no-progress", "--mcap", str(mcap)]
    if how == "closed":
        proc = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, timeout=120,
                              preexec_fn=lambda: os.close(1))
    elif how == "full":
        with open("/dev/full", "w") as full:
            proc = subprocess.run(cmd, stdout=full, stderr=subprocess.PIPE, text=True, timeout=120)
    else:
        r, w = os.pipe()
        os.close(r)
        proc = subprocess.run(cmd, stdout=w, stderr=subprocess.PIPE, text=True, timeout=120)
        os.close(w)
    assert "Traceback" not in proc.stderr and "AttributeError" not in proc.stderr, proc.stderr
    if how != "pipe":
        assert proc.returncode == 0, proc.stderr
    if how != "closed":
        assert "warning: standard output:" in proc.stderr and "the rest of the summary is not shown" in proc.stderr
    assert _mcap_samples(mcap) > 0 and not (tmp_path / "r.mcap.journal").exists()


def test_a_result_printed_where_it_cannot_be_written_fails_the_command(scene, tmp_path):
    """`qchain info` and `qchain layout` print their result: with standard output /dev/full they said a
    warning and exit 0. `layout -o FILE` prints only a summary, which may be lost."""
    import subprocess
    import sys

    mcap = tmp_path / "r.mcap"
    assert main(["run", str(scene), "--no-plots", "--no-progress", "--mcap", str(mcap)]) == 0
    for args, code in ((["info", str(scene)], 1), (["layout", str(mcap)], 1),
                       (["layout", str(mcap), "-o", str(tmp_path / "l.json")], 0)):
        with open("/dev/full", "w") as full:
            proc = subprocess.run([sys.executable, "-m", "qchain", *args], stdout=full, stderr=subprocess.PIPE,
                                  text=True, timeout=120)
        assert proc.returncode == code and "Traceback" not in proc.stderr, (args, proc.stderr)
        assert "warning: standard output: No space left on device" in proc.stderr, (args, proc.stderr)


def test_a_closed_stdout_does_not_stop_a_sweep(tmp_path):
    import subprocess
    import sys

    p = sweep_file(tmp_path, SWEEP_HEAD + AXIS)
    proc = subprocess.run([sys.executable, "-m", "qchain", "sweep", str(p), "--dry-run"], stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True, timeout=120, cwd=tmp_path,
                          preexec_fn=lambda: os.close(1))
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr


def test_control_characters_of_a_scene_are_escaped_in_info_and_run(scene, capsys):
    scene.write_text(SCENE.replace('name = "adversarial"', 'name = "a\\nb\\u001b[31mRED"'))
    for argv in (["info", scene], ["run", scene, "--no-record", "--no-plots", "--no-progress"]):
        code, out, err = run(argv, capsys)
        assert code == 0, err
        assert "\x1b" not in out and "a\\nb\\x1b[31mRED" in out, out
        (line,) = [x for x in out.splitlines() if x.startswith("scene:")]
        assert line.endswith("(a\\nb\\x1b[31mRED)"), line


def test_control_characters_of_a_sweep_are_escaped_in_its_description(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    p = sweep_file(tmp_path, 'name = "s\\u001b[31m"\n' + SWEEP_HEAD + AXIS)
    code, out, err = run(["sweep", p, "--dry-run"], capsys)
    assert code == 0, err
    assert "\x1b" not in out, out


@pytest.mark.parametrize("where", ["flag", "scene"])
@pytest.mark.parametrize("value", ["4.9e-324", "1e-20", "1e-13"])
def test_a_duration_shorter_than_the_solver_takes_is_bad_input(where, value, scene, capsys):
    """Was 't_span must last at least 1.42e-14 s', exit 1, naming t_span."""
    if where == "flag":
        code, _, err = run(["run", scene, "--duration", value, "--no-record", "--no-plots"], capsys)
        name = "--duration"
    else:
        scene.write_text(SCENE.replace("duration = 0.02", f"duration = {value}").replace('method = "rk4"\ndt = 1e-3\n',
                                                                                         ""))
        code, _, err = run(["run", scene, "--no-record", "--no-plots"], capsys)
        name = "simulation.duration"
    line = error_line(err) if where == "flag" else err
    assert code == 2 and name in line and ">= 1e-12" in line and "t_span" not in err, err


def test_the_shortest_accepted_duration_runs(scene, capsys):
    scene.write_text(SCENE.replace('method = "rk4"\ndt = 1e-3\n', ""))
    code, _, err = run(["run", scene, "--duration", "1e-12", "--no-record", "--no-plots", "--no-progress"], capsys)
    assert code == 0, err


@pytest.mark.parametrize("flag, value", [("--duration", "1000000000000.0001"), ("--viewer-timeout", "3600.0000000001")])
def test_a_value_just_past_its_bound_is_shown_with_all_its_digits(flag, value, scene, capsys):
    code, _, err = run(["run", scene, flag, value], capsys)
    line = error_line(err)
    assert code == 2 and line.endswith(f"found {value}"), line


def test_a_c_locale_without_coercion_shows_a_non_ascii_name_escaped(tmp_path):
    import subprocess
    import sys

    p = tmp_path / "é🦑.toml"
    p.write_text(SCENE)
    env = dict(os.environ, LC_ALL="C", PYTHONCOERCECLOCALE="0", PYTHONUTF8="0")
    proc = subprocess.run([sys.executable, "-m", "qchain", "info", os.fsencode(p)], capture_output=True, env=env,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert b"codec" not in proc.stderr and b"scene: " in proc.stdout
    # a run names its recording after the scene: in characters this file system's encoding takes
    proc = subprocess.run([sys.executable, "-m", "qchain", "run", os.fsencode(p), "--no-plots", "--no-progress"],
                          capture_output=True, env=env, timeout=120, cwd=tmp_path)
    assert proc.returncode == 0 and b"codec" not in proc.stderr, proc.stderr
    assert [f.name for f in (tmp_path / "runs").iterdir() if f.suffix == ".mcap"], list((tmp_path / "runs").iterdir())


def test_check_flag_values_at_a_closed_bound_and_past_it():
    ranges = {"duration": ("--duration", B.DURATION)}

    class A:
        duration = B.DURATION.high

    check_flag_values(A, ranges)
    A.duration = math.nextafter(B.DURATION.high, math.inf)
    with pytest.raises(BadInput, match=re.escape(f"found {A.duration!r}")):
        check_flag_values(A, ranges)


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


def test_an_explicit_method_on_a_stiff_scene_is_refused_before_anything_is_recorded(tmp_path, capsys):
    """Once 1e7 steps of about 1e-14 s (a minute) before the step budget stopped it; now the
    stability limit of dopri5's step at the start puts it over budget.max_steps at once."""
    text = SCENE.replace('method = "rk4"\ndt = 1e-3', 'method = "dopri5"').replace("youngs_modulus = 1e5",
                                                                                   "youngs_modulus = 1e12")
    text = text.replace("length = 0.1", "length = 1e-5")
    assert "1e12" in text and "1e-5" in text and "dopri5" in text
    p = tmp_path / "stiff.toml"
    p.write_text(text)
    t = time.perf_counter()
    code, out, err = run(["run", p, "--mcap", tmp_path / "stiff.mcap", "--no-progress"], capsys)
    assert code == 2 and time.perf_counter() - t < 30, err
    line = error_line(err)
    assert re.search(r"stiff.toml: the run would exceed its budget, refused before it starts: budget.max_steps: "
                     r"expected at most 10000000 steps, found [0-9.e+]+ steps \(duration 0.02 s / dopri5's stability "
                     r"limit of the step at the start, about [0-9.e+-]+ s: the model is stiff for an explicit "
                     r"method, use method 'radau5'\) \(raise it in the scene's \[budget\] table\)", line), line
    assert not (tmp_path / "stiff.mcap").exists() and "simulated" not in out
    code, out, err = run(["run", p, "--no-record", "--no-progress", "--no-plots"], capsys, seconds=60)
    assert code == 2  # the same with no recording
    p.write_text(text.replace('method = "dopri5"', 'method = "radau5"'))
    code, out, err = run(["run", p, "--no-record", "--no-progress", "--no-plots"], capsys, seconds=60)
    assert code == 0 and "run: success" in out, err
