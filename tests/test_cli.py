"""The ``qchain`` command: info, run (summary, outputs, recording, progress), exit codes."""

import os
import re
import time
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from qchain.cli import main
from qchain.scene import load_scene

EXAMPLES = Path(__file__).parents[1] / "examples" / "scenes"

SHORT = """
name = "short"
gravity = [0.0, 0.0, -9.81]
[model]
node_tolerance = 1e-8
[[segments]]
count = 2
length = 0.1
radius = 0.015
mass = 0.05
chamber_area = 4.5e-5
chamber_radius = 0.0085
youngs_modulus = 1e5
damping = 0.02
[pressure]
type = "ramp"
t0 = 0.0
t1 = 0.05
end = [3e4, 0.0, 0.0,  0.0, 2e4, 0.0]
[simulation]
duration = 0.1
method = "rk4"
dt = 1e-3
[output]
sample_rate = 100.0
plots = ["tip", "arm", "energy", "pressure"]
"""


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


def test_run_prints_the_summary_and_writes_the_outputs(short_scene, tmp_path, capsys):
    out_dir = tmp_path / "results"
    code = main(["run", str(short_scene), "--out", str(out_dir), "--no-record", "--no-progress"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "run: success: The end of the time span was reached." in out
    m = re.search(r"simulated 0\.1 s in ([0-9.e+-]+) s wall time: ([0-9.e+-]+) x real time; nfev = (\d+), 11 samples, "
                  r"method rk4", out)
    assert m, out
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
    import qchain.simulate as sim

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


def test_the_module_runs_as_a_command(tmp_path):
    r = subprocess.run([sys.executable, "-m", "qchain.cli", "info", str(EXAMPLES / "step_response.toml")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "nodes: 4 per segment from node_tolerance = 1e-08" in r.stdout
    r = subprocess.run([sys.executable, "-m", "qchain.cli", "info", str(tmp_path / "none.toml")], capture_output=True,
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
    assert main(["recover", str(path)]) == 0  # a whole recording stays whole
    assert "recovered" in capsys.readouterr().out
    assert main(["recover", str(tmp_path / "none.mcap")]) == 2
