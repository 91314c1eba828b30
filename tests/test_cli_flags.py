"""The ``qchain`` command's flags and inputs: numbers outside their range, durations, viewer
URLs, serve addresses and a sweep that would expand past the budget are refused before the
run, naming flag, bound and value."""

import math
import re
import time

import pytest
from hypothesis import given
from hypothesis import strategies as st

from helpers import deadline
from qchain.batch.sweep_spec import apply_values
from qchain.checks import bounds as B
from qchain.cli.checks import BadInput, check_flag_values, check_viewer_url, flag_ranges
from qchain.cli.main import main
from support import AXIS, FAST, SCENE, SWEEP_HEAD, error_line, run, sweep_file


def test_replay_checks_its_viewer_flags_as_run_does(whole, tmp_path, capsys):
    from qchain.cli.recording import replay_main

    data, _, _, _ = whole
    path = tmp_path / "run.mcap"
    path.write_bytes(data)
    assert replay_main([str(path), "--connect", "ftp://x y"]) == 2
    assert "argument --connect: expected" in capsys.readouterr().err
    assert replay_main([str(path), "--serve", "--bind", "bad host!"]) == 2
    assert "argument --bind: expected an IPv4 address" in capsys.readouterr().err
    assert replay_main([str(path), "--serve", "--bind", "::1"]) == 2
    assert "IPv6 is not served" in capsys.readouterr().err


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


def test_check_flag_values_at_a_closed_bound_and_past_it():
    ranges = {"duration": ("--duration", B.DURATION)}

    class A:
        duration = B.DURATION.high

    check_flag_values(A, ranges)
    A.duration = math.nextafter(B.DURATION.high, math.inf)
    with pytest.raises(BadInput, match=re.escape(f"found {A.duration!r}")):
        check_flag_values(A, ranges)


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
