"""What ``qchain run`` writes and prints: output paths it cannot write are refused before the run,
a standard output it cannot write loses no recording, names are escaped and plain text."""

import os
import re
import subprocess
import sys
import time

import numpy as np
import pytest

from qchain.cli.main import main
from qchain.logging import read_recording
from qchain.scene import SceneError, load_scene, parse_scene
from support import ONE_SEGMENT_SCENE, SCENE, base_scene, error_line, run, to_toml


def qchain_run(args, cwd, env=None, seconds=120):
    return subprocess.run([sys.executable, "-m", "qchain", *map(str, args)], cwd=cwd, capture_output=True, text=True,
                          timeout=seconds, env={**os.environ, **(env or {})})


@pytest.mark.slow
def test_a_scene_name_with_dollars_is_plain_text_and_the_data_come_first(tmp_path, monkeypatch, capsys):
    """'$...$' in the name was matplotlib's mathtext: the plots failed after the run and
    trajectory.npz, written after them, was lost."""
    from qchain.cli.main import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(ONE_SEGMENT_SCENE.replace("NAME", r"cost $\\undefinedmacro{x}$ at $x^$"))
    assert main(["run", "s.toml", "--no-record", "--out", "o"]) == 0, capsys.readouterr().err
    assert (tmp_path / "o" / "tip.png").stat().st_size > 1000 and (tmp_path / "o" / "trajectory.npz").is_file()
    import matplotlib.figure

    def full(*a, **k):
        raise OSError(27, "File too large")

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", full)
    assert main(["run", "s.toml", "--no-record", "--out", "o2"]) == 1
    err = capsys.readouterr().err
    assert "qchain run: error: could not write o2/tip.png (File too large)" in err, err
    assert np.load(tmp_path / "o2" / "trajectory.npz")["q"].shape == (11, 3)
    assert sorted(p.name for p in (tmp_path / "o2").iterdir()) == ["trajectory.npz"]


def test_rerun_rate_holds_without_a_recording_too(tmp_path, monkeypatch):
    """``--rerun-rate`` with ``--no-record`` and a viewer or .rrd only: the logger gets the
    rate as it does when the run is recorded."""
    from qchain.cli import recording as qlog

    made = []
    real = qlog.RunLogger

    def spy(*args, **kwargs):
        made.append(kwargs.get("rerun_rate"))
        return real(*args, **kwargs)

    monkeypatch.setattr(qlog, "RunLogger", spy)
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(ONE_SEGMENT_SCENE.replace("NAME", "rate"))
    for flags in (["--no-record", "--rrd", "v.rrd"], ["--mcap", "r.mcap"]):
        assert main(["run", "s.toml", "--duration", "0.01", "--no-plots", "--rerun-rate", "25", *flags]) == 0
    assert made == [25.0, 25.0] and (tmp_path / "v.rrd").stat().st_size > 0


def test_run_flags_the_header_and_the_recording_agree(tmp_path, monkeypatch, capsys):
    from qchain.cli.main import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(ONE_SEGMENT_SCENE.replace("NAME", "flags"))
    assert main(["run", "s.toml", "--no-record", "--mcap", "m.mcap", "--duration", "0.01", "--out", "else"]) == 0
    out = capsys.readouterr().out
    assert "simulation: 0.01 s, radau5" in out and "output: 200 Hz to else, plots: tip" in out, out
    assert len(read_recording(tmp_path / "m.mcap")) == 3  # --no-record, but --mcap asks for one
    code = main(["run", "s.toml", "--mcap", "newdir/", "--no-plots"])
    assert code == 2 and "argument --mcap: expected a file's path, found 'newdir/'" in capsys.readouterr().err
    assert not (tmp_path / "newdir").exists()


