"""Recordings that are no regular readable file (FIFOs, devices, folders, text streams,
unreadable files), outputs ``qchain replay``/``layout`` cannot write, and peers ``replay``
cannot send to (a closed port, garbage, resets): a clear error or one warning naming the file
or URL, never a hang or a file of another kind replaced."""

import io
import json
import os
import socket
import stat
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import pytest

from helpers import Peer, children, deadline
from qchain.cli.recording import layout_main, recover_main, replay_main
from qchain.logging import (
    LoggingError,
    LoggingWarning,
    ReadLimits,
    RecordingFormatError,
    journal_path,
    read_mcap,
    read_recording,
    recover,
    replay,
)
from support import (
    N_LOGGED,
    ROOT,
    craft,
    craft_chunks,
    good_states,
    info_json,
    refused_recording,
    splice,
    state_dicts,
    write,
)


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


def test_errors_and_summaries_stay_one_line_whatever_the_file_says(tmp_path, capsys):
    """A file name with a newline and an escape sequence, not UTF-8 bytes, an outcome
    message with control characters: the error is one line naming the file (escaped), and
    the summary prints no control character (before: a fake second error line, a
    terminal's screen cleared)."""
    bad = tmp_path / "a\nqchain replay: error: \x1b[2Jfake.mcap"
    bad.write_bytes(b"not a recording")
    assert replay_main([str(bad), "--rrd", str(tmp_path / "o.rrd")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "\x1b" not in err
    assert err.startswith("qchain replay: error: ") and "a\\nqchain replay: error: \\x1b[2Jfake.mcap" in err
    raw = Path(os.fsdecode(bytes(tmp_path) + b"/rec-\xff\xfe.mcap"))
    raw.write_bytes(b"junk")
    assert recover_main([str(raw)]) == 2
    err = capsys.readouterr().err
    assert "rec-\\xff\\xfe.mcap: not an MCAP file" in err and err.count("\n") == 1
    p = tmp_path / "ansi.mcap"
    p.write_bytes(craft_chunks(outcome={"success": "false", "status": "1", "message": "a\nb\x1b[2Jc\r", "n_records": "6"}))
    assert replay_main([str(p), "--rrd", str(tmp_path / "o.rrd")]) == 0
    out = capsys.readouterr().out
    assert "the run ended: a\\nb\\x1b[2Jc\\r" in out and "\x1b" not in out and "\r" not in out


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_layout_never_replaces_a_fifo_or_a_device(tmp_path, logged, kind, capsys):
    """Before: ``qchain layout r.mcap -o NODE`` made a temporary file and os.replace'd the
    FIFO or device node with it (``-o /dev/full`` as root). Now: refused, one line, exit 2."""
    from qchain.cli.recording import layout_main

    data, _ = logged
    rec = tmp_path / "r.mcap"
    rec.write_bytes(data)
    node = tmp_path / "node"
    if kind == "fifo":
        os.mkfifo(node)
    else:  # a link to a device: no privileges needed, and a replaced link leaves the device itself alone
        os.symlink(os.devnull, node)
    before = os.stat(node)
    assert layout_main([str(rec), "-o", str(node)]) == 2
    err = capsys.readouterr().err
    assert str(node) in err and err.count("\n") == 1, err
    after = os.stat(node)
    assert (after.st_mode, after.st_ino) == (before.st_mode, before.st_ino)
    assert sorted(os.listdir(tmp_path)) == ["node", "r.mcap"]


def test_a_text_stream_is_refused_with_a_clear_error(tmp_path, logged):
    data, _ = logged
    p = tmp_path / "r.mcap"
    p.write_bytes(data)
    with open(p) as fh, pytest.raises(TypeError, match=r"expected a binary stream \(open the file with 'rb'\)"):
        read_mcap(fh)
    with open(p, encoding="latin-1") as fh, pytest.raises(TypeError, match="binary stream"):
        read_recording(fh)

    class Texty:  # not an io.TextIOBase, but read() gives str
        def read(self, n=-1):
            return "\x89MCAP0\r\n"

    with pytest.raises(TypeError, match="binary stream"):
        read_recording(Texty())


@pytest.mark.parametrize("value", ["yes", 1, None, 0.0])
def test_read_recording_journal_flag_must_be_a_bool(tmp_path, logged, value):
    data, _ = logged
    p = tmp_path / "r.mcap"
    p.write_bytes(data)
    with pytest.raises(TypeError, match="journal must be True or False"):
        read_recording(p, journal=value)
    assert len(read_recording(p, journal=False)) == N_LOGGED


def _unblock_after(path: Path, seconds: float) -> threading.Timer:
    """If a reader is blocked opening the FIFO ``path``, open its other end after
    ``seconds`` so the test fails instead of hanging."""
    def unblock():
        try:
            fd = os.open(path, os.O_WRONLY | os.O_NONBLOCK)
            os.close(fd)
        except OSError:
            pass

    timer = threading.Timer(seconds, unblock)
    timer.daemon = True
    timer.start()
    return timer


def test_a_fifo_is_refused_without_waiting(tmp_path):
    """A FIFO as the recording (it blocked forever, or an 'Illegal seek' traceback): refused
    at once by the reader and by each command."""
    fifo = tmp_path / "run.mcap"
    os.mkfifo(fifo)
    timer = _unblock_after(fifo, 10.0)
    try:
        t0 = time.monotonic()
        refused_recording(fifo, "a FIFO (named pipe), not a recording file")
        with pytest.raises(RecordingFormatError, match="FIFO"):
            read_mcap(fifo)
        with pytest.raises(RecordingFormatError, match="FIFO"):
            recover(fifo)
        assert replay_main([str(fifo), "--rrd", str(tmp_path / "x.rrd")]) == 2
        assert layout_main([str(fifo)]) == 2
        assert recover_main([str(fifo)]) == 2
        assert time.monotonic() - t0 < 5.0
    finally:
        timer.cancel()
    assert stat.S_ISFIFO(os.stat(fifo).st_mode)  # left as it was


def test_a_fifo_from_the_command_line_ends(tmp_path):
    """The same as a process: ``qchain replay FIFO`` exits with code 2 and a message, no
    traceback, within its timeout."""
    fifo = tmp_path / "run.mcap"
    os.mkfifo(fifo)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run([sys.executable, "-m", "qchain", "replay", str(fifo), "--rrd", str(tmp_path / "x.rrd")],
                          capture_output=True, text=True, timeout=120, env=env, stdin=subprocess.DEVNULL)
    assert done.returncode == 2, done.stderr
    assert "FIFO" in done.stderr and "Traceback" not in done.stderr


def test_a_fifo_as_the_journal_is_not_read(tmp_path):
    """A FIFO where a killed run's journal would be: the recording reads, the journal is
    reported, nothing waits on it."""
    p = write(tmp_path, craft())
    os.mkfifo(journal_path(p))
    timer = _unblock_after(journal_path(p), 10.0)
    try:
        rec = read_recording(p)
    finally:
        timer.cancel()
    assert len(rec) == 6 and any(d.startswith("journal:") and "FIFO" in d for d in rec.damage)


def test_devices_and_folders_are_refused(tmp_path):
    refused_recording("/dev/zero", "a character device")
    refused_recording("/dev/null", "a character device")
    refused_recording(tmp_path, "a folder")
    refused_recording(write(tmp_path, b"x", "a_file") / "x.mcap", "cannot be read (Not a directory)")
    with pytest.raises(FileNotFoundError, match="no such recording"):
        read_recording(tmp_path / "nothing.mcap")


def test_a_file_that_cannot_be_read_is_an_error_naming_it(tmp_path, monkeypatch, capsys):
    """No permission to read (tests may run as root, where a mode of 000 does not stop
    reading, so the refusal is made by os.open itself): a RecordingFormatError naming the
    file, and exit code 2 from each command."""
    p = write(tmp_path, craft())
    real_open = os.open

    def no_permission(path, flags, *args, **kw):
        if os.fspath(path) == str(p):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, flags, *args, **kw)

    monkeypatch.setattr(os, "open", no_permission)
    refused_recording(p, "cannot be read (Permission denied)")
    for main in (layout_main, recover_main):
        assert main([str(p)]) == 2
    assert replay_main([str(p), "--rrd", str(tmp_path / "x.rrd")]) == 2
    err = capsys.readouterr().err
    assert err.count("Permission denied") == 3 and "Traceback" not in err


def test_arguments_of_the_wrong_type_are_type_errors_naming_them(tmp_path):
    for bad in (None, 123, 1.5, [str(tmp_path)]):
        with pytest.raises(TypeError, match="read_mcap: path must be a path"):
            read_mcap(bad)
        with pytest.raises(TypeError, match="read_recording: source must be a path"):
            read_recording(bad)
        with pytest.raises(TypeError, match="replay: path must be a path"):
            replay(bad, rrd=tmp_path / "x.rrd")
    with pytest.raises(TypeError, match="wrap bytes in io.BytesIO"):
        read_recording(craft())
    with pytest.raises(TypeError, match="binary mode"):
        read_recording(io.StringIO("abc"))
    with pytest.raises(TypeError, match="limits must be a ReadLimits"):
        read_recording(write(tmp_path, craft()), limits={"max_depth": 3})
    with pytest.raises(ValueError, match="ReadLimits.expansion"):
        ReadLimits(expansion=float("nan"))


@pytest.mark.slow
def test_every_command_refuses_every_kind_of_bad_file(tmp_path, gib_bomb, capsys):
    """qchain replay, recover and layout, and qchain.logging.replay, on each kind of bad
    input the tester reported: exit code 2 (a RecordingFormatError from the API) naming the
    file, no traceback, nothing written, the file left as it was."""
    deep = "[" * 100_000 + "]" * 100_000
    n = 1_000_000
    big_step = good_states()
    big_step[1]["step"] = 1e30
    files = {
        "deep.mcap": craft(meta={"info": '{"params": ' + deep + "}"}),
        "million.mcap": craft(states=[], info=info_json(n_segments=n, radii=[0.015] * n)),
        "step.mcap": craft(big_step),
        "bomb.mcap": splice(craft(), gib_bomb),
        "text.mcap": b"not a recording at all",
    }
    paths = [write(tmp_path, data, name) for name, data in files.items()]
    fifo = tmp_path / "fifo.mcap"
    os.mkfifo(fifo)
    paths += [fifo, tmp_path / "a_folder.mcap", Path("/dev/zero")]
    (tmp_path / "a_folder.mcap").mkdir()
    timer = _unblock_after(fifo, 20.0)
    try:
        for p in paths:
            before = p.read_bytes() if p.is_file() else None
            for name, main, args in (("replay", replay_main, ["--rrd", str(tmp_path / "out.rrd")]),
                                     ("recover", recover_main, []),
                                     ("layout", layout_main, ["-o", str(tmp_path / "l.json")])):
                assert main([str(p), *args]) == 2, (p, name)
                err = capsys.readouterr().err
                assert err.startswith(f"qchain {name}: error: {p}") and "Traceback" not in err, err
            with pytest.raises(RecordingFormatError, match=str(p)):
                replay(p, rrd=tmp_path / "out.rrd")
            assert not (tmp_path / "out.rrd").exists() and not (tmp_path / "l.json").exists()
            assert (p.read_bytes() if p.is_file() else None) == before
    finally:
        timer.cancel()


def test_replay_into_a_place_it_cannot_write_is_an_error(tmp_path, capsys):
    """--rrd under a file, the recording itself, a folder, a device: exit code 2 with a
    message (a traceback before), the recording unchanged."""
    data = craft()
    p = write(tmp_path, data)
    blocker = write(tmp_path, b"a file", "blocker")
    for out, why in [(blocker / "x.rrd", "cannot write rrd file"), (p, "is the recording being replayed"),
                     (tmp_path, "must be a file path"), (Path("/dev/full"), "not a regular file")]:
        assert replay_main([str(p), "--rrd", str(out)]) == 2
        err = capsys.readouterr().err
        assert why in err and "Traceback" not in err, err
        with pytest.raises(LoggingError, match=why):
            replay(p, rrd=out)
    assert p.read_bytes() == data


def test_layout_into_a_place_it_cannot_write_is_an_error(tmp_path, capsys):
    data = craft()
    p = write(tmp_path, data)
    blocker = write(tmp_path, b"a file", "blocker")
    for out, why in [(blocker / "l.json", "cannot write"), (p, "is the recording"), (tmp_path, "folder")]:
        assert layout_main([str(p), "-o", str(out)]) == 2
        assert why in capsys.readouterr().err
    assert p.read_bytes() == data
    assert layout_main([str(p), "-o", str(tmp_path / "ok" / "l.json")]) == 0
    assert json.loads((tmp_path / "ok" / "l.json").read_text())


@pytest.mark.slow
@pytest.mark.parametrize("mode, why", [("garbage", "not as an HTTP/2 (gRPC) server"),
                                       ("reset", "Connection reset by peer"),
                                       ("settings-then-reset", "")])
def test_replay_to_a_peer_that_answers_garbage_or_resets(tmp_path, mode, why):
    """Each ends within its deadline with sent False, one warning naming the URL, the
    recording read whole, and no process left."""
    p = tmp_path / "rec.mcap"
    p.write_bytes(craft_chunks(state_dicts(200), chunks=4))
    peer = Peer(mode=mode)
    before = children()
    try:
        t0 = time.monotonic()
        with deadline(90, f"replay to a {mode} peer"), warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            session = replay(p, connect=peer.url, timeout=3.0)
        took = time.monotonic() - t0
    finally:
        peer.close()
    said = [str(w.message) for w in caught if issubclass(w.category, LoggingWarning)]
    if mode == "settings-then-reset" and session.sent:  # the whole stream fit before the reset
        assert said == []
    else:
        assert session.sent is False and len(said) == 1 and peer.url in said[0] and why in said[0], said
    assert len(session.recording) == 200 and took < 60
    deadline_t = time.monotonic() + 10
    while children() - before and time.monotonic() < deadline_t:
        time.sleep(0.1)
    assert children() <= before


def test_connect_to_a_closed_port_warns_and_fails(tmp_path, capsys):
    """Nothing listening (it reported success before): a warning naming the URL, exit code 1."""
    p = write(tmp_path, craft())
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    t0 = time.monotonic()
    assert replay_main([str(p), "--connect", f"rerun+http://127.0.0.1:{port}/proxy"]) == 1
    out = capsys.readouterr()
    assert "warning: no Rerun viewer took the recording" in out.err and str(port) in out.err
    assert "not sent to" in out.out and "replayed" not in out.out
    assert time.monotonic() - t0 < 10.0
    with pytest.warns(LoggingWarning, match="Connection refused"):
        session = replay(p, connect=f"rerun+http://127.0.0.1:{port}/proxy")
    assert session.sent is False and session.problems and len(session.recording) == 6
