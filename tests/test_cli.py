"""The ``qchain`` command: info, run (summary, outputs, recording, progress), exit codes."""

import os
import re
import signal
import time
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import SHORT_SCENE
from qchain.cli.main import main
from qchain.scene import load_scene

EXAMPLES = Path(__file__).parents[1] / "examples" / "scenes"

SHORT = SHORT_SCENE + 'plots = ["tip", "arm", "energy", "pressure"]\n'


@pytest.fixture
def short_scene(tmp_path):
    p = tmp_path / "short.toml"
    p.write_text(SHORT)
    return p


def test_info(capsys):
    path = EXAMPLES / "wave_arm.toml"
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    model = load_scene(path).build()
    assert f"model: nq = 9, nv = 9, free dofs = {model.chain.nv_active}, pressure inputs = 9" in out
    assert "reductions (on):" in out and "  - planar: uy locked at 0 in every segment" in out
    assert f"nodes: {', '.join(map(str, model.nodes)) if len(set(model.nodes)) > 1 else f'{model.nodes[0]} per segment'}" in out
    assert "simulation: 4 s, radau5, rtol = 0.001, atol = 1e-05" in out
    assert main(["info", str(path), "--full"]) == 0
    out = capsys.readouterr().out
    assert "free dofs = 9" in out and "planar: not tried (reduce = false)" in out and "reductions (off):" in out


