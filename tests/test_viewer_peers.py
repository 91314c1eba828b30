"""Rerun viewers at ``--connect`` that never answer, or answer and then stall (issue 18): the
run ends in bounded time with one warning, its recording complete, and no process of it
left behind. Output paths the system or the recording cannot take are refused before
anything is made.

The peers are loopback servers: one accepts and never says a word; one answers the HTTP/2
connection (its SETTINGS frame, what the probe asks for) and then reads nothing, so the
Rerun SDK's gRPC client waits for it without end (its flush, its disconnect, its exit).
A real Rerun gRPC server (``rr.serve_grpc`` in a process of its own) is the positive case.
"""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from helpers import SHORT_SCENE, Peer, children, closed_port_url, deadline, descendants, session_members
from logging_fixtures import arm_info, arm_records
from qchain.cli.recording import replay_main
from qchain.logging import LoggingError, LoggingWarning, RunLogger, check_outputs, journal_path, read_recording
from qchain.recording import replay, rerun_sink
from qchain.recording.writer import TEARDOWN_LIMIT, RemoteViewer
from support import craft, good_states, write

ROOT = Path(__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent
PY = sys.executable
SCENE = SHORT_SCENE
#: s a test waits for the processes of a run to be gone after it ended (the writer's leave
#: of Rerun is bounded by TEARDOWN_LIMIT; the rest is a loaded machine's slack).
GONE_WITHIN = TEARDOWN_LIMIT + 25.0


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------


@pytest.fixture
def silent_peer():
    p = Peer(answer=False)
    yield p
    p.close()


@pytest.fixture
def stalling_peer():
    p = Peer(answer=True)
    yield p
    p.close()


def wait_gone(probe, within: float = GONE_WITHIN) -> set[int]:
    """What ``probe()`` still returns after waiting up to ``within`` s for it to be empty."""
    deadline = time.monotonic() + within
    left = probe()
    while left and time.monotonic() < deadline:
        time.sleep(0.2)
        left = probe()
    return left


def ours(caught) -> list[str]:
    return [str(w.message) for w in caught if issubclass(w.category, LoggingWarning)]


def log_run(path, records, **kw):
    """Log ``records`` through a RunLogger (process writer); (summary, warnings, s taken by
    close(), s in all)."""
    t0 = time.monotonic()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log = RunLogger(arm_info(), path, quiet=True, **kw)
        for r in records:
            log.log(r)
        t1 = time.monotonic()
        summary = log.close()
        t2 = time.monotonic()
    return summary, ours(caught), t2 - t1, t2 - t0


def assert_complete(path, n):
    rec = read_recording(path)
    assert len(rec) == n and rec.complete and not rec.recovered and not rec.truncated
    assert not Path(f"{path}.journal").exists()
    return rec


def qchain_cli(*args, cwd, timeout=240.0):
    """``python -m qchain ARGS`` in a session of its own: (returncode, stdout, stderr, s,
    session id). On a timeout its whole session is killed and the test fails."""
    env = {k: v for k, v in os.environ.items() if k != "RUST_LOG"}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    t0 = time.monotonic()
    proc = subprocess.Popen([PY, "-m", "qchain", *map(str, args)], cwd=cwd, env=env, stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        _kill_session(proc.pid)
        proc.communicate()
        raise AssertionError(f"qchain {' '.join(map(str, args))} did not end within {timeout} s") from None
    return proc.returncode, out, err, time.monotonic() - t0, proc.pid


def _kill_session(sid: int) -> None:
    for p in session_members(sid):
        try:
            os.kill(p, signal.SIGKILL)
        except OSError:
            pass


@pytest.fixture
def scene(tmp_path):
    p = tmp_path / "short.toml"
    p.write_text(SCENE)
    return p


@pytest.fixture
def rerun_server():
    """A real Rerun gRPC server (``rr.serve_grpc``) in a process of its own: its URL."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code = ("import sys, rerun as rr; rr.init('qchain-test-viewer'); "
            "print(rr.serve_grpc(grpc_port=int(sys.argv[1])), flush=True); sys.stdin.read()")
    server = subprocess.Popen([PY, "-c", code, str(port)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                              env=rerun_sink.quiet_env())
    try:
        url = server.stdout.readline().strip()
        assert url == f"rerun+http://127.0.0.1:{port}/proxy", url
        yield url, server.pid
    finally:
        server.stdin.close()
        try:
            server.wait(60)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()


# --------------------------------------------------------------------------------------
# the probe: one function, HTTP/2
# --------------------------------------------------------------------------------------


def test_one_probe_asks_for_the_viewers_http2_answer(silent_peer, stalling_peer):
    """``replay`` and the writer use the same probe; a TCP connection alone no longer passes
    (the writer's check was a plain connect: a peer that never answers passed it)."""
    assert replay.probe_viewer is rerun_sink.probe_viewer
    assert not hasattr(rerun_sink, "probe_url")
    t0 = time.monotonic()
    assert rerun_sink.probe_viewer(silent_peer.url, timeout=0.5) == \
        "the peer accepted the connection but did not answer within 0.5 s"
    assert time.monotonic() - t0 < 10
    assert rerun_sink.probe_viewer(stalling_peer.url, timeout=5) is None  # it answers: the stall comes later
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        closed = f"rerun+http://127.0.0.1:{s.getsockname()[1]}/proxy"
    assert rerun_sink.probe_viewer(closed, timeout=5) == "Connection refused"
    assert rerun_sink.probe_viewer("ftp://127.0.0.1:21/x") == \
        "unsupported URL scheme 'ftp' (use rerun+http://HOST:PORT/proxy)"


# --------------------------------------------------------------------------------------
# the Python API
# --------------------------------------------------------------------------------------


@pytest.mark.slow
def test_api_a_peer_that_never_answers(tmp_path, silent_peer):
    """Refused by the probe within viewer_timeout: one warning, the recording complete, no
    process left (before, a plain TCP check let it through and the writer hung in Rerun's
    disconnect forever)."""
    before = descendants()
    path = tmp_path / "run.mcap"
    summary, said, t_close, t_all = log_run(path, arm_records(200), connect=silent_peer.url, viewer_timeout=1.0)
    assert said == [f"qchain.logging: no Rerun viewer can be reached at {silent_peer.url} (the peer accepted the "
                    "connection but did not answer within 1 s); the run goes on without it and the MCAP log is still "
                    "written"]
    assert summary["n_records"] == 200 and summary["error"] is None
    assert t_close < 30 and t_all < 90
    assert_complete(path, 200)
    assert wait_gone(lambda: descendants() - before) == set()


@pytest.mark.slow
def test_api_a_peer_that_stalls_after_the_handshake(tmp_path, stalling_peer):
    """The probe passes, the Rerun SDK then waits for the peer: the writer says "finished"
    first, gives the viewer viewer_timeout s, warns once and ends within its teardown
    limit (before: close() waited for the writer's flush, and the writer for the peer
    without end, outliving the run)."""
    before = descendants()
    path = tmp_path / "run.mcap"
    summary, said, t_close, _ = log_run(path, arm_records(300), connect=stalling_peer.url, viewer_timeout=2.0)
    assert len(said) == 1 and "\n" not in said[0], said
    assert said[0].startswith(f"qchain.logging: the Rerun viewer at {stalling_peer.url} stopped answering (")
    assert said[0].endswith(") and was given up; the MCAP log is not affected")
    assert summary["n_records"] == 300 and summary["error"] is None
    assert t_close < 2.0 + 2.0 + TEARDOWN_LIMIT + 20  # the viewer's time, its disconnect, a loaded machine's slack
    assert_complete(path, 300)
    assert wait_gone(lambda: descendants() - before) == set()


@pytest.mark.slow
def test_api_stalled_peer_and_rrd_the_rrd_is_complete(tmp_path, stalling_peer):
    """A .rrd beside a stalled viewer has a stream of its own: it is finalised (footer and
    all) before the run's end is confirmed, whatever the viewer does."""
    import rerun as rr  # (reads the file only: no recording stream in this process)

    before = descendants()
    path, rrd = tmp_path / "run.mcap", tmp_path / "run.rrd"
    summary, said, _, _ = log_run(path, arm_records(120), connect=stalling_peer.url, rrd=rrd, viewer_timeout=1.5)
    assert len(said) == 1 and "stopped answering" in said[0], said
    assert_complete(path, 120)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a file without its footer is read with a RerunWarning
        reader = rr.chunk.RrdReader(rrd)
        steps = set()
        for chunk in reader.stream():
            if not chunk.is_static and chunk.entity_path == "/plots/energy":
                rb = chunk.to_record_batch()
                steps.update(rb.column(rb.schema.names.index("step")).to_pylist())
    assert steps == set(range(120))
    assert wait_gone(lambda: descendants() - before) == set()


@pytest.mark.slow
def test_api_interrupted_run_with_a_stalled_peer(tmp_path, stalling_peer):
    """Ctrl-C in the run (a KeyboardInterrupt through the logger's block): the recording is
    finished with the outcome saying so, the viewer warned of, nothing left behind."""
    before = descendants()
    path = tmp_path / "run.mcap"
    records = arm_records(150)
    t0 = time.monotonic()
    with warnings.catch_warnings(record=True) as caught, pytest.raises(KeyboardInterrupt):
        warnings.simplefilter("always")
        with RunLogger(arm_info(), path, connect=stalling_peer.url, viewer_timeout=1.5, quiet=True) as log:
            for r in records:
                log.log(r)
            raise KeyboardInterrupt
    assert time.monotonic() - t0 < 60
    said = ours(caught)
    assert len(said) == 1 and "stopped answering" in said[0], said
    rec = assert_complete(path, 150)
    assert rec.outcome["success"] == "false" and "interrupted (KeyboardInterrupt) at t = 0.149 s" in \
        rec.outcome["message"]
    assert wait_gone(lambda: descendants() - before) == set()


def test_api_a_real_viewer_takes_the_run(tmp_path, rerun_server):
    """The positive case: a Rerun gRPC server answers the probe and takes the data; no
    warning, and the writer is gone soon after."""
    url, server_pid = rerun_server
    before = descendants() | {server_pid}
    path = tmp_path / "run.mcap"
    summary, said, t_close, _ = log_run(path, arm_records(300), connect=url, viewer_timeout=20.0)
    assert said == [] and summary["error"] is None
    assert t_close < 30
    assert_complete(path, 300)
    assert wait_gone(lambda: descendants() - before) == set()


@pytest.mark.slow
def test_api_in_memory_stream_with_a_stalled_peer_exits(tmp_path, stalling_peer):
    """The thread writer (an in-memory stream) feeds the viewer in the simulating process
    itself: close() is bounded, and the interpreter's exit too (Rerun's own exit handler
    would wait for the peer without end)."""
    code = f"""
import io, sys, time, warnings
sys.path.insert(0, {str(TESTS)!r})
from logging_fixtures import arm_info, arm_records
from qchain.logging import RunLogger, read_recording
buf = io.BytesIO()
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    with RunLogger(arm_info(), buf, connect=sys.argv[1], viewer_timeout=1.5, quiet=True) as log:
        for r in arm_records(100):
            log.log(r)
buf.seek(0)
print(len(read_recording(buf)), flush=True)
for w in caught:
    print("W", w.message, flush=True)
"""
    env = {k: v for k, v in os.environ.items() if k != "RUST_LOG"}
    env["PYTHONPATH"] = str(ROOT)
    t0 = time.monotonic()
    proc = subprocess.Popen([PY, "-c", code, stalling_peer.url], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=env, start_new_session=True)
    try:
        out, err = proc.communicate(timeout=180)
    except subprocess.TimeoutExpired:
        _kill_session(proc.pid)
        proc.communicate()
        raise AssertionError("a process that logged into a stream beside a stalled viewer did not exit") from None
    assert proc.returncode == 0, err
    assert time.monotonic() - t0 < 120
    lines = out.splitlines()
    assert lines[0] == "100"
    said = [ln for ln in lines[1:] if ln.startswith("W ")]
    assert len(said) == 1 and "stopped answering" in said[0], out
    assert wait_gone(lambda: session_members(proc.pid)) == set()


@pytest.mark.slow
def test_api_killed_run_with_a_stalled_peer(tmp_path, stalling_peer):
    """The simulating process killed (SIGKILL) while its writer feeds a stalled viewer: the
    writer finishes the recording from the journal and ends on its own, within its
    deadlines (it is in the killed run's session: that session empties)."""
    code = f"""
import sys, time
sys.path.insert(0, {str(TESTS)!r})
from logging_fixtures import arm_info, arm_record
from qchain.logging import RunLogger
log = RunLogger(arm_info(), sys.argv[1], connect=sys.argv[2], viewer_timeout=1.5, quiet=True)
for k in range(100):
    log.log(arm_record(k * 1e-3, k))
log.flush()
print("flushed", flush=True)
time.sleep(600)
"""
    env = {k: v for k, v in os.environ.items() if k != "RUST_LOG"}
    env["PYTHONPATH"] = str(ROOT)
    path = tmp_path / "run.mcap"
    proc = subprocess.Popen([PY, "-c", code, str(path), stalling_peer.url], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, env=env, start_new_session=True)
    try:
        assert proc.stdout.readline() == "flushed\n"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(30)
        left = wait_gone(lambda: session_members(proc.pid), within=1.5 + 2.0 + 2 * TEARDOWN_LIMIT + 30)
    finally:
        _kill_session(proc.pid)
        proc.stdout.close()
    assert left == set()
    rec = assert_complete(path, 100)
    assert rec.outcome["success"] == "false" and "killed" in rec.outcome["message"]


# --------------------------------------------------------------------------------------
# the feeding thread alone: a Rerun that blocks for ever
# --------------------------------------------------------------------------------------


class _BlockingRec:
    def __init__(self, gate):
        self.gate = gate

    def flush(self, timeout_sec):
        self.gate.wait()


class _BlockingSink:
    """A RerunSink whose every call blocks (as the SDK's once ~100 MB wait for a peer)."""

    def __init__(self):
        self.gate = threading.Event()
        self.rec = _BlockingRec(self.gate)
        self.batches = 0

    def write_batch(self, b):
        self.batches += 1
        self.gate.wait()

    def close(self):
        self.gate.wait()


def test_remote_viewer_never_blocks_its_caller(monkeypatch):
    """A send that never returns holds the feeding thread only: puts return at once, the
    viewer is given up after its timeout with one warning, and finish() is bounded."""
    from qchain.logging import RecordLayout
    from qchain.recording.records import Batch
    from qchain.recording import writer

    monkeypatch.setattr(writer, "bound_exit", lambda sink: None)  # (this test process has no Rerun to bound)
    lay = RecordLayout(9, 9, 9, 3, 12)
    rows = np.zeros((10, lay.row_width))
    rows[:, 0] = np.arange(10) * 1e-3
    rows[:, 1] = np.arange(10)
    b = Batch.from_rows(rows, lay)
    sink, said = _BlockingSink(), []
    rv = RemoteViewer(sink, "rerun+http://127.0.0.1:1/proxy", 0.5, said.append)
    try:
        t0 = time.monotonic()
        for _ in range(50):
            rv.put(b)
        assert time.monotonic() - t0 < 0.5
        time.sleep(0.8)
        rv.put(b)  # the thread has been in one call for longer than the timeout: given up
        assert rv.stalled is not None and said == [
            "the Rerun viewer at rerun+http://127.0.0.1:1/proxy stopped answering (it has taken no data for 0.5 s) "
            "and was given up; the MCAP log is not affected"]
        t0 = time.monotonic()
        assert rv.finish() == rv.stalled and rv.flush() == rv.stalled
        assert time.monotonic() - t0 < 0.5 and len(said) == 1 and sink.batches == 1
    finally:
        sink.gate.set()


# --------------------------------------------------------------------------------------
# qchain run --connect
# --------------------------------------------------------------------------------------


@pytest.mark.slow
def test_cli_a_peer_that_never_answers(tmp_path, scene, silent_peer):
    rc, out, err, took, sid = qchain_cli("run", scene, "--connect", silent_peer.url, "--mcap", tmp_path / "r.mcap",
                                         "--no-plots", "--no-progress", cwd=tmp_path)
    assert rc == 0, err
    assert err.splitlines() == [f"qchain run: warning: no Rerun viewer answers at {silent_peer.url} (the peer "
                                "accepted the connection but did not answer within 5 s); the run goes on without it"]
    assert "recorded " in out and "(11 samples, up to t = 0.1 s)" in out
    assert took < 200
    assert_complete(tmp_path / "r.mcap", 11)
    assert wait_gone(lambda: session_members(sid)) == set()


@pytest.mark.slow
def test_cli_a_peer_that_stalls_after_the_handshake(tmp_path, scene, stalling_peer):
    """The command's probe passes (the peer answers), the writer's viewer then stalls: one
    warning line, the recording complete, and no process of the command left (its session
    is empty) - before, the writer stayed in Rerun's disconnect without end."""
    rc, out, err, took, sid = qchain_cli("run", scene, "--connect", stalling_peer.url, "--mcap",
                                         tmp_path / "r.mcap", "--no-plots", "--no-progress", cwd=tmp_path)
    assert rc == 0, err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith(f"qchain run: warning: the Rerun viewer at {stalling_peer.url} stopped answering (")
    assert lines[0].endswith(") and was given up; the MCAP log is not affected")
    assert "(11 samples, up to t = 0.1 s)" in out
    assert took < 200
    assert_complete(tmp_path / "r.mcap", 11)
    assert wait_gone(lambda: session_members(sid)) == set()


@pytest.mark.slow
def test_cli_interrupted_with_a_stalled_peer(tmp_path, scene, stalling_peer):
    """Ctrl-C (SIGINT to the command's process group, as a terminal sends it; the writer has
    a group of its own) in a run paced to the wall clock: it ends, the recording says it was
    interrupted, and nothing of the command stays."""
    env = {k: v for k, v in os.environ.items() if k != "RUST_LOG"}
    env["PYTHONPATH"] = str(ROOT)
    mcap = tmp_path / "r.mcap"
    proc = subprocess.Popen([PY, "-m", "qchain", "run", str(scene), "--duration", "30", "--realtime", "--connect",
                             stalling_peer.url, "--mcap", str(mcap), "--no-plots", "--no-progress"], cwd=tmp_path,
                            env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 180
        while not Path(f"{mcap}.journal").exists() or os.path.getsize(f"{mcap}.journal") < 4096:
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.1)
        time.sleep(1.0)
        os.killpg(proc.pid, signal.SIGINT)
        t0 = time.monotonic()
        out, err = proc.communicate(timeout=120)
    except subprocess.TimeoutExpired:
        _kill_session(proc.pid)
        proc.communicate()
        raise AssertionError("the interrupted run did not end") from None
    finally:
        if proc.poll() is None:
            _kill_session(proc.pid)
    assert time.monotonic() - t0 < 60
    assert proc.returncode == 1, err
    assert "Traceback" not in err
    said = [ln for ln in err.splitlines() if "warning" in ln]
    assert len(said) == 1 and "stopped answering" in said[0], err
    rec = read_recording(mcap)
    assert rec.complete and len(rec) > 0 and "interrupted" in rec.outcome["message"]
    assert not Path(f"{mcap}.journal").exists()
    assert wait_gone(lambda: session_members(proc.pid)) == set()


# --------------------------------------------------------------------------------------
# output paths checked before the run
# --------------------------------------------------------------------------------------


def test_a_file_name_too_long_with_its_journal_is_refused_before_the_run(tmp_path):
    """A name that fits the file system but not with ``.journal`` after it: a LoggingError
    naming the path and the limit (before: a raw OSError, ENAMETOOLONG from the journal's
    check), and nothing made; a name one byte shorter runs."""
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    too_long = tmp_path / ("a" * (limit - len(".mcap") - len(".journal") + 1) + ".mcap")
    with pytest.raises(LoggingError) as err:
        check_outputs(too_long)
    msg = str(err.value)
    assert msg.startswith(f"mcap path {str(too_long)[:60]}")
    assert f"its file name is {limit - len('.journal') + 1} bytes long and its .journal file beside it needs 8 " \
           f"more, more than the {limit} bytes a file name may have there" in msg
    with pytest.raises(LoggingError, match="its .journal file beside it"):
        RunLogger(arm_info(), too_long, quiet=True)
    assert os.listdir(tmp_path) == []
    fits = tmp_path / ("a" * (limit - len(".mcap") - len(".journal")) + ".mcap")
    summary, said, _, _ = log_run(fits, arm_records(20))
    assert said == [] and summary["n_records"] == 20
    assert_complete(fits, 20)
    # a folder name too long, a NUL, a name that is not UTF-8: refused the same way
    with pytest.raises(LoggingError, match=rf"its folder name d+\.\.\.d+ is {limit + 1} bytes long, more than the "
                                           rf"{limit} bytes"):
        check_outputs(tmp_path / ("d" * (limit + 1)) / "x.mcap")
    with pytest.raises(LoggingError, match="contains a NUL character"):
        check_outputs(tmp_path / "x\0.mcap")
    with pytest.raises(LoggingError, match=r"is not UTF-8 text"):
        RunLogger(arm_info(), tmp_path / os.fsdecode(b"\xff.mcap"), quiet=True)
    with pytest.raises(LoggingError, match="rrd path .* its file name is"):
        check_outputs(None, tmp_path / ("r" * (limit + 1)))
    assert sorted(os.listdir(tmp_path)) == [fits.name]


@pytest.mark.parametrize("given", [os.fsdecode(b"scenes/arm-\xff\xfe.toml"), b"scenes/arm-\xff\xfe.toml"])
def test_a_scene_path_that_is_not_utf8_is_recorded_escaped(tmp_path, given):
    """A scene path of bytes that are not UTF-8 (as ``os.fsdecode`` gives them, or as
    bytes): recorded with those bytes escaped, and the run goes through (before: the
    journal was made, then its metadata failed to encode, leaving 39 bytes of junk)."""
    info = arm_info(scene_path=given)
    assert info.scene_path == "scenes/arm-\\xff\\xfe.toml"
    assert info.scene_file == os.fsdecode(b"scenes/arm-\xff\xfe.toml")
    path = tmp_path / "run.mcap"
    with RunLogger(info, path, quiet=True) as log:
        for r in arm_records(10):
            log.log(r)
    rec = assert_complete(path, 10)
    assert rec.info.scene_path == "scenes/arm-\\xff\\xfe.toml"
    assert os.listdir(tmp_path) == ["run.mcap"]


def test_text_that_is_not_utf8_is_refused_before_anything_is_made(tmp_path, monkeypatch):
    """Other RunInfo text is refused naming the field; and whatever fails while the journal
    is being made, the journal made is removed and the error names it."""
    for field in ("scene", "name"):
        with pytest.raises(ValueError, match=rf"{field} is not UTF-8 text \(surrogates not allowed: '\\udcff' at "):
            arm_info(**{field: "x\udcffy"})
    with pytest.raises(ValueError, match=r"q_names\[1\] is not UTF-8 text"):
        arm_info(q_names=["a", "b\udcff"])
    from qchain.recording import logger

    real = logger.info_metadata
    monkeypatch.setattr(logger, "info_metadata", lambda info, rid: {**real(info, rid), "scene": "\udcff"})
    path = tmp_path / "run.mcap"
    with pytest.raises(LoggingError, match=r"the recording's journal .*run\.mcap\.journal cannot be written \("
                                           r"'utf-8' codec can't encode"):
        RunLogger(arm_info(), path, quiet=True)
    assert os.listdir(tmp_path) == []


# --------------------------------------------------------------------------------------
# Hostile input (issue 18): what once ended in a foreign traceback, a hang, a crash, a silent
# NaN or lost data, kept fixed.

@pytest.mark.slow
@pytest.mark.parametrize("mode", ["garbage", "reset", "closed"])
def test_a_run_beside_a_peer_that_answers_garbage_keeps_every_record(tmp_path, mode):
    """RunLogger(connect=...) to a peer that answers garbage, resets, or a closed port: one
    warning, the recording complete, the run's summary clean."""
    peer = None if mode == "closed" else Peer(mode=mode)
    url = closed_port_url() if peer is None else peer.url
    path = tmp_path / "run.mcap"
    try:
        with deadline(120, f"a run beside a {mode} peer"), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with RunLogger(arm_info(), path, connect=url, viewer_timeout=2.0, quiet=True) as log:
                for r in arm_records(150):
                    log.log(r)
    finally:
        if peer is not None:
            peer.close()
    said = [str(w.message) for w in caught if issubclass(w.category, LoggingWarning)]
    assert len(said) == 1 and url in said[0] and "the MCAP log is still written" in said[0], said
    rec = read_recording(path)
    assert len(rec) == 150 and rec.complete and not journal_path(path).exists()


@pytest.mark.slow
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


@pytest.mark.slow
def test_connect_to_a_peer_that_never_answers_times_out(tmp_path, capsys):
    """A peer that accepts and never answers: a warning after the timeout, exit code 1, no
    process left."""
    p = write(tmp_path, craft())
    peer = Peer(answer=False)
    before = children()
    try:
        t0 = time.monotonic()
        assert replay_main([str(p), "--connect", peer.url, "--timeout", "1"]) == 1
        elapsed = time.monotonic() - t0
    finally:
        peer.close()
    assert 0.9 < elapsed < 10.0
    assert "did not answer within 1 s" in capsys.readouterr().err
    assert children() <= before


@pytest.mark.slow
def test_connect_to_a_peer_that_stops_halfway_is_cut_off(tmp_path):
    """A peer that answers the connection, then takes no data (the Rerun SDK would wait for
    it forever, even at exit): ``qchain replay`` warns and ends, and leaves no process."""
    data = craft(good_states(200), chunks=4)  # more than an HTTP/2 window of data
    p = write(tmp_path, data)
    peer = Peer(answer=True)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    try:
        t0 = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-m", "qchain", "replay", str(p), "--connect", peer.url,
                                 "--timeout", "1.5"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                env=env, stdin=subprocess.DEVNULL, start_new_session=True)
        try:
            out, err = proc.communicate(timeout=90)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
            raise AssertionError("qchain replay --connect did not end") from None
        elapsed = time.monotonic() - t0
    finally:
        peer.close()
    assert proc.returncode == 1, err
    assert "did not take the recording within 1.5 s" in err and "Traceback" not in err
    assert elapsed < 45.0
    # no process of that command outlives it: its session is empty
    leftover = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    fields = fh.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[4]) == proc.pid and fields[0] != "Z":  # session id
                leftover.append(int(entry))
    assert not leftover


def test_connect_to_a_real_viewer_sends(tmp_path, capsys):
    """A Rerun gRPC server on 127.0.0.1 answers the probe and takes the recording."""
    import rerun as rr

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    server = rr.RecordingStream("qchain-test-viewer")
    server.set_sinks(rr.GrpcServerSink(bind_ip="127.0.0.1", port=port))
    p = write(tmp_path, craft())
    before = children()
    try:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                time.sleep(0.05)
        assert replay_main([str(p), "--connect", f"rerun+http://127.0.0.1:{port}/proxy", "--timeout", "20"]) == 0
    finally:
        server.disconnect()
    out = capsys.readouterr()
    assert "replayed 6 steps" in out.out and "sent to" in out.out and "warning" not in out.err
    assert children() <= before