def test_the_environment_a_run_cannot_work_in_is_refused(tmp_path):
    (tmp_path / "s.toml").write_text(ONE_SEGMENT_SCENE.replace("NAME", "env"))
    r = qchain_run(["run", "s.toml", "--no-record"], tmp_path, env={"NUMBA_DISABLE_JIT": "1"})
    assert r.returncode == 2 and "NUMBA_DISABLE_JIT=1 is set" in r.stderr and "Traceback" not in r.stderr
    gone = tmp_path / "gone"
    gone.mkdir()
    r = subprocess.run(f"cd {gone} && rmdir {gone} && {sys.executable} -m qchain run ../s.toml --no-record",
                       shell=True, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "the working folder cannot be used" in r.stderr, r.stderr
    r = subprocess.run(f"{sys.executable} -m qchain info s.toml >&-", shell=True, cwd=tmp_path, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 1 and "standard output is closed: the result has nowhere to go" in r.stderr


def test_a_recorded_run_past_two_to_the_32_seconds_is_refused_before_the_build(tmp_path, monkeypatch, capsys):
    """Foxglove timestamps count seconds in 32 bits: a run of 7.5e9 s failed after the build
    (the writer's OverflowError), and recover then failed too; a sweep reported success
    with 5 of its 11 samples recorded."""
    from qchain.cli.main import main
    from qchain.recording.records import T_MAX

    assert T_MAX == 2**32 - 1
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(ONE_SEGMENT_SCENE.replace("NAME", "long").replace("duration = 0.05", "duration = 7.5e9")
                                     .replace("sample_rate = 200.0", "sample_rate = 1e-9"))
    assert main(["run", "s.toml", "--no-plots", "--mcap", "r.mcap"]) == 2
    err = capsys.readouterr()
    assert "simulation.duration 7.5e+09 s: a recorded run lasts at most 4294967295 s" in err.err and \
        "scene:" not in err.out
    assert main(["run", "s.toml", "--no-plots", "--no-record", "--duration", "5e9", "--rrd", "x.rrd"]) == 2
    assert "--duration 5e+09 s: a recorded run lasts at most" in capsys.readouterr().err
    from qchain.batch.sweep_spec import Axis, SweepError, SweepSpec
    from qchain.scene import load_scene

    spec = SweepSpec(scene=load_scene(tmp_path / "s.toml"), axes=[Axis("segments[0].damping", values=(0.01,))],
                     mcap=True, folder=tmp_path / "sw")
    from qchain.batch.sweeps import run_sweep

    with pytest.raises(SweepError, match=r"simulation.duration: expected at most 4294967295 s for a recorded run"):
        run_sweep(spec, workers=1)


def test_outputs_a_run_could_not_write_are_refused_before_it_starts(tmp_path, monkeypatch, capsys):
    from qchain.cli.main import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(ONE_SEGMENT_SCENE.replace("NAME", "outs"))
    for args, said in ((["--out", "o", "--mcap", "o"], "is the plots' folder"),
                       (["--out", "o2/sub", "--mcap", "o2"], "or a folder above it"),
                       (["--mcap", "r.mcap.journal", "--no-plots"], "the name of a recording's journal")):
        assert main(["run", "s.toml", *args]) == 2
        err = capsys.readouterr().err
        assert said in err, err
    assert not (tmp_path / "o").exists() and not (tmp_path / "o2").exists()
    (tmp_path / "dl.mcap").symlink_to("nothere/x.mcap")
    assert main(["run", "s.toml", "--no-plots", "--mcap", "dl.mcap"]) == 2
    assert "whose folder does not exist" in capsys.readouterr().err


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


def test_a_scene_name_with_a_newline_or_an_escape_stays_on_its_error_line(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    p = tmp_path / "a\nqchain info: error: fake\x1b[31m.toml"
    p.write_text(SCENE.replace("length = 0.1", "length = -1"))
    code, _, err = run(["info", p], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "\x1b" not in err, err
    assert "a\\nqchain info: error: fake\\x1b[31m.toml" in err, err


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
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


def test_control_characters_of_a_scene_are_escaped_in_info_and_run(scene, capsys):
    scene.write_text(SCENE.replace('name = "adversarial"', 'name = "a\\nb\\u001b[31mRED"'))
    for argv in (["info", scene], ["run", scene, "--no-record", "--no-plots", "--no-progress"]):
        code, out, err = run(argv, capsys)
        assert code == 0, err
        assert "\x1b" not in out and "a\\nb\\x1b[31mRED" in out, out
        (line,) = [x for x in out.splitlines() if x.startswith("scene:")]
        assert line.endswith("(a\\nb\\x1b[31mRED)"), line


@pytest.mark.slow
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


def test_output_folders_that_cannot_be_written_are_refused_before_the_run(tmp_path, monkeypatch):
    scene = parse_scene(to_toml(base_scene()), tmp_path / "s.toml")
    assert scene.check_output(tmp_path / "out" / "run") == tmp_path / "out" / "run"
    assert (tmp_path / "out" / "run").is_dir()
    (tmp_path / "file").write_text("x")
    with pytest.raises(SceneError, match=r"output.folder: expected a folder .*, found .*file is a file"):
        scene.check_output(tmp_path / "file" / "run")
    with pytest.raises(SceneError, match=r"output.folder: expected a folder qchain can write in, found /proc/"):
        scene.check_output("/proc/qchain-no-such-place/run")  # not writable, not even by root
    with pytest.raises(SceneError, match=r"without a NUL character"):
        scene.check_output(str(tmp_path / "a\0b"))
    import collections
    import shutil

    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(10**9, 10**9 - 1000, 1000))  # a full disk
    with pytest.raises(SceneError, match=r"output.folder: expected room for the outputs, about .* MiB, found "
                                         r"0.000954 MiB free"):
        scene.check_output(tmp_path / "out")


def test_a_tendon_scene_runs_records_and_plots_its_tensions(tmp_path, capsys):
    """`qchain run` of examples/scenes/hanging_tendons.toml: the tensions of the ramp in
    trajectory.npz and in the MCAP (read back), tension.png beside pressure.png, and the
    tendons said by the run's description."""
    from pathlib import Path

    from qchain.sim.inputs import Ramp

    scene = Path(__file__).parent.parent / "examples" / "scenes" / "hanging_tendons.toml"
    mcap, out = tmp_path / "run.mcap", tmp_path / "out"
    assert main(["run", str(scene), "--duration", "0.2", "--mcap", str(mcap), "--out", str(out),
                 "--no-progress"]) == 0, capsys.readouterr().err
    said = capsys.readouterr().out
    assert "tendon 1: radius 0.012 m, angle 1.5708 rad, helical, pitch 1.2 m, to the tip" in said
    assert (out / "tension.png").is_file() and (out / "pressure.png").is_file()
    data = np.load(out / "trajectory.npz")
    ramp = Ramp(0.0, 0.5, np.array([5.0, 4.0]), np.zeros(2))
    np.testing.assert_array_equal(data["tension"], np.array([ramp(t) for t in data["t"]]))
    rec = read_recording(mcap)
    assert rec.damage == [] and rec.info.params["tendons"][0]["end"] == 1
    np.testing.assert_array_equal(rec.tension, data["tension"])
    np.testing.assert_array_equal(rec.q, data["q"])


def test_a_recording_keeps_each_segments_damping_law(tmp_path, capsys):
    """`qchain run` of a scene with the medium's drag and a damping matrix: the recording's
    parameters give each segment's law as the scene set it (read back from the MCAP)."""
    from pathlib import Path

    text = (Path(__file__).parent.parent / "examples" / "scenes" / "tip_control.toml").read_text()
    text = text.replace("damping = 0.02\n", "damping_matrix = [[1e-4, 0.0, 0.0], [0.0, 2e-5, 0.0], [0.0, 0.0, 2e-5]]\n"
                        "drag_linear = 0.5\ndrag_quadratic = 2.0\n")
    scene = tmp_path / "dragged.toml"
    scene.write_text(text)
    mcap = tmp_path / "run.mcap"
    assert main(["run", str(scene), "--duration", "0.02", "--mcap", str(mcap), "--no-plots", "--no-progress"]) == 0, \
        capsys.readouterr().err
    segs = read_recording(mcap).info.params["segments"]
    assert len(segs) == 3
    for s in segs:
        assert s["drag_linear"] == 0.5 and s["drag_quadratic"] == 2.0 and s["damping"] == 0.0
        assert s["damping_matrix"] == [[1e-4, 0.0, 0.0], [0.0, 2e-5, 0.0], [0.0, 0.0, 2e-5]]
