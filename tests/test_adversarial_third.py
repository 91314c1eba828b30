"""Bad input tried a third time (issue 18, "done when"): a fresh set of about 1400 cases
(scene files and the command line, the Python API, recordings and their peers) found the
failures below; each test is one of them, fixed: a chunk a journal could give back lost for
good, a damaged journal deleted by ``recover``, one flipped bit outside the chunks losing a
chunk, a few KiB of compressed JSON growing into gigabytes, views a batch taker could write
the results through, copies of a model that were no longer read-only, and more.

The generators are not part of the suite; these are their representative cases.
"""

from __future__ import annotations

import copy
import io
import math
import os
import pickle
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from helpers import SEGMENTS_TOML
from logging_fixtures import arm_info, arm_records

import qchain
from qchain import Chain, Segment, simulate_batch
from qchain.sim.budget import BudgetError
from qchain.logging import LoggingError, RecordingFormatError, RunLogger, read_recording, recover
from qchain.recording.journal import JournalReader, JournalWriter, journal_path
from qchain.recording.records import Batch
from qchain.recording.scan import scan
from qchain.sim.simulation import simulate

ROOT = Path(__file__).parents[1]
SEG = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5,
           damping=0.01)
N = 300


# --------------------------------------------------------------------------------------
# recordings: a killed run's file and journal


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """A recording of N records in several chunks, its rows and its qchain metadata."""
    path = tmp_path_factory.mktemp("whole") / "run.mcap"
    with RunLogger(arm_info(), path, flush_interval=0.05, quiet=True, worker="thread") as log:
        for r in arm_records(N, dt=1e-3):
            log.log(r)
    rec = read_recording(path)
    assert len(rec) == N and not rec.gaps
    b = rec.batch()
    return path.read_bytes(), b.rows(), Batch.layout.fget(b), rec.metadata


def _journal(path: Path, rows: np.ndarray, layout, metadata: dict, blocks: int = 6) -> None:
    """The journal a run of ``rows`` leaves when it is killed: every row on disk, no end."""
    jw = JournalWriter(journal_path(path), metadata, str(path))
    jw.start(layout)
    for part in np.array_split(rows, blocks):
        jw.append(np.ascontiguousarray(part))
    jw.release(remove=False)


def _killed(data: bytes) -> bytes:
    """The file as a killed run leaves it: cut after its last chunk (no summary, no footer)."""
    return data[: [it.end for it in scan(data) if it.kind == "chunk"][-1]]


def test_recover_fills_a_damaged_chunk_from_the_journal_and_keeps_every_record(whole, tmp_path):
    """The journal held every record of a chunk the file had lost to one flipped bit; only
    records after the file's last were merged, and recover then deleted the journal: those
    of the damaged chunk were gone for good."""
    data, rows, layout, meta = whole
    cut = bytearray(_killed(data))
    chunks = [it for it in scan(bytes(cut)) if it.kind == "chunk"]
    assert len(chunks) >= 4
    cut[chunks[1].offset + 60] ^= 0x10  # inside the second chunk's data
    path = tmp_path / "run.mcap"
    path.write_bytes(bytes(cut))
    _journal(path, rows, layout, meta)
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.step, np.arange(N))
    np.testing.assert_array_equal(rec.t, rows[:, 0])
    assert not rec.gaps and rec.recovered > 0
    assert any("its records read from the run's journal" in d for d in rec.damage), rec.damage
    recover(path)
    again = read_recording(path)
    assert len(again) == N and not again.gaps and not again.truncated
    assert not journal_path(path).exists()