@pytest.mark.slow
def test_run_prints_the_summary_and_writes_the_outputs(short_scene, tmp_path, capsys):
    out_dir = tmp_path / "results"
    code = main(["run", str(short_scene), "--out", str(out_dir), "--no-record", "--no-progress"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "run: success: The end of the time span was reached." in out
    m = re.search(r"simulated 0\.1 s in ([0-9.e+-]+) s wall time: ([0-9.e+-]+) x real time; nfev = (\d+), 11 samples, "
                  r"method rk4", out)
    assert m, (out, err)
    wall, rtf, nfev = float(m[1]), float(m[2]), int(m[3])
    assert rtf == pytest.approx(0.1 / wall, rel=0.01) and nfev == 4 * 100
    for name in ("tip.png", "arm.png", "energy.png", "pressure.png", "trajectory.npz"):
        assert (out_dir / name).is_file() and f"wrote {out_dir / name}" in out
    data = np.load(out_dir / "trajectory.npz")
    assert data["t"].shape == (11,) and bool(data["success"])
    tip = data["tip"][-1] * 1e3
    assert f"position ({tip[0]:.3f}, {tip[1]:.3f}, {tip[2]:.3f}) mm" in out
    ke, pe = data["kinetic_energy"][-1], data["potential_energy"][-1]
    assert f"kinetic {ke:.6g}, potential {pe:.6g} (gravity + elastic), total {ke + pe:.6g}" in out
    assert re.search(r"orientation rpy \(-?[0-9.]+, -?[0-9.]+, -?[0-9.]+\) deg, quaternion xyzw", out)
    assert "largest bends reached (rad): " in out and "nodes sized for" in out
    # the summary agrees with the scene run directly
    sc = load_scene(short_scene)
    traj = sc.simulate()
    assert np.array_equal(traj.q, data["q"])


def test_summary_values_of_many_segments_are_summed_up_not_listed():
    """A 1000-segment run once printed 1000 numbers on its bends line."""
    from qchain.cli.outputs import SUMMARY_LIST, _values

    few = [0.1, 0.25, 0.5]
    assert _values(few) == "0.1, 0.25, 0.5"
    many = np.linspace(0.0, 1.0, 1000)
    many[437] = 2.5
    assert _values(many) == ("1000 segments, largest 2.5 (segment 437), median "
                             f"{np.median(many):.3g}, smallest 0")
    assert len(_values(many)) < 100 and _values(np.ones(SUMMARY_LIST)).count(",") == SUMMARY_LIST - 1


def test_run_failure_exits_1(tmp_path, capsys):
    """300 kPa in one chamber curls the arm out of the model's domain: the run stops
    there, names the segment and the time, and exits 1."""
    text = SHORT.replace("end = [3e4, 0.0, 0.0,  0.0, 2e4, 0.0]", "end = [3e5, 0.0, 0.0,  0.0, 0.0, 0.0]")
    text = text.replace("node_tolerance = 1e-8", "")
    p = tmp_path / "burst.toml"
    p.write_text(text)
    code = main(["run", str(p), "--no-record", "--no-plots", "--no-progress", "--duration", "0.4"])
    out = capsys.readouterr().out
    assert code == 1
    m = re.search(r"run: FAILED: (.*)", out)
    assert m and re.search(r"segment \d \(q\[\d:\d\]\): .* must be ", m[1]), out
    assert "(at t = " in m[1]
    assert "final tip" in out  # the samples up to the failure are summarised


def test_bad_scene_exits_2(tmp_path, capsys):
    p = tmp_path / "bad.toml"
    p.write_text(SHORT.replace("radius = 0.015", "radius = -0.015"))
    assert main(["run", str(p), "--no-record"]) == 2
    err = capsys.readouterr().err
    assert f"qchain run: error: {p}: segments[0].radius: expected a number >= 1e-06 and <= 10 (m), found -0.015" in err
    assert main(["info", str(tmp_path / "missing.toml")]) == 2
    assert "expected an existing scene file, found no such file" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [[], ["simulate", "x.toml"], ["run"], ["run", "x.toml", "--duration", "-1"],
                                  ["run", "x.toml", "--progress", "--no-progress"]])
def test_usage_errors_exit_2(argv, short_scene, capsys):
    argv = [str(short_scene) if a == "x.toml" else a for a in argv]
    assert main(argv) == 2
    assert "usage: qchain" in capsys.readouterr().err


def test_help_exits_0(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert "run" in out and "info" in out
    assert main(["run", "--help"]) == 0
    out = capsys.readouterr().out
    for flag in ("--duration", "--out", "--full", "--no-plots", "--progress", "--mcap", "--serve", "--connect", "--rrd"):
        assert flag in out


def test_full_model_run(short_scene, tmp_path, capsys):
    assert main(["run", str(short_scene), "--full", "--no-record", "--no-plots", "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "reductions (off):" in out and "free dofs = 6" in out


def test_progress_bar_on_stderr(short_scene, monkeypatch, capsys):
    """``--progress`` shows simulate's bar (after a second of wall time: a fake clock here, 2 s a
    reading, as the compiled engine looks at the clock only a few times in a short run)."""
    import qchain.sim.simulation as sim

    class Clock:
        t = 0.0

        def perf_counter(self):
            self.t += 2.0
            return self.t

    monkeypatch.setattr(sim, "_time", Clock())
    assert main(["run", str(short_scene), "--no-record", "--no-plots", "--progress"]) == 0
    err = capsys.readouterr().err
    assert "100.0%" in err and "real time" in err and err.endswith("\n")
    assert main(["run", str(short_scene), "--no-record", "--no-plots", "--no-progress"]) == 0
    assert "real time" not in capsys.readouterr().err


@pytest.mark.slow
def test_run_records_an_mcap(short_scene, tmp_path, capsys):
    from qchain.logging import read_mcap

    mcap = tmp_path / "rec" / "short.mcap"
    out_dir = tmp_path / "out"
    assert main(["run", str(short_scene), "--mcap", str(mcap), "--out", str(out_dir), "--no-progress"]) == 0
    assert f"recorded {mcap}" in capsys.readouterr().out
    rec = read_mcap(mcap)
    data = np.load(out_dir / "trajectory.npz")
    assert np.array_equal(rec.t, data["t"]) and np.array_equal(rec.q, data["q"]) and np.array_equal(rec.p, data["p"])
    assert rec.success


@pytest.mark.slow
def test_the_module_runs_as_a_command(tmp_path):
    r = subprocess.run([sys.executable, "-m", "qchain", "info", str(EXAMPLES / "step_response.toml")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "nodes: 4 per segment from node_tolerance = 1e-08" in r.stdout
    r = subprocess.run([sys.executable, "-m", "qchain", "info", str(tmp_path / "none.toml")], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 2 and "no such file" in r.stderr


def test_replay_is_handed_to_the_logging_module(tmp_path, capsys):
    assert main(["replay", "--help"]) == 0
    assert "usage: qchain replay" in capsys.readouterr().out
    bad = tmp_path / "not.mcap"
    bad.write_bytes(b"not a recording")
    assert main(["replay", str(bad), "--rrd", str(tmp_path / "x.rrd")]) == 2
    assert "qchain replay: error:" in capsys.readouterr().err


# --------------------------------------------------------------------------------------
# output paths: checked before the run starts, a clear error rather than a loss


def test_recording_over_the_scene_file_is_refused(short_scene, capsys):
    before = short_scene.read_bytes()
    assert main(["run", str(short_scene), "--mcap", str(short_scene), "--no-plots", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"qchain run: error: mcap path {short_scene} is the scene file itself" in err
    assert short_scene.read_bytes() == before
    assert main(["run", str(short_scene), "--rrd", str(short_scene), "--no-record", "--no-plots", "--no-progress"]) == 2
    assert "rrd path" in capsys.readouterr().err and short_scene.read_bytes() == before


def test_one_path_for_two_outputs_is_refused(short_scene, tmp_path, capsys):
    out = tmp_path / "x.out"
    assert main(["run", str(short_scene), "--mcap", str(out), "--rrd", str(out), "--no-plots", "--no-progress"]) == 2
    assert "--mcap and --rrd are the same path" in capsys.readouterr().err
    assert not out.exists()


def test_unwritable_and_full_locations_are_refused_before_the_run(short_scene, tmp_path, capsys, monkeypatch):
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, not a folder")
    assert main(["run", str(short_scene), "--mcap", str(blocker / "run.mcap"), "--no-plots", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "cannot write mcap file" in err and "blocker/run.mcap" in err
    assert "simulated" not in capsys.readouterr().out  # no run without its recording
    import shutil

    from qchain.recording import options

    monkeypatch.setattr(options.shutil, "disk_usage", lambda p: shutil._ntuple_diskusage(10 << 30, 10 << 30, 1 << 20))
    assert main(["run", str(short_scene), "--mcap", str(tmp_path / "full.mcap"), "--no-plots", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "only 1.0 MB free" in err and "a run needs at least 17 MB" in err
    assert not (tmp_path / "full.mcap").exists()


def test_a_path_another_run_is_writing_is_refused(short_scene, tmp_path, capsys):
    """A live run holds its journal locked: a second run on the same path stops at once with
    an error naming it; the first run's recording is untouched. A killed run's journal is
    named too, with the command that recovers it."""
    from qchain.logging import LoggingError, RunLogger, journal_path, read_recording
    from logging_fixtures import arm_info, arm_records

    path = tmp_path / "shared.mcap"
    records = arm_records(30)
    with RunLogger(arm_info(), path, quiet=True) as first:
        for r in records[:10]:
            first.log(r)
        assert main(["run", str(short_scene), "--mcap", str(path), "--no-plots", "--no-progress"]) == 2
        err = capsys.readouterr().err
        assert f"another run (pid {os.getpid()}) is writing {path}" in err
        with pytest.raises(LoggingError, match="another run"):
            RunLogger(arm_info(), path, quiet=True)
        for r in records[10:]:
            first.log(r)
    rec = read_recording(path)
    assert len(rec) == 30 and not rec.truncated
    journal_path(path).write_bytes(journal_path(path).read_bytes() if journal_path(path).exists() else b"\x89MCAP0\r\n")
    assert main(["run", str(short_scene), "--mcap", str(path), "--no-plots", "--no-progress"]) == 2
    assert f"qchain recover {path}" in capsys.readouterr().err


@pytest.mark.slow
def test_an_existing_file_that_is_not_a_recording_is_not_overwritten(short_scene, tmp_path, capsys):
    notes = tmp_path / "notes.mcap"
    notes.write_text("my notes")
    assert main(["run", str(short_scene), "--mcap", str(notes), "--no-plots", "--no-progress"]) == 2
    assert "exists and is not an MCAP recording; refusing to overwrite it" in capsys.readouterr().err
    assert notes.read_text() == "my notes"
    rec = tmp_path / "again.mcap"
    assert main(["run", str(short_scene), "--mcap", str(rec), "--no-plots", "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["run", str(short_scene), "--mcap", str(rec), "--no-plots", "--no-progress"]) == 0
    assert f"qchain run: replacing the earlier recording {rec}" in capsys.readouterr().err


@pytest.mark.slow
def test_realtime_paces_the_run_to_the_wall_clock(short_scene, tmp_path, capsys):
    t0 = time.perf_counter()
    assert main(["run", str(short_scene), "--mcap", str(tmp_path / "rt.mcap"), "--no-plots", "--no-progress",
                 "--realtime", "--duration", "1.0"]) == 0
    wall = time.perf_counter() - t0
    assert wall >= 1.0  # one simulated second took at least one second
    assert "recorded" in capsys.readouterr().out


def test_recover_and_layout_commands(short_scene, tmp_path, capsys):
    import json

    path = tmp_path / "r.mcap"
    assert main(["run", str(short_scene), "--mcap", str(path), "--no-plots", "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["layout", str(path), "-o", str(tmp_path / "layout.json")]) == 0
    layout = json.loads((tmp_path / "layout.json").read_text())
    text = json.dumps(layout)
    assert '"segment 2 ux [1/m]"' in text and "/qchain/state.q[4]" in text and "/qchain/arm" in text
    whole = path.read_bytes()
    assert main(["recover", str(path)]) == 0  # a whole recording stays whole, untouched
    assert "nothing to recover" in capsys.readouterr().out and path.read_bytes() == whole
    assert main(["recover", str(tmp_path / "none.mcap")]) == 2


# --------------------------------------------------------------------------------------
# the command line as a user meets it (issue 18, part B): one-line errors, exit codes,
# --version, --debug, python -m qchain, Ctrl-C at any moment, output paths checked first

PY = sys.executable


def _said(err: str) -> str:
    """``err`` without the one-line notice of a first compile (a cold engine cache says so)."""
    return "".join(line for line in err.splitlines(keepends=True) if not line.startswith("qchain: compiling the "))


def qchain(*args, timeout=300, **kw) -> subprocess.CompletedProcess:
    """``python -m qchain ARGS`` in a process of its own."""
    return subprocess.run([PY, "-m", "qchain", *map(str, args)], capture_output=True, text=True, timeout=timeout,
                          **kw)


@pytest.mark.slow
def test_version_and_python_dash_m_qchain(tmp_path, capsys):
    from importlib.metadata import version

    r = qchain("--version")
    assert (r.returncode, r.stdout, r.stderr) == (0, f"qchain {version('qchain')}\n", "")
    assert re.fullmatch(r"qchain \d+\.\d+\.\d+\n", r.stdout)
    assert main(["--version"]) == 0 and capsys.readouterr().out == f"qchain {version('qchain')}\n"
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert "--version" in out and "--debug" in out and "2 bad input or usage" in out
    r = qchain("info", EXAMPLES / "step_response.toml")
    assert r.returncode == 0 and "nodes: 4 per segment from node_tolerance = 1e-08" in r.stdout, r.stderr
    r = qchain("info", tmp_path / "none.toml")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr == f"qchain info: error: {tmp_path / 'none.toml'}: (file): expected an existing scene file, " \
                       "found no such file\n"
    r = qchain("run")
    assert r.returncode == 2 and r.stderr.startswith("usage: qchain run") and "Traceback" not in r.stderr


def test_import_qchain_is_light_and_exports_the_error_and_budget_classes():
    code = ("import sys, qchain; print(sorted(m for m in ('numpy', 'pinocchio', 'numba', 'scipy', 'qchain.cli') "
            "if m in sys.modules))\n"
            "from qchain import NonFiniteError, Budget, BudgetError, QchainError, DomainError\n"
            "import qchain.errors as E, qchain.sim.budget as G\n"
            "print(NonFiniteError is E.NonFiniteError, Budget is G.Budget, BudgetError is G.BudgetError,\n"
            "      issubclass(NonFiniteError, QchainError), issubclass(DomainError, ValueError))\n"
            "print(all(n in qchain.__all__ and n in dir(qchain) for n in ('NonFiniteError', 'Budget', 'BudgetError')))")
    r = subprocess.run([PY, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines() == ["[]", "True True True True True", "True"]


def test_an_error_qchain_did_not_foresee_is_one_line_and_debug_shows_its_traceback(short_scene, monkeypatch, capsys):
    import qchain.cli.main as cli

    def boom(args):
        raise RuntimeError("boom\nsecond line")

    monkeypatch.setattr(cli, "_info", boom)
    assert main(["info", str(short_scene)]) == 1
    err = capsys.readouterr().err
    assert err == "qchain info: error: RuntimeError: boom second line (run with --debug for the traceback)\n"
    for argv in (["info", str(short_scene), "--debug"], ["--debug", "info", str(short_scene)]):
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert err.startswith("Traceback (most recent call last):") and 'raise RuntimeError("boom' in err
        assert err.splitlines()[-1] == "qchain info: error: RuntimeError: boom second line"


@pytest.mark.parametrize("error, code, line", [
    (ValueError("a value refused before the run"), 2, "qchain info: error: a value refused before the run"),
    (OSError(28, "No space left on device"), 1, "qchain info: error: [Errno 28] No space left on device"),
    (MemoryError(), 1, "qchain info: error: out of memory"),
    (KeyboardInterrupt(), 1, "qchain info: interrupted during start-up (nothing was run)"),
])
def test_foreseen_errors_are_one_line_with_their_exit_code(error, code, line, short_scene, monkeypatch, capsys):
    import qchain.cli.main as cli

    def fail(args):
        raise error

    monkeypatch.setattr(cli, "_info", fail)
    assert main(["info", str(short_scene)]) == code
    assert capsys.readouterr().err == line + "\n"


def test_a_closed_output_pipe_ends_the_command_quietly(short_scene, monkeypatch, capsys):
    import qchain.cli.main as cli

    def closed(args):
        raise BrokenPipeError(32, "Broken pipe")

    monkeypatch.setattr(cli, "_info", closed)
    assert main(["info", str(short_scene)]) == 1
    assert capsys.readouterr().err == ""


def test_output_folders_are_checked_before_the_model_is_built(short_scene, tmp_path, capsys, monkeypatch):
    """A folder that is a file, one that cannot be made or written, one without room: exit 2
    and one line naming it, before the model is built (the tester's traceback came after
    the whole run)."""
    blocker = tmp_path / "blocker"
    blocker.write_text("a file, not a folder")
    cases = [
        (blocker / "out", f"qchain run: error: --out {blocker / 'out'}: expected a folder (or a path where one can be "
                          f"made), found {blocker} is a file"),
        ("/proc/qchain-no-such-place/run", "qchain run: error: --out /proc/qchain-no-such-place/run: expected a folder "
                                           "qchain can write in, found /proc/qchain-no-such-place/run: "),
        (str(tmp_path / "a\0b"), "qchain run: error: --out "),
    ]
    for out, line in cases:
        assert main(["run", str(short_scene), "--out", str(out), "--no-record", "--no-progress"]) == 2
        got = capsys.readouterr()
        assert got.err.startswith(line) and got.err.count("\n") == 1, got.err
        assert "scene:" not in got.out and "simulated" not in got.out  # nothing was built or run
    # the scene's own folder, named by its key
    (tmp_path / "scene-out").write_text("a file")
    p = tmp_path / "folder.toml"
    p.write_text(SHORT.replace("[output]", f'[output]\nfolder = "{tmp_path / "scene-out"}"'))
    assert main(["run", str(p), "--no-record", "--no-progress"]) == 2
    got = capsys.readouterr()
    assert got.err == f"qchain run: error: {p}: output.folder: expected a folder (or a path where one can be made), " \
                      f"found {tmp_path / 'scene-out'} is a file\n" and "simulated" not in got.out
    # a full disk
    import shutil

    monkeypatch.setattr(shutil, "disk_usage", lambda p: shutil._ntuple_diskusage(10 << 30, 10 << 30, 1 << 16))
    assert main(["run", str(short_scene), "--out", str(tmp_path / "full"), "--no-record", "--no-progress"]) == 2
    got = capsys.readouterr()
    assert re.fullmatch(r"qchain run: error: --out \S+: expected room for the outputs, about [0-9.]+ MiB, found "
                        r"0\.0625 MiB free in \S+\n", got.err), got.err
    assert "simulated" not in got.out
    # --no-plots writes nothing there: no check
    assert main(["run", str(short_scene), "--out", str(blocker / "out"), "--no-record", "--no-progress",
                 "--no-plots"]) == 0


def test_recording_paths_a_run_could_not_use_are_refused_before_the_run(short_scene, tmp_path, capsys):
    long = tmp_path / ("x" * 250 + ".mcap")  # 255 bytes: its journal's name would be 263
    cases = [
        (long, "qchain run: error: --mcap file name xxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxxx... is 255 bytes long and its "
               ".journal file beside it needs 8 more: a file name may have at most 255 bytes there"),
        (tmp_path / "bad\udcffname.mcap", f"qchain run: error: --mcap path {tmp_path}/bad\\xffname.mcap is not UTF-8 "
                                          "text; choose a name of UTF-8 characters"),
        (tmp_path / "a\0b.mcap", f"qchain run: error: --mcap path {tmp_path}/a\\0b.mcap contains a NUL character"),
    ]
    for path, line in cases:
        assert main(["run", str(short_scene), "--mcap", str(path), "--no-plots", "--no-progress"]) == 2
        got = capsys.readouterr()
        assert got.err == line + "\n" and "simulated" not in got.out
    assert main(["run", str(short_scene), "--rrd", str(tmp_path / "v\udcff.rrd"), "--no-record", "--no-plots",
                 "--no-progress"]) == 2
    assert "--rrd path" in capsys.readouterr().err
    assert sorted(os.listdir(tmp_path)) == ["short.toml"]  # nothing written


@pytest.mark.slow
@pytest.mark.parametrize("name, stem", [("bad\udcffname.toml", "bad_name"), ("a" * 235 + ".toml", "a" * 100)])
def test_a_scene_file_with_any_name_gives_a_usable_recording(name, stem, tmp_path, monkeypatch, capsys):
    """A file name that is not UTF-8 or is 240 characters long (exit 0 and no usable
    recording before): the default recording is named from a UTF-8 stem of at most 100 bytes."""
    from qchain.logging import read_recording

    monkeypatch.chdir(tmp_path)
    (tmp_path / name).write_text(SHORT)
    assert main(["run", name, "--no-plots", "--no-progress"]) == 0
    got = capsys.readouterr()
    made = sorted((tmp_path / "runs").iterdir())
    assert len(made) == 1 and re.fullmatch(rf"{stem}-\d{{8}}-\d{{6}}\.mcap", made[0].name), made
    assert f"recorded runs/{made[0].name} (11 samples, up to t = 0.1 s)" in got.out
    rec = read_recording(made[0])
    assert len(rec) == 11 and rec.complete and rec.outcome["success"] == "true"
    assert rec.info.name == "short" and rec.info.scene_path == os.fsencode(name).decode("utf-8", "backslashreplace")


def _silent_peer():
    """A loopback server that accepts connections and never answers: (url, close)."""
    import socket
    import threading

    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(16)
    held = []

    def accept():
        while True:
            try:
                held.append(srv.accept()[0])
            except OSError:
                return

    threading.Thread(target=accept, daemon=True).start()

    def close():
        srv.close()
        for c in held:
            c.close()

    return f"rerun+http://127.0.0.1:{srv.getsockname()[1]}/proxy", close


@pytest.mark.slow
def test_a_viewer_that_never_answers_does_not_hold_the_run(short_scene, tmp_path, monkeypatch, capsys):
    """``--connect`` to a port that accepts and never answers: the run goes on without it
    after CONNECT_TIMEOUT, says so in one line and records everything (before, the Rerun
    SDK waited for it without end, and the run never returned)."""
    import qchain.cli.main as cli
    from qchain.logging import read_recording

    monkeypatch.setattr(cli, "CONNECT_TIMEOUT", 0.5)
    url, close = _silent_peer()
    try:
        t0 = time.monotonic()
        assert main(["run", str(short_scene), "--connect", url, "--mcap", str(tmp_path / "r.mcap"), "--no-plots",
                     "--no-progress"]) == 0
        wall = time.monotonic() - t0
    finally:
        close()
    got = capsys.readouterr()
    assert _said(got.err) == f"qchain run: warning: no Rerun viewer answers at {url} (the peer accepted the " \
                             "connection but did not answer within 0.5 s); the run goes on without it\n"
    assert wall < 120
    assert len(read_recording(tmp_path / "r.mcap")) == 11
    # a closed port: the same, said at once (this warning was swallowed before)
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        closed = f"rerun+http://127.0.0.1:{s.getsockname()[1]}/proxy"
    assert main(["run", str(short_scene), "--connect", closed, "--no-record", "--no-plots", "--no-progress"]) == 0
    assert _said(capsys.readouterr().err) == f"qchain run: warning: no Rerun viewer answers at {closed} " \
                                             "(Connection refused); the run goes on without it\n"


def _processes_with(tag: str) -> list[int]:
    """Pids of the live processes whose environment holds ``tag``."""
    found = []
    for pid in os.listdir("/proc"):
        if pid.isdigit():
            try:
                with open(f"/proc/{pid}/environ", "rb") as fh:
                    if tag.encode() in fh.read():
                        found.append(int(pid))
            except OSError:
                pass
    return found


@pytest.mark.slow
def test_a_viewer_that_never_answers_leaves_no_process_behind(short_scene, tmp_path):
    import uuid

    tag = f"QCHAIN_TEST_TAG={uuid.uuid4().hex}"
    env = dict(os.environ, QCHAIN_TEST_TAG=tag.split("=")[1])
    url, close = _silent_peer()
    try:
        r = qchain("run", short_scene, "--connect", url, "--mcap", tmp_path / "r.mcap", "--no-plots", "--no-progress",
                   env=env, timeout=240)
    finally:
        close()
    assert r.returncode == 0, r.stderr
    assert _said(r.stderr) == f"qchain run: warning: no Rerun viewer answers at {url} (the peer accepted the " \
                              "connection but did not answer within 5 s); the run goes on without it\n"
    deadline = time.monotonic() + 30  # the writer's exit is not waited for: give it time
    while _processes_with(tag) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert _processes_with(tag) == []


@pytest.mark.slow
def test_the_viewer_probe_passes_a_rerun_viewer_and_refuses_what_is_not_one():
    import http.server
    import socket
    import threading

    from qchain.cli.main import viewer_silence

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code = ("import sys, rerun as rr; rr.init('probe'); print(rr.serve_grpc(grpc_port=int(sys.argv[1])), flush=True); "
            "sys.stdin.read()")
    viewer = subprocess.Popen([PY, "-c", code, str(port)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        url = viewer.stdout.readline().strip()
        assert url == f"rerun+http://127.0.0.1:{port}/proxy"
        assert viewer_silence(url, timeout=30) is None
    finally:
        viewer.stdin.close()
        viewer.wait(60)
    web = http.server.ThreadingHTTPServer(("127.0.0.1", 0), http.server.SimpleHTTPRequestHandler)
    threading.Thread(target=web.serve_forever, daemon=True).start()
    try:
        why = viewer_silence(f"rerun+http://127.0.0.1:{web.server_address[1]}/proxy", timeout=30)
    finally:
        web.shutdown()
        web.server_close()
    assert why == "the peer answered, but not as an HTTP/2 (gRPC) server: not a Rerun viewer?"
    assert viewer_silence("ftp://127.0.0.1:21/x") == "unsupported URL scheme 'ftp' (use rerun+http://HOST:PORT/proxy)"


def _wait_for(predicate, timeout: float, what: str):
    deadline = time.monotonic() + timeout
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError(f"no {what} within {timeout} s")
        time.sleep(0.005)


def _interrupt_when(proc, predicate, timeout: float, what: str) -> tuple[str, str]:
    """Ctrl-C ``proc`` once ``predicate()`` holds (within ``timeout`` s); its stdout and
    stderr. The process is killed if it is still there when the test leaves."""
    try:
        _wait_for(predicate, timeout, what)
        proc.send_signal(signal.SIGINT)
        return proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def _maps(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/maps") as fh:
            return fh.read()
    except OSError:
        return ""


@pytest.mark.slow
@pytest.mark.parametrize("loading", ["libboost_python", "llvmlite"])
def test_ctrl_c_during_start_up_is_one_line_and_exit_code_1(loading, short_scene, tmp_path):
    """Ctrl-C while the command loads Pinocchio (Boost.Python) or numba (llvmlite, whose
    callbacks drop the KeyboardInterrupt): one line, exit code 1, no traceback, nothing run."""
    proc = subprocess.Popen([PY, "-m", "qchain", "run", str(short_scene), "--duration", "30", "--realtime",
                             "--mcap", str(tmp_path / "r.mcap"), "--no-plots", "--no-progress"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = _interrupt_when(proc, lambda: loading in _maps(proc.pid) or proc.poll() is not None, 120, loading)
    assert proc.returncode == 1, (out, err)
    assert _said(err) == "qchain run: interrupted during start-up (nothing was run)\n"
    assert "simulated" not in out


def _journal_grows(path: Path, seconds: float):
    """A predicate: the file at ``path`` has grown for ``seconds`` of wall time."""
    first = []

    def grown():
        size = path.stat().st_size if path.exists() else 0
        if not first and size > 4096:
            first.append(time.monotonic())
        return bool(first) and time.monotonic() - first[0] >= seconds

    return grown


@pytest.mark.slow
@pytest.mark.parametrize("method", ["RK45", "dopri5"])
def test_ctrl_c_in_a_run_reports_the_time_its_samples_reach(method, tmp_path):
    """Ctrl-C a second into a run paced to the wall clock: the summary, the line on stderr,
    the recording's outcome and its last sample agree on the time reached (it said
    ``t = 0 s`` with the Python engine's methods)."""
    from qchain.logging import read_recording

    scene = tmp_path / "paced.toml"
    scene.write_text(SHORT.replace('method = "rk4"', f'method = "{method}"').replace("dt = 1e-3", ""))
    mcap = tmp_path / "paced.mcap"
    proc = subprocess.Popen([PY, "-m", "qchain", "run", str(scene), "--duration", "60", "--realtime", "--mcap",
                             str(mcap), "--no-plots", "--no-progress"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = _interrupt_when(proc, _journal_grows(Path(str(mcap) + ".journal"), 1.0), 240, "samples recorded")
    assert proc.returncode == 1, (out, err)
    m = re.search(r"run: FAILED: interrupted by the user \(Ctrl-C\) at t = ([0-9.e+-]+) s\n", out)
    assert m, (out, err)
    reached = m[1]
    assert float(reached) > 0.0
    assert _said(err) == f"run: interrupted at t = {reached} s\n"
    assert f"simulated {reached} s in" in out and f"final tip (t = {reached} s, world)" in out
    assert re.search(rf"recorded {re.escape(str(mcap))} \(\d+ samples, up to t = {re.escape(reached)} s\)", out)
    rec = read_recording(mcap)
    assert rec.complete and f"{rec.t[-1]:.6g}" == reached
    assert rec.outcome["message"] == f"interrupted by the user (Ctrl-C) at t = {reached} s"
    assert rec.outcome["success"] == "false"


# --------------------------------------------------------------------------------------
# qchain sweep: the same rules

SWEEP_SCENE = SHORT.replace('name = "short"', 'name = "sweep base"')


@pytest.fixture
def sweep_file(tmp_path):
    (tmp_path / "base.toml").write_text(SWEEP_SCENE)
    p = tmp_path / "study.toml"
    p.write_text('scene = "base.toml"\n[[axes]]\nkey = "segments[0].damping"\nvalues = [0.01, 0.02]\n')
    return p


def test_sweep_errors_are_one_line_with_their_exit_code(sweep_file, tmp_path, monkeypatch, capsys):
    import qchain.cli.sweep as sweeps

    blocker = tmp_path / "blocker"
    blocker.write_text("a file")
    assert sweeps.main([str(sweep_file), "--out", str(blocker / "results"), "--workers", "1", "--no-progress"]) == 2
    got = capsys.readouterr()
    assert got.err == f"qchain sweep: error: the results folder {blocker / 'results'} cannot be made: {blocker} is a " \
                      "file\n"
    assert "computed now" not in got.out
    assert main(["sweep", str(sweep_file), "--workers", "0"]) == 2
    assert capsys.readouterr().err == "qchain sweep: error: --workers must be an integer >= 1 and <= 1024, got 0\n"

    def interrupted(path):
        raise KeyboardInterrupt

    monkeypatch.setattr(sweeps, "load_sweep", interrupted)
    assert main(["sweep", str(sweep_file)]) == 1
    assert capsys.readouterr().err == "qchain sweep: interrupted during start-up (nothing was run)\n"
    monkeypatch.undo()

    def broken(*args, **kwargs):
        raise RuntimeError("the engine broke")

    monkeypatch.setattr(sweeps, "run_sweep", broken)
    out = tmp_path / "results"
    assert main(["sweep", str(sweep_file), "--out", str(out), "--workers", "1", "--no-progress"]) == 1
    assert _said(capsys.readouterr().err) == "qchain sweep: error: RuntimeError: the engine broke (run with --debug " \
                                             "for the traceback)\n"
    assert main(["sweep", str(sweep_file), "--out", str(out), "--workers", "1", "--no-progress", "--debug"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("Traceback") and err.endswith("qchain sweep: error: RuntimeError: the engine broke\n")
    monkeypatch.undo()
    assert main(["sweep", str(sweep_file), "--out", str(out), "--workers", "1", "--no-progress"]) == 0
    assert "2 runs (0 finished before, 2 computed now" in capsys.readouterr().out


@pytest.mark.slow
def test_ctrl_c_in_a_running_sweep_is_said_once(sweep_file, tmp_path):
    """Ctrl-C while ``qchain sweep`` runs: one line saying where the finished runs are, exit
    code 1 (not a second "interrupted" line from the ``qchain`` command around it)."""
    log = tmp_path / "ran.log"
    values = [0.011, 0.012, 0.013, 0.014, 0.015, 0.016, 0.017, 0.018]
    sweep_file.write_text(f'scene = "base.toml"\nmetrics = "batch_probe:damping_logged"\n[set]\n'
                          f'description = "probe {log} 0.3"\n[[axes]]\nkey = "segments[0].damping"\nvalues = {values}\n')
    out = tmp_path / "results"
    env = dict(os.environ, PYTHONPATH=f"{Path(__file__).parent}{os.pathsep}{os.environ.get('PYTHONPATH', '')}")
    proc = subprocess.Popen([PY, "-m", "qchain", "sweep", str(sweep_file), "--out", str(out), "--workers", "1",
                             "--no-progress"], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    journal = out / "runs.jsonl"
    stdout, err = _interrupt_when(
        proc, lambda: (journal.is_file() and journal.read_text().count("\n") >= 2) or proc.poll() is not None, 240,
        "two finished runs")
    assert proc.returncode == 1, (stdout, err)
    assert _said(err) == f"qchain sweep: interrupted; the finished runs are in {out} (run the same command again " \
                         "to continue)\n"
    assert 2 <= journal.read_text().count("\n") < len(values)