def test_a_damaged_journal_is_read_as_far_as_it_goes_and_never_deleted(whole, tmp_path):
    """Its first chunk (the rows channel's declaration) damaged: its later chunks read by
    the layout sealed outside the chunks; recover refuses and leaves both files as they
    were (the journal once went with the damaged chunk's rows and every later one)."""
    data, rows, layout, meta = whole
    path = tmp_path / "run.mcap"
    path.write_bytes(_killed(data)[: len(data) // 2])
    _journal(path, rows, layout, meta)
    jp = journal_path(path)
    jdata = bytearray(jp.read_bytes())
    first = next(it for it in scan(bytes(jdata)) if it.kind == "chunk")
    jdata[first.offset + 80] ^= 0x10
    jp.write_bytes(bytes(jdata))
    jr = JournalReader(jp)
    blocks = jr.poll(final=True)
    jr.close()
    assert jr.layout is not None and jr.lost and len(blocks) == 5  # all but the damaged first one
    rec = read_recording(path)
    assert rec.step[-1] == N - 1 and rec.journal_unread
    before = (path.read_bytes(), jp.read_bytes())
    with pytest.raises(LoggingError, match=r"cannot be \(wholly\) merged .* nothing was changed"):
        recover(path)
    assert (path.read_bytes(), jp.read_bytes()) == before


def test_a_second_layout_in_a_journal_is_damage_not_a_numpy_error(whole, tmp_path):
    data, rows, layout, meta = whole
    path = tmp_path / "run.mcap"
    path.write_bytes(_killed(data)[: len(data) // 2])
    jp = journal_path(path)
    jw = JournalWriter(jp, meta, str(path))
    jw.start(layout)
    jw.append(np.ascontiguousarray(rows[:10]))
    from qchain.recording.records import RecordLayout

    other = RecordLayout(3, 3, 3, 1, 2)
    cid = jw._w.register_channel("/qchain/rows", "qchain.rows.f64le", 1, {"layout": __import__("json").dumps(
        other.to_json())})
    jw._w.add_message(cid, 1, np.zeros((2, other.row_width)).tobytes(), 1, 1)
    jw._w.flush()
    jw.release(remove=False)
    rec = read_recording(path)  # (numpy's "all the input array dimensions..." before)
    assert any("has the layout" in d for d in rec.damage) and rec.journal_unread


def test_a_journal_that_is_a_loop_of_links_is_said_not_an_oserror(whole, tmp_path):
    data, _, _, _ = whole
    path = tmp_path / "run.mcap"
    path.write_bytes(_killed(data))
    os.symlink(journal_path(path).name, journal_path(path))
    rec = read_recording(path)
    assert len(rec) == N and "symbolic links" in rec.journal_unread


def test_a_bad_journal_row_leaves_the_files_own_records_readable(whole, tmp_path):
    data, rows, layout, meta = whole
    path = tmp_path / "run.mcap"
    path.write_bytes(_killed(data)[: len(data) // 2])
    bad = rows.copy()
    bad[N // 2 + 1, 0] = np.nan  # inside a block (its first and last times are the chunk's)
    _journal(path, bad, layout, meta)
    rec = read_recording(path)
    assert len(rec) > 0 and "has the time nan (expected" in rec.journal_unread, rec.journal_unread
    with pytest.raises(LoggingError):
        recover(path)
    assert journal_path(path).exists()


@pytest.mark.parametrize("cut_into", [9, 100, 1000, 5000])
def test_a_file_cut_inside_its_first_chunk_keeps_its_metadata(whole, tmp_path, cut_into):
    """A record skipped by its length must end where another starts, or fill its own
    fields exactly: a cut chunk after the metadata is the file's end, not damage of the
    metadata (whose loss would refuse the whole file)."""
    data, rows, layout, meta = whole
    first = next(it for it in scan(data) if it.kind == "chunk")
    path = tmp_path / "run.mcap"
    path.write_bytes(data[: first.offset + cut_into])
    _journal(path, rows, layout, meta)
    rec = read_recording(path)
    assert len(rec) == N and not any("metadata" in d for d in rec.damage), rec.damage


def test_parsed_numbers_are_charged_to_the_reading_budget(tmp_path):
    """2 million backbone points of "[0.0,0.0,0.0]" in a 7 KiB zstd file once took 594 MB
    (1.26 GB at 4.4 million): orjson makes 53 bytes of objects a number. Now refused before
    parsing, naming the file and the byte, within the budget of the file's size."""
    import json

    from test_bad_recordings import N_SEG, craft, good_states

    s = good_states(1)[0]
    P = 2_000_000
    text = json.dumps({**s, "backbone": "@"}).encode()
    pts = b"[" + b",".join([b"[0.0,0.0,0.0]"] * P) + b"]"
    blob = text.replace(b'"@"', b"[" + b",".join([pts] * N_SEG) + b"]")
    data = craft([blob], chunks=1)
    assert len(data) < 64 * 1024
    path = tmp_path / "amp.mcap"
    path.write_bytes(data)
    tracemalloc.start()
    try:
        with pytest.raises(RecordingFormatError, match=r"the numbers of its state messages\): reading it would "
                                                       r"process more than"):
            read_recording(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 200 * 2**20, peak


def test_a_killed_writer_with_a_complete_recording_is_a_warning(tmp_path):
    """The writer process killed mid-run: the recording is finished from the journal,
    complete; that was 'error: the recording failed' and exit code 1."""
    import signal

    path = tmp_path / "run.mcap"
    log = RunLogger(arm_info(), path, flush_interval=0.05, quiet=True, worker="process")
    records = arm_records(200, dt=1e-3)
    for r in records[:100]:
        log.log(r)
    log.flush(60.0)
    os.kill(log._proc.pid, signal.SIGKILL)
    log._proc.wait(30)
    for r in records[100:]:
        log.log(r)
    with pytest.warns(Warning, match="the recording was finished from the journal, complete"):
        done = log.close()
    assert done["error"] is None and done["n_records"] == 200
    rec = read_recording(path)
    assert len(rec) == 200 and not rec.truncated and not rec.gaps


# --------------------------------------------------------------------------------------
# the Python API


def arm(n=3, **kw):
    return Chain([Segment(**SEG) for _ in range(n)], **kw)


def test_controller_rate_counts_in_the_run_budget():
    """controller_rate=1e9 built every instant (a 7.45 GiB array) or made 1e8 Python calls."""
    ch = arm()
    q, v, p = ch.neutral(), np.zeros(ch.nv), np.zeros(ch.nu)
    match = r"budget.max_steps: .* \(duration 1 s x controller_rate 1e\+0[89] Hz: a step ends at every controller"
    for rate in (1e8, 1e9):
        with pytest.raises(BudgetError, match=match):
            simulate(ch, q, v, (0, 1), pressure=lambda t, q, v: p, controller_rate=rate)
        with pytest.raises(BudgetError, match=match):
            simulate_batch(ch, q, v, (0, 1), pressure=lambda t, q, v: p, controller_rate=rate, t_eval=[1.0], workers=1)


def test_a_batch_checks_each_rollouts_cost_and_inputs_before_anything_runs():
    ch = arm()
    q, v = ch.neutral(), np.zeros(ch.nv)
    with pytest.raises(BudgetError, match=r"duration 1 s / dt 1e-300 s"):
        simulate_batch(ch, q, v, (0, 1), method="rk4", dt=1e-300, workers=1)
    with pytest.raises(ValueError, match=r"pressure\[1\]\[0\] must be >= -101325 and <= 1e\+09 Pa, got 2e\+09 Pa"):
        simulate_batch(ch, q, v, (0, 0.1), pressure=np.array([np.zeros(9), np.full(9, 2e9)]), t_eval=[0.1],
                       workers=1)
    with pytest.raises(ValueError, match=r"client must be a scheduler address 'tcp://HOST:PORT', got 'not a url'"):
        simulate_batch(ch, q, v, (0, 0.1), t_eval=[0.1], client="not a url")


def test_a_batch_taker_gets_read_only_views_and_t_eval_stays_the_callers():
    class Taker:
        max_sim = 0.05

        def __call__(self, t, q, v, p):
            pass

        def record_batch(self, t, q, v, p, ke, pe):
            for a in (t, q, v, p):
                with pytest.raises(ValueError, match="read-only"):
                    a[...] = -1.0
            self.n = getattr(self, "n", 0) + len(t)

    ch = arm()
    te = np.linspace(0, 0.2, 11)
    keep = te.copy()
    taker = Taker()
    tr = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.2), t_eval=te, on_sample=taker)
    np.testing.assert_array_equal(te, keep)
    np.testing.assert_array_equal(tr.t, keep)
    assert taker.n == 11 and tr.t.base is not te
    taker.max_sim = "soon"
    with pytest.raises(TypeError, match=r"on_sample.max_sim must be a real number"):
        simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.2), t_eval=te, on_sample=taker)


@pytest.mark.parametrize("how", ["deepcopy", "pickle"])
def test_copies_of_a_model_keep_its_arrays_read_only(how):
    """numpy unpickles every array writeable: a copy's gravity could be set outside its bound."""
    from qchain.sim.inputs import Sine

    dup = copy.deepcopy if how == "deepcopy" else (lambda x: pickle.loads(pickle.dumps(x)))
    ch = dup(arm(floating=True) if "floating" in Chain.__init__.__code__.co_varnames else arm())
    for a in (ch.gravity, ch.active, ch.segments[0].alpha_weights, ch.segments[0].disk_inertia):
        assert not a.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            a[...] = 0.0
    s = dup(Sine([1.0] * 9, 2.0))
    assert not s.amplitude.flags.writeable
    q, v, p = ch.neutral(), np.zeros(ch.nv), np.zeros(ch.nu)
    np.testing.assert_array_equal(ch.forward_dynamics(q, v, p), arm().forward_dynamics(q, v, p))


def test_a_first_step_below_the_span_resolution_is_refused_and_late_spans_say_why():
    ch = arm()
    q, v = ch.neutral(), np.zeros(ch.nv)
    with pytest.raises(ValueError, match=r"first_step must be >= 4.44e-15 s \(20 float64 spacings of max\(1 s, "
                                         r"\|t0\|, \|t1\|\)\), got 1e-300 s"):
        simulate(ch, q, v, (0, 1), first_step=1e-300)
    for method in ("radau5", "dopri5"):  # once: "the step size fell below its floor" at once
        r = simulate(ch, q, v, (1e11, 1e11 + 0.05), method=method, t_eval=[1e11 + 0.05])
        assert r.success, (method, r.message)
    # at 1e12 s float64 times are 1.2e-4 s apart: step times rounded by 1 % of a step spoil an
    # error estimate of 1e-8; the run stops at its start saying so (not "singular" alone)
    for span in ((1e12 - 0.05, 1e12), (-1e12, -1e12 + 0.05)):
        r = simulate(ch, q, v, span, method="radau5", t_eval=[span[1]])
        assert r.success or ("10 float64 spacings of t (0.00122 s)" in r.message
                             and "shift t_span toward 0" in r.message), r.message


def test_nodes_for_tolerance_takes_a_paper_coordinate_segment():
    from qchain.model.segment import nodes_for_tolerance

    s = Segment(**SEG, coords="paper", stiffness_matrix=np.eye(3), rest_q_e=[0.1, 500.0, 1.0])
    assert nodes_for_tolerance(s, 1.0, 1e-3) == nodes_for_tolerance(Segment(**SEG), 1.0, 1e-3)


def test_kinematics_arguments_are_checked_where_they_enter():
    ch = arm()
    q = ch.neutral()
    Q = np.stack([q, q])
    ch.backbone(q, 20)
    for bad in ([20], np.array(20.0), 20.0, True):
        with pytest.raises(ValueError, match=r"points_per_segment must be an int >= 2 and <= 10000"):
            ch.backbone(q, bad)
    for t in (float("nan"), "soon"):
        with pytest.raises((TypeError, ValueError), match=r"\bt\b"):
            ch.frames_batch(Q, t=t)
    for flag in (np.array([True, False]), "no"):
        with pytest.raises(TypeError, match=r"skip_checks must be True or False"):
            ch.forward_dynamics(q, np.zeros(ch.nv), np.zeros(ch.nu), skip_checks=flag)
    for segs in ({Segment(**SEG)}, {0: Segment(**SEG)}):
        with pytest.raises(TypeError, match=r"segments must be a sequence"):
            Chain(segs)
    assert not hasattr(qchain, "no_such.sub") and not hasattr(qchain, "..x") and hasattr(qchain, "cli")


def test_read_only_and_strided_arrays_do_not_compile_the_passes_again():
    ch = arm()
    q, v, p, tau = ch.neutral(), np.zeros(ch.nv), np.zeros(ch.nu), np.zeros(ch.nv)
    ch.forward_dynamics_derivatives(q, v, p, tau)
    q2 = np.zeros(2 * ch.nq)
    q2[::2] = q
    for a in (q, v, p, tau):
        a.flags.writeable = False
    t0 = time.perf_counter()
    ch.forward_dynamics_derivatives(q2[::2], v, p, tau)
    ch.forward_dynamics(q, v, p)
    assert time.perf_counter() - t0 < 2.0  # a compile of the passes takes 8-20 s


def test_a_sweep_seed_and_an_integer_axis_are_checked():
    from qchain.batch.sweep_spec import Axis

    with pytest.raises(ValueError, match=r"axis segments\[0\].count: an integer range needs a whole number in it, "
                                         r"got \[1.2, 1.8\]"):
        Axis("segments[0].count", range=(1.2, 1.8), num=3, integer=True)
    ax = Axis("segments[0].count", range=(1.2, 3.8), num=4, integer=True)
    assert ax.grid() == [2, 3] and all(1.2 <= x <= 3.8 for x in ax.grid())
    from qchain.batch.sweeps import sweep

    with pytest.raises(ValueError, match=r"seed must be an int >= 0 and < 2\*\*128"):
        sweep(ROOT / "examples" / "scenes" / "step_response.toml", [Axis("segments[0].count", values=(1, 2))],
              sampling="random", n=2, seed=-1)


# --------------------------------------------------------------------------------------
# scene files and the command line


SCENE = """
name = "NAME"
""" + SEGMENTS_TOML.replace("count = 2", "count = 1") + """[pressure]
type = "constant"
value = [2e4, 0.0, 0.0]
[simulation]
duration = 0.05
method = "radau5"
[output]
sample_rate = 200.0
plots = ["tip"]
"""


def qchain_run(args, cwd, env=None, seconds=120):
    return subprocess.run([sys.executable, "-m", "qchain", *map(str, args)], cwd=cwd, capture_output=True, text=True,
                          timeout=seconds, env={**os.environ, **(env or {})})


def test_a_scene_name_with_dollars_is_plain_text_and_the_data_come_first(tmp_path, monkeypatch, capsys):
    """'$...$' in the name was matplotlib's mathtext: the plots failed after the run and
    trajectory.npz, written after them, was lost."""
    from qchain.cli.main import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(SCENE.replace("NAME", r"cost $\\undefinedmacro{x}$ at $x^$"))
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


def test_run_flags_the_header_and_the_recording_agree(tmp_path, monkeypatch, capsys):
    from qchain.cli.main import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(SCENE.replace("NAME", "flags"))
    assert main(["run", "s.toml", "--no-record", "--mcap", "m.mcap", "--duration", "0.01", "--out", "else"]) == 0
    out = capsys.readouterr().out
    assert "simulation: 0.01 s, radau5" in out and "output: 200 Hz to else, plots: tip" in out, out
    assert len(read_recording(tmp_path / "m.mcap")) == 3  # --no-record, but --mcap asks for one
    code = main(["run", "s.toml", "--mcap", "newdir/", "--no-plots"])
    assert code == 2 and "argument --mcap: expected a file's path, found 'newdir/'" in capsys.readouterr().err
    assert not (tmp_path / "newdir").exists()


def test_the_environment_a_run_cannot_work_in_is_refused(tmp_path):
    (tmp_path / "s.toml").write_text(SCENE.replace("NAME", "env"))
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


@given(duration=st.floats(1e-3, 50.0), rate=st.floats(0.5, 2000.0))
@settings(max_examples=200, deadline=None, derandomize=True, database=None)
def test_the_sample_budget_counts_what_sample_times_makes(duration, rate):
    """The budget counted one sample more than the run makes (a 'max_samples = 2' refused
    a run of two)."""
    from qchain.scene import parse_scene

    sc = parse_scene(SCENE.replace("NAME", "n").replace("duration = 0.05", f"duration = {duration!r}")
                     .replace("sample_rate = 200.0", f"sample_rate = {rate!r}"))
    assert sc.cost().samples == len(sc.sample_times())


def test_values_next_to_a_bound_are_shown_with_all_their_digits():
    from qchain.scene import SceneError, parse_scene

    text = SCENE.replace("NAME", "b").replace("value = [2e4, 0.0, 0.0]", "value = [-101325.0001, 0, 0]")
    text += "[initial]\nq_e = [1.0000001, 0, 0]\n"
    with pytest.raises(SceneError) as err:
        parse_scene(text)
    msg = str(err.value)
    assert "found -101325.0001 Pa at index 0" in msg and "found 1.0000001" in msg, msg
    moving = SCENE.replace("NAME", "m") + ('[base]\ntype = "prescribed"\n[base.motion]\ntype = "translation"\n'
                                           'axis = [1e-200, 0, 0]\namplitude = 0.01\nfrequency = 1.0\n')
    sc = parse_scene(moving)
    assert np.allclose(sc.base.motion.axis, [1.0, 0.0, 0.0])


def test_two_sweeps_on_one_folder_and_a_restart_that_keeps_what_is_not_its_own(tmp_path):
    """Two sweeps on one folder both computed every run; --restart removed a qchain run's
    runs/run-<time>.mcap from a sweep folder '.'."""
    from qchain.batch.sweep_spec import SweepError
    from qchain.batch.sweeps import _Folder

    a = _Folder(tmp_path)
    a.lock()
    with pytest.raises(SweepError, match=rf"another sweep \(pid {os.getpid()}\) is writing it"):
        _Folder(tmp_path).lock()
    a.close()
    b = _Folder(tmp_path)
    b.lock()  # free again
    runs = tmp_path / "runs"
    runs.mkdir()
    for name in ("run-00003.npz", ".run-00003.npz.tmp", "run-20261202-134758.mcap", "notes.txt"):
        (runs / name).write_text("x")
    b.clear()
    b.close()
    assert sorted(p.name for p in runs.iterdir()) == ["notes.txt", "run-20261202-134758.mcap"]


def test_recover_through_a_link_replaces_the_file_it_names(whole, tmp_path):
    """The link was replaced by a regular file, the file it named left truncated."""
    data, rows, layout, meta = whole
    real = tmp_path / "real"
    real.mkdir()
    target = real / "run.mcap"
    target.write_bytes(_killed(data)[: len(data) // 2])
    link = tmp_path / "run.mcap"
    link.symlink_to(target)
    _journal(link, rows, layout, meta)
    recover(link)
    assert link.is_symlink() and os.readlink(link) == str(target)
    rec = read_recording(target)
    assert len(rec) == N and not rec.truncated


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


# --------------------------------------------------------------------------------------
# a fourth pass's cases


def test_recover_refuses_a_link_to_its_own_journal_or_to_a_file_with_a_journal(whole, tmp_path):
    """A link to its own journal: recover wrote the journal over itself, then deleted it (every
    record lost). A link to a killed run's file: the journal beside that file was ignored."""
    data, rows, layout, meta = whole
    a = tmp_path / "a"
    a.mkdir()
    path = a / "r.mcap"
    _journal(path, rows, layout, meta)
    path.symlink_to(journal_path(path).name)
    before = journal_path(path).read_bytes()
    with pytest.raises(LoggingError, match="is a link to its own journal"):
        recover(path)
    assert journal_path(path).read_bytes() == before
    b = tmp_path / "b"
    b.mkdir()
    target = b / "s.mcap"
    target.write_bytes(_killed(data)[: len(data) // 2])
    _journal(target, rows, layout, meta)
    link = b / "r.mcap"
    link.symlink_to(target.name)
    with pytest.raises(LoggingError, match=r"has a journal of its own .* recover .*s\.mcap"):
        recover(link)
    from qchain.logging import check_outputs

    with pytest.raises(LoggingError, match=r"s\.mcap\.journal holds the records of a run that was killed"):
        check_outputs(link)  # a run through the link would write over that file
    recover(target)
    assert len(read_recording(target)) == N


def test_journal_rows_with_no_place_keep_the_journal(whole, tmp_path):
    """Rows after the file's last step but before its last time were dropped without a word,
    and recover then deleted the journal that held them."""
    data, rows, layout, meta = whole
    path = tmp_path / "run.mcap"
    path.write_bytes(_killed(data)[: len(data) // 2])
    k = len(read_recording(path, journal=False))
    odd = rows.copy()
    odd[k:, 0] -= 0.05
    _journal(path, odd, layout, meta)
    rec = read_recording(path)
    assert "have steps after the file's last" in rec.journal_unread
    with pytest.raises(LoggingError):
        recover(path)
    assert journal_path(path).exists()


def test_recover_keeps_the_files_mode(whole, tmp_path):
    data, rows, layout, meta = whole
    path = tmp_path / "run.mcap"
    path.write_bytes(_killed(data))
    path.chmod(0o644)
    _journal(path, rows, layout, meta)
    recover(path)
    assert (path.stat().st_mode & 0o777) == 0o644


def test_a_recorded_run_past_two_to_the_32_seconds_is_refused_before_the_build(tmp_path, monkeypatch, capsys):
    """Foxglove timestamps count seconds in 32 bits: a run of 7.5e9 s failed after the build
    (the writer's OverflowError), and recover then failed too; a sweep reported success
    with 5 of its 11 samples recorded."""
    from qchain.cli.main import main
    from qchain.recording.records import T_MAX

    assert T_MAX == 2**32 - 1
    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(SCENE.replace("NAME", "long").replace("duration = 0.05", "duration = 7.5e9")
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


def test_no_more_workers_start_than_there_are_tasks():
    from qchain.batch.workers import engine_for

    assert engine_for(1024, tasks=1) is None  # one run: in this process
    pool = engine_for(1024, tasks=2)
    try:
        assert pool.workers == 2
    finally:
        pool.close()


def test_a_noisy_controller_without_a_rate_stalls_and_says_so():
    """It once took 30 s for 6.5e-7 s of 0.01 s (hours to the step budget); now the run
    stops after 1000 steps shorter than 1e-9 s, naming controller_rate."""
    ch = arm(1)
    rng = np.random.default_rng(0)
    t0 = time.perf_counter()
    r = simulate(ch, ch.neutral(), np.zeros(3), (0, 0.01), pressure=lambda t, q, v: 1e4 + rng.normal(0, 10, 3),
                 t_eval=[0, 0.005, 0.01])
    assert time.perf_counter() - t0 < 60
    assert not r.success and "stalled" in r.message and "controller_rate" in r.message, r.message
    held = simulate(ch, ch.neutral(), np.zeros(3), (0, 0.01), pressure=lambda t, q, v: 1e4 + rng.normal(0, 10, 3),
                    t_eval=[0, 0.005, 0.01], controller_rate=1000.0)
    assert held.success


@pytest.mark.parametrize("method", ["rk4", "midpoint"])
def test_a_terminal_event_at_a_step_end_is_one_sample(method):
    from qchain.sim.simulation import Event

    ch = arm(1)
    for root in (0.05, 0.02):
        r = simulate(ch, ch.neutral(), np.zeros(3), (0, 0.05), method=method, dt=0.01,
                     events=[Event(lambda t, q, v, root=root: t - root, terminal=True)])
        np.testing.assert_allclose(r.t, np.arange(0, root + 1e-9, 0.01))


def test_the_step_budget_hint_fits_the_method():
    from qchain.sim.budget import Budget

    ch = arm(1)
    r = simulate(ch, ch.neutral(), np.zeros(3), (0, 1), pressure=lambda t, q, v: np.full(3, 1e4 * math.sin(t)),
                 controller_rate=100.0, budget=Budget(max_steps=100))
    assert not r.success and "budget.max_steps = 100" in r.message
    assert "use method='radau5'" not in r.message and "rejected steps count" in r.message, r.message


def test_a_recorder_checks_each_sample_where_it_enters(tmp_path):
    """A negative time or a NaN q was taken, then refused at the flush, taking the good
    samples buffered with it; times going back were recorded silently."""
    from qchain.recording.recorder import ChainRecorder

    ch = arm(1)
    q, v, p = ch.neutral(), np.zeros(3), np.zeros(3)
    path = tmp_path / "r.mcap"
    with RunLogger(arm_info(1), path, quiet=True, worker="thread") as log, ChainRecorder(log, ch) as rec:
        rec(0.0, q, v, p)
        rec(0.001, q, v, p)
        for t, qq, energies, match in ((-1.0, q, None, "t must be a time >= 0"),
                                       (0.0005, q, None, "t must not go back"),
                                       (0.002, np.full(3, np.nan), None, r"q has non-finite entries"),
                                       (0.002, np.full(3, np.nan), (0.0, 0.0), r"q\[0\] must be finite"),
                                       (0.002, q, 5.0, r"energies must be \(kinetic, potential\)"),
                                       (0.002, q, (1, 2, 3), r"energies must be \(kinetic, potential\)")):
            with pytest.raises(ValueError, match=match):
                rec(t, qq, v, p, energies=energies)
        with pytest.raises(ValueError, match=r"t must not go back: t\[1\]"):
            rec.record_batch(np.array([0.3, 0.1]), np.stack([q, q]), np.zeros((2, 3)), np.zeros((2, 3)),
                             np.zeros(2), np.zeros(2))
    assert len(read_recording(path)) == 2  # the good samples kept


def test_schedules_check_their_time_and_phase_and_show_the_digits_near_a_bound():
    from qchain.sim.inputs import Sine, Step, Table

    with pytest.raises(ValueError, match=r"phase\[0\] must be >= -1000 and <= 1000 rad, got 1e\+300 rad"):
        Sine([1.0] * 3, 1.0, phase=1e300)
    for u in (Sine([1.0] * 3, 1.0), Table([0.0, 1.0], [[0.0] * 3, [1.0] * 3]), Step(0.5, [0.0] * 3, [1.0] * 3)):
        for t in (float("nan"), float("inf")):
            with pytest.raises(ValueError, match="t must be finite"):
                u(t)
    ch = arm(1)
    with pytest.raises(ValueError, match=r"reaches 1000000001.0 Pa"):
        simulate(ch, ch.neutral(), np.zeros(3), (0, 0.1), pressure=Sine([1.0] * 3, 1.0, offset=[1e9] * 3))


def test_a_batch_index_is_no_boolean_and_a_logger_stream_must_seek():
    ch = arm(1)
    b = simulate_batch(ch, ch.neutral(), np.zeros(3), (0, 0.01), t_eval=[0.01], workers=1,
                       pressure=np.zeros((2, 3)))
    with pytest.raises(IndexError, match="rollout index must be an int"):
        b[True]

    class NoSeek(io.RawIOBase):
        def writable(self):
            return True

        def write(self, data):
            return len(data)

    with pytest.raises(ValueError, match="a binary stream that can seek"):
        RunLogger(arm_info(), NoSeek(), quiet=True)


# --------------------------------------------------------------------------------------
# a fifth pass's cases


def test_a_workspace_cannot_be_relabelled_and_gravity_cannot_be_reassigned():
    """d.n, d.nv = 8, 24 made a 2-segment workspace pass for 8 segments: a wrong answer, then
    a segmentation fault; Chain.gravity = ... was taken by some passes and not others."""
    ch = arm(2)
    d = ch.create_data()
    ch.mass_matrix(ch.neutral(), data=d)
    for name, value in (("n", 8), ("nv", 24), ("M", np.zeros((1, 1)))):
        with pytest.raises(AttributeError, match=rf"Data.{name} cannot be set"):
            setattr(d, name, value)
    with pytest.raises(AttributeError, match="Chain.gravity is read-only"):
        ch.gravity = np.zeros(3)
    import itertools

    with pytest.raises(ValueError, match=r"segments must hold at most 1e\+06 Segments"):
        Chain(itertools.repeat(Segment(**SEG)))


def test_runs_that_once_failed_inside_scipy_or_numba_say_why_or_run():
    import warnings

    paper = Chain([Segment(**SEG, coords="paper")])
    from qchain.errors import SingularConfigurationError

    with pytest.raises(SingularConfigurationError, match="paper's \\(l, psi, kappa\\) coordinates are singular"):
        simulate(paper, paper.neutral(), np.zeros(3), (0, 0.005))
    ch = arm(2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numba's experimental-feature warning at every call stopped every run
        for method in ("radau5", "dopri5", "rk4"):
            assert simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.005), method=method, dt=1e-3).success
    with np.errstate(all="raise"):  # scipy's own nextafter(0, inf) underflowed
        assert simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 0.005), method="RK45").success


def test_a_batch_is_checked_as_a_whole_against_the_memory_budget():
    ch = arm(2)
    with pytest.raises(BudgetError, match=r"budget.max_memory: .* \(1000000 rollouts x"):
        simulate_batch(ch, np.broadcast_to(ch.neutral(), (10**6, ch.nq)), np.zeros(ch.nv), (0, 1),
                       t_eval=np.linspace(0, 1, 1001), workers=1)


def test_sweep_keys_metrics_and_huge_grids(tmp_path):
    from qchain.batch.sweep_spec import Axis, SweepSpec, runs_problem
    from qchain.scene import parse_scene

    sc = parse_scene(SCENE.replace("NAME", "sw"))
    with pytest.raises(ValueError, match=r"address the same value, on two axes"):
        SweepSpec(scene=sc, axes=[Axis("segments[0].youngs_modulus", values=(1e5,)),
                                  Axis("segments[*].youngs_modulus", values=(1e9,))])
    axes = [Axis(f"segments[{i}].damping", range=(0.0, 0.1), num=10**8) for i in range(40)]
    key, expected, found = runs_problem("grid", None, axes, 1000)
    assert key == "axes" and "more than 1e300" in found
    from qchain.batch.sweeps import run_sweep

    spec = SweepSpec(scene=sc, axes=[Axis("segments[0].damping", values=(0.01, 0.02))],
                     metrics=lambda scene, model, traj: {"segments[0].damping": -1.0}, folder=tmp_path / "m")
    res = run_sweep(spec, workers=1)
    table = res.table.to_pydict()
    assert table["segments[0].damping"] == [0.01, 0.02] and not any(table["success"])
    assert all("are the sweep's axis keys" in m for m in table["message"])


def test_outputs_a_run_could_not_write_are_refused_before_it_starts(tmp_path, monkeypatch, capsys):
    from qchain.cli.main import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "s.toml").write_text(SCENE.replace("NAME", "outs"))
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


# --------------------------------------------------------------------------------------
# a sixth pass's cases


def test_a_recorder_used_for_two_runs_refuses_the_second_instead_of_splicing(tmp_path):
    """record_batch took a second run's samples before the first's last time as a batch
    handed over again, and dropped them: the recording spliced the two runs."""
    from qchain.recording.recorder import ChainRecorder

    ch = arm(2)
    q0, v0 = ch.neutral(), np.zeros(ch.nv)
    with RunLogger(arm_info(2), tmp_path / "r.mcap", quiet=True, worker="thread") as log, \
            ChainRecorder(log, ch) as rec:
        simulate(ch, q0, v0, (0, 0.1), on_sample=rec, t_eval=np.linspace(0, 0.1, 11))
        with pytest.raises(ValueError, match=r"t must not go back: a batch from t = 0.0 s .* \(one recorder a run\)"):
            simulate(ch, q0, v0, (0, 0.2), on_sample=rec, t_eval=np.linspace(0, 0.2, 21))
    np.testing.assert_allclose(read_recording(tmp_path / "r.mcap").t, np.linspace(0, 0.1, 11))


def test_rrd_and_layout_outputs_never_replace_a_file_of_another_kind(whole, tmp_path, capsys):
    from qchain.cli.recording import layout_main, replay_main

    data, _, _, _ = whole
    rec = tmp_path / "run.mcap"
    rec.write_bytes(data)
    other = tmp_path / "other.mcap"
    other.write_bytes(data)
    notes = tmp_path / "notes.txt"
    notes.write_text("mine")
    for target in (notes, other):
        assert replay_main([str(rec), "--rrd", str(target)]) == 2
        assert "is not a Rerun .rrd file; refusing to overwrite it" in capsys.readouterr().err
        assert layout_main([str(rec), "-o", str(target)]) == 2
        assert "is not a layout (JSON); refusing to overwrite it" in capsys.readouterr().err
    assert notes.read_text() == "mine" and other.read_bytes() == data
    assert replay_main([str(rec), "--rrd", str(tmp_path / "x.rrd")]) == 0
    assert replay_main([str(rec), "--rrd", str(tmp_path / "x.rrd")]) == 0  # an earlier .rrd is replaced
    assert layout_main([str(rec), "-o", str(tmp_path / "l.json")]) == 0
    assert layout_main([str(rec), "-o", str(tmp_path / "l.json")]) == 0


def test_the_sweep_api_checks_that_axis_values_are_a_list():
    from qchain.batch.sweeps import sweep

    scene = ROOT / "examples" / "scenes" / "step_response.toml"
    for bad in (0.1, None, "xy"):
        with pytest.raises(TypeError, match=r"axes\['segments\[0\].length'\] must be a list of values"):
            sweep(scene, {"segments[0].length": bad}, workers=1)


def test_recover_leaves_a_complete_recording_as_it_is(whole, tmp_path, capsys):
    from qchain.cli.recording import recover_main

    data, _, _, _ = whole
    path = tmp_path / "run.mcap"
    path.write_bytes(data)
    assert recover_main([str(path)]) == 0
    assert "nothing to recover" in capsys.readouterr().out and path.read_bytes() == data
