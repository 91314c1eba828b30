"""Untrusted recordings (issue 18, part B): reading is bounded in time and memory, and every
bad input ends in a RecordingFormatError (or TypeError for a bad argument) naming the file,
never a traceback, a hang, a crash, a silent NaN or lost data.

The files here are crafted with the mcap library's Writer (valid CRCs and seals, so the
reader's checks of content are what is tested, not the checksums) or from bytes by hand
(a zstd bomb, records of the wrong kind). Sockets and processes are on 127.0.0.1 only and
every wait has a hard timeout.
"""

from __future__ import annotations

import io
import json
import os
import signal
import socket
import stat
import struct
import subprocess
import sys
import threading
import time
import tracemalloc
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from helpers import Peer, children
from logging_fixtures import arm_info, arm_records
from mcap.writer import CompressionType, Writer

from qchain.logging import (
    TOPICS, LoggingError, LoggingWarning, ReadLimits, RecordingFormatError, RunLogger, journal_path, read_mcap,
    read_recording, recover, replay)
from qchain.cli.recording import layout_main, recover_main, replay_main
from qchain.recording.mcap_sink import info_metadata
from qchain.recording.records import seal
from qchain.recording.scan import scan

ROOT = Path(__file__).resolve().parents[1]
N_SEG, POINTS = 2, 4

# --------------------------------------------------------------------------------------
# Crafting recordings
# --------------------------------------------------------------------------------------


def state_of(r) -> dict:
    """A step record as the ``/qchain/state`` message's JSON object."""
    return {"t": r.t, "step": r.step, "q": r.q.tolist(), "v": r.v.tolist(), "p": r.p.tolist(),
            "kinetic": r.kinetic, "potential": r.potential, "total": r.total,
            "base": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "tips": r.tip_frames.tolist(),
            "backbone": r.backbone.tolist()}


def good_states(k: int = 6) -> list[dict]:
    return [state_of(r) for r in arm_records(k, dt=1e-2, n=N_SEG, P=POINTS)]


def craft(states=None, info: dict | None = None, meta: dict | None = None, outcome: dict | None = None,
          chunks: int = 2) -> bytes:
    """A qchain recording: the state channel only, ``states`` (dicts, or raw bytes as the
    message data) in ``chunks`` zstd chunks, the ``qchain`` metadata built from ``info``
    (RunInfo JSON) with ``meta`` entries replaced, all sealed."""
    base_info = arm_info(N_SEG)
    states = good_states() if states is None else states
    buf = io.BytesIO()
    w = Writer(buf, chunk_size=1 << 40, compression=CompressionType.ZSTD)
    w.start(profile="", library="crafted")
    sid = w.register_schema("qchain.State", "jsonschema", b"{}")
    cid = w.register_channel(TOPICS["state"], "json", sid)
    m = info_metadata(base_info, "crafted")
    if info is not None:
        m["info"] = json.dumps(info)
    m["channels"] = json.dumps({str(cid): TOPICS["state"]})
    if meta:
        m.update(meta)
    w.add_metadata("qchain", seal(m))
    per = max(1, -(-len(states) // chunks))
    for k, s in enumerate(states):
        w.add_message(cid, k, s if isinstance(s, bytes) else json.dumps(s, allow_nan=False).encode(), k, k)
        if (k + 1) % per == 0:
            w.flush()
    w.add_metadata("qchain.outcome", seal(outcome or {"success": "true", "status": "0", "message": "ok",
                                                      "nfev": "1"}))
    w.finish()
    return buf.getvalue()


def info_json(**changes) -> dict:
    d = json.loads(json.dumps(arm_info(N_SEG).to_json()))
    d.update(changes)
    return d


def chunk_record(compression: str, data: bytes, usize: int, crc: int) -> bytes:
    """An MCAP chunk record holding ``data`` as it stands."""
    c = compression.encode()
    body = struct.pack("<QQQII", 0, 0, usize, crc, len(c)) + c + struct.pack("<Q", len(data)) + data
    return struct.pack("<BQ", 0x06, len(body)) + body


def splice(data: bytes, record: bytes) -> bytes:
    """``data`` with ``record`` inserted before its first chunk."""
    first = next(item.offset for item in scan(data) if item.kind == "chunk")
    return data[:first] + record + data[first:]


def zstd_rle(total: int, byte: int = 0) -> bytes:
    """A zstd frame of ``total`` bytes ``byte``: RLE blocks of 128 KiB, 4 bytes each (32 KiB
    a GiB), window 128 KiB, so any decoder takes it."""
    out = bytearray(b"\x28\xb5\x2f\xfd" + bytes([0xC0, 0x38]) + struct.pack("<Q", total))
    left = total
    while left:
        n = min(1 << 17, left)
        left -= n
        out += struct.pack("<I", (n << 3) | (1 << 1) | (left == 0))[:3] + bytes([byte])
    return bytes(out)


def crc_of_repeated(byte: int, total: int) -> int:
    piece = bytes([byte]) * (1 << 20)
    crc = 0
    for _ in range(total >> 20):
        crc = zlib.crc32(piece, crc)
    return zlib.crc32(piece[: total & ((1 << 20) - 1)], crc)


def write(tmp_path: Path, data: bytes, name: str = "crafted.mcap") -> Path:
    p = tmp_path / name
    p.write_bytes(data)
    return p


def refused(path, match: str = "", **kw) -> RecordingFormatError:
    """The RecordingFormatError reading ``path`` raises; it names the file."""
    with pytest.raises(RecordingFormatError) as err:
        read_recording(path, **kw)
    msg = str(err.value)
    assert str(path) in msg, msg
    assert match in msg, msg
    return err.value


def assert_valid(rec) -> None:
    """A recording as the reader may hand it on: times and steps finite and in range, shapes
    consistent, and every non-finite value said in ``nonfinite``."""
    N = len(rec)
    assert rec.t.shape == (N,) and rec.step.shape == (N,) and rec.step.dtype == np.int64
    assert np.all(np.isfinite(rec.t)) and np.all((rec.t >= 0) & (rec.t <= 2**32 - 1))
    assert np.all((rec.step >= 0) & (rec.step <= 1 << 53))
    n = rec.info.n_segments
    assert rec.backbone.shape[:2] == (N, n) and rec.tip_frames.shape == (N, n, 7) and rec.base.shape == (N, 7)
    said = " ".join(rec.nonfinite)
    for key, label in (("q", "q"), ("v", "v"), ("p", "p"), ("energy", "energies"), ("base", "base"),
                       ("backbone", "backbone"), ("tip_frames", "tip frames")):
        arr = getattr(rec, key)
        assert np.all(np.isfinite(arr)) or f"{label}:" in said, (key, rec.nonfinite)
    if rec.nonfinite:
        assert "non-finite" in rec.to_trajectory().message


# --------------------------------------------------------------------------------------
# Content: nesting, sizes, numbers
# --------------------------------------------------------------------------------------


def test_a_crafted_recording_reads_back(tmp_path):
    """The crafting above makes a recording the reader takes (so the refusals below are
    about what was changed)."""
    states = good_states()
    rec = read_recording(write(tmp_path, craft(states)))
    assert len(rec) == 6 and rec.complete and not rec.damage and not rec.nonfinite
    np.testing.assert_array_equal(rec.q, [s["q"] for s in states])
    assert_valid(rec)


def test_deep_nesting_is_refused_naming_the_file_and_the_byte(tmp_path):
    """Run information, channel list and a state message nested 100000 deep (a
    RecursionError before): each a RecordingFormatError naming the file and the byte."""
    deep = "[" * 100_000 + "]" * 100_000
    cases = [
        ({"info": '{"n_segments": 2, "params": {"x": ' + deep + "}}"}, None, "the run information"),
        ({"channels": deep}, None, "channel list"),
        ({"info": json.dumps(info_json(params={"x": json.loads("[" * 70 + "]" * 70)}))}, None, "nested more than 64"),
        (None, [b'{"t": 0, "step": 0, "q": ' + deep.encode() + b"}"], "the state message in the chunk at byte"),
    ]
    for k, (meta, states, what) in enumerate(cases):
        p = write(tmp_path, craft(states=states, meta=meta), f"deep{k}.mcap")
        err = refused(p, what)
        assert "byte" in str(err)


def test_a_million_segments_is_refused_at_once(tmp_path):
    """A 6 MB file declaring a million segments (a layout asking for 10 GiB before): refused
    from the metadata, in well under a second, by read_recording and by qchain layout."""
    n = 1_000_000
    data = craft(states=[], info=info_json(n_segments=n, radii=[0.015] * n, chamber_radii=None))
    assert len(data) > 6e6
    p = write(tmp_path, data)
    t0 = time.monotonic()
    refused(p, "declares 1000000 segments, more than 10000")
    assert time.monotonic() - t0 < 5.0
    assert layout_main([str(p), "-o", str(tmp_path / "l.json")]) == 2
    assert not (tmp_path / "l.json").exists()
    # the limit is the reader's to raise
    ok = write(tmp_path, craft(info=info_json(n_segments=2)), "two.mcap")
    refused(ok, "declares 2 segments, more than 1", limits=ReadLimits(max_segments=1))


def test_the_commands_raise_the_segment_limit_with_a_flag(tmp_path, capsys):
    """A run whose budget allowed more segments than the reader's default is read back by
    raising --max-segments, never by editing code; a value outside 1..1e6 is a usage error."""
    two = write(tmp_path, craft(info=info_json(n_segments=2)), "two.mcap")
    out = tmp_path / ("l" * 240 + ".json")  # its temporary name must stay under the 255-byte limit too
    assert layout_main([str(two), "-o", str(out), "--max-segments", "1"]) == 2
    assert "--max-segments of qchain replay, recover and layout" in capsys.readouterr().err
    assert layout_main([str(two), "-o", str(out), "--max-segments", "2"]) == 0 and out.stat().st_size > 0
    assert sorted(x.name for x in tmp_path.iterdir()) == sorted(["two.mcap", out.name])  # no temporary left
    for bad in ("0", "1000001"):
        with pytest.raises(SystemExit) as exc:
            layout_main([str(two), "--max-segments", bad])
        assert exc.value.code == 2 and f"found {bad}" in capsys.readouterr().err
    assert replay_main([str(two), "--rrd", str(tmp_path / "r.rrd"), "--max-segments", "1"]) == 2
    assert not (tmp_path / "r.rrd").exists()


@pytest.mark.parametrize("field, value, match", [
    ("step", 1e30, "step must be a whole number"),  # an OverflowError before
    ("step", -1, "step must be a whole number"),
    ("step", 2.5, "step must be a whole number"),
    ("step", 2 ** 60, "step must be a whole number"),
    ("t", 1e30, "t must be a time from 0"),
    ("t", -1.0, "t must be a time from 0"),
    ("t", None, "t must be a time from 0"),
    ("q", ["a"] * 6, "not a number"),
    ("q", [True] * 6, "not a number"),
    ("q", [[1.0]] * 6, "nested 2 deep, expected 1"),
    ("q", list(range(100)), "q has the shape (100,), the others (6,)"),
    ("backbone", [], "backbone"),
    ("tips", [[0.0] * 7] * 3, "tips has the shape (3, 7), the others (2, 7)"),
    ("kinetic", [1.0], "kinetic"),
])
def test_values_out_of_the_format_are_refused(tmp_path, field, value, match):
    """A value the format does not allow in one state message (the third): refused naming
    the file, the chunk's byte and what is wrong."""
    states = good_states()
    states[2][field] = value
    refused(write(tmp_path, craft(states)), match)


def test_more_series_than_the_segments_have_are_refused(tmp_path):
    """q, v or p longer than 3 n + 7 (n segments and a floating base) in every record: a
    recording of 2 segments cannot have 100 coordinates (nor a layout and plots of them)."""
    for key in ("q", "v", "p"):
        states = good_states()
        for s in states:
            s[key] = list(range(100))
        refused(write(tmp_path, craft(states), f"{key}.mcap"), f"{key} has 100 entries; 2 segment(s) have at most 13")


def test_a_state_with_other_fields_is_refused(tmp_path):
    states = good_states()
    states[1]["extra"] = 1.0
    refused(write(tmp_path, craft(states), "extra.mcap"), "expected the fields")
    states = good_states()
    del states[4]["v"]
    refused(write(tmp_path, craft(states), "missing.mcap"), "expected the fields")
    refused(write(tmp_path, craft([b"[1, 2, 3]"]), "list.mcap"), "found a JSON list")


def test_shapes_that_change_between_records_are_refused(tmp_path):
    states = good_states(8)
    states[7]["q"] = states[7]["q"][:-1]  # the last record, in the second chunk
    err = refused(write(tmp_path, craft(states)), "q has the shape (5,), the others (6,)")
    chunk_offsets = [item.offset for item in scan(craft(states)) if item.kind == "chunk"]
    assert f"byte {chunk_offsets[-1]}" in str(err)


def test_non_finite_values_are_read_as_nan_and_said(tmp_path):
    """null in a state (what the writer makes of a non-finite value) reads as NaN, and the
    recording, its trajectory and a replay say so: never a silent NaN."""
    states = good_states()
    states[3]["q"][1] = None
    states[4]["potential"] = None
    p = write(tmp_path, craft(states))
    rec = read_recording(p)
    assert np.isnan(rec.q[3, 1]) and np.isnan(rec.energy[4, 1])
    assert rec.nonfinite == ["q: 1 value(s) in 1 record(s), the first at t = 0.03 s (step 3)",
                             "energies: 1 value(s) in 1 record(s), the first at t = 0.04 s (step 4)"]
    traj = read_mcap(p)
    assert "non-finite values recorded" in traj.message and traj.meta["nonfinite"] == rec.nonfinite
    assert_valid(rec)
    with pytest.warns(LoggingWarning, match="holds non-finite values"):
        replay(p, rrd=tmp_path / "out.rrd").close()


@pytest.mark.filterwarnings("ignore:overflow encountered in cast:RuntimeWarning")  # Rerun's float32 view
def test_huge_finite_numbers_read_and_replay(tmp_path):
    """Numbers near the float64 limit are finite: they read as they are and replay."""
    states = good_states()
    for s in states:
        s["q"] = [1e300] * 6
        s["p"] = [-1.7e308] * 6
        s["kinetic"] = 1.7e308
    p = write(tmp_path, craft(states))
    rec = read_recording(p)
    assert np.all(rec.q == 1e300) and not rec.nonfinite
    replay(p, rrd=tmp_path / "big.rrd").close()
    assert (tmp_path / "big.rrd").stat().st_size > 0


def test_metadata_values_of_the_wrong_kind_are_refused(tmp_path):
    cases = [
        (dict(info=json.dumps([1, 2])), "is a JSON list, not an object"),
        (dict(info="{nope"), "not valid JSON"),
        (dict(info=json.dumps(info_json(radii=["a", "b"]))), "does not have the expected form"),
        (dict(info=json.dumps(info_json(n_segments=True))), "does not have the expected form"),
        (dict(info=json.dumps(info_json(params={"segments": 5}))), "params.segments"),
        (dict(info=json.dumps(info_json(params={"segments": [{"length": "long"}, {}]}))), "params.segments"),
        (dict(channels=json.dumps({"1": "/qchain/state", "x": 5})), None),  # a key that is not an id: ignored
        (dict(format_version="2.0"), "format version '2.0'"),
        (dict(format_version="9" * 5000), "format version"),
    ]
    for k, (meta, match) in enumerate(cases):
        p = write(tmp_path, craft(meta=meta), f"m{k}.mcap")
        if match is None:
            assert len(read_recording(p)) == 6
        else:
            refused(p, match)


def test_an_outcome_of_the_wrong_kind_is_reported_not_used(tmp_path):
    for k, bad in enumerate([{"success": "maybe"}, {"success": "true", "status": "abc"},
                             {"success": "false", "nfev": "1" * 5000}, {"success": "true", "last_t": "nan"}]):
        rec = read_recording(write(tmp_path, craft(outcome=bad), f"o{k}.mcap"))
        assert rec.outcome is None and any("qchain.outcome" in d and "not usable" in d for d in rec.damage)
        traj = rec.to_trajectory()
        assert traj.success is False and len(traj.t) == 6


# --------------------------------------------------------------------------------------
# Size: bombs, record counts
# --------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def gib_bomb():
    """A 32 KiB zstd chunk that expands to 1 GiB of zeros, its CRC correct."""
    total = 1 << 30
    frame = zstd_rle(total)
    assert len(frame) < 33 * 1024
    return chunk_record("zstd", frame, total, crc_of_repeated(0, total))


def test_a_zstd_bomb_is_refused_in_bounded_time_and_memory(tmp_path, gib_bomb):
    """A 32 KiB chunk expanding to 1 GiB (no answer in 60 s before): refused naming the file
    and the chunk's byte, within seconds, having held well under 1 GiB."""
    data = splice(craft(), gib_bomb)
    p = write(tmp_path, data)
    at = data.index(gib_bomb)
    tracemalloc.start()
    try:
        t0 = time.monotonic()
        err = refused(p, "decompression bomb")
        elapsed = time.monotonic() - t0
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert f"at byte {at}" in str(err)
    assert elapsed < 10.0
    assert peak < 200 * 2**20, peak  # the budget: 64 MiB + 256 x 40 KB
    # the same through the commands: an error, exit code 2, the file left as it was
    assert layout_main([str(p)]) == 2 and recover_main([str(p)]) == 2
    assert p.read_bytes() == data


def test_a_bomb_declaring_a_small_size_is_refused_too(tmp_path):
    """The same frame in a chunk that declares 1000 bytes (the declared size is not
    trusted): refused as a bomb within the same bounds."""
    small = chunk_record("zstd", zstd_rle(1 << 30), 1000, 12345)
    data = splice(craft(), small)
    t0 = time.monotonic()
    err = refused(write(tmp_path, data), "declaring 1000 bytes")
    assert "decompression bomb" in str(err) and f"at byte {data.index(small)}" in str(err)
    assert time.monotonic() - t0 < 10.0


def test_an_intact_chunk_with_a_wrong_size_field_loses_nothing(tmp_path):
    """A chunk whose data match its CRC but not its declared size: read, the size reported."""
    body = craft()
    item = next(it for it in scan(body) if it.kind == "chunk")
    size_at = item.offset + 9 + 16
    bad = body[:size_at] + struct.pack("<Q", 7) + body[size_at + 8:]
    rec = read_recording(write(tmp_path, bad))
    assert len(rec) == 6 and not rec.gaps
    assert any(f"the chunk at byte {item.offset} declares 7 bytes" in d for d in rec.damage)


def test_many_tiny_records_in_a_chunk_are_refused(tmp_path):
    """A chunk of 10 million empty private records (9 bytes each, 90 MB compressing to a
    few KB): refused by the record count before parsing them all."""
    import zstandard

    raw = b"\x80" + bytes(8)
    body = raw * 10_000_000
    rec = chunk_record("zstd", zstandard.ZstdCompressor(level=3).compress(body), len(body), zlib.crc32(body))
    del body
    p = write(tmp_path, splice(craft(), rec))
    t0 = time.monotonic()
    err = refused(p)
    assert ("records inside chunks" in str(err) or "decompression bomb" in str(err))
    assert time.monotonic() - t0 < 10.0


def test_a_huge_declared_length_is_damage_not_an_allocation(tmp_path):
    """Records that declare lengths of up to 2**64 - 1 bytes: reported (the file ends inside
    a record, or damage), nothing allocated for them."""
    data = craft()
    first = next(item.offset for item in scan(data) if item.kind == "chunk")
    for length in (2**64 - 1, 2**40, len(data)):
        bad = data[:first + 1] + struct.pack("<Q", length) + data[first + 9:]
        rec = read_recording(write(tmp_path, bad, f"len{length}.mcap"))
        assert rec.damage and len(rec) == 3  # the first chunk lost, the second read
        assert_valid(rec)


def test_a_stream_is_read_up_to_its_limit(tmp_path):
    data = craft()
    assert len(read_recording(io.BytesIO(data))) == 6
    with pytest.raises(RecordingFormatError, match="more than 1000 bytes"):
        read_recording(io.BytesIO(data), limits=ReadLimits(max_stream_bytes=1000))
    with open("/dev/zero", "rb") as zero:  # an endless stream: refused from its first bytes
        with pytest.raises(RecordingFormatError, match="not an MCAP file"):
            read_recording(zero)


# --------------------------------------------------------------------------------------
# What a path names: FIFOs, devices, folders, files that cannot be read
# --------------------------------------------------------------------------------------


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
        refused(fifo, "a FIFO (named pipe), not a recording file")
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
    refused("/dev/zero", "a character device")
    refused("/dev/null", "a character device")
    refused(tmp_path, "a folder")
    refused(write(tmp_path, b"x", "a_file") / "x.mcap", "cannot be read (Not a directory)")
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
    refused(p, "cannot be read (Permission denied)")
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
        with pytest.raises(TypeError, match="recover: path must be a path"):
            recover(bad)
    with pytest.raises(TypeError, match="wrap bytes in io.BytesIO"):
        read_recording(craft())
    with pytest.raises(TypeError, match="binary mode"):
        read_recording(io.StringIO("abc"))
    with pytest.raises(TypeError, match="limits must be a ReadLimits"):
        read_recording(write(tmp_path, craft()), limits={"max_depth": 3})
    with pytest.raises(ValueError, match="ReadLimits.expansion"):
        ReadLimits(expansion=float("nan"))


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


# --------------------------------------------------------------------------------------
# Outputs: --rrd, -o, recover's file
# --------------------------------------------------------------------------------------


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


def test_recover_that_cannot_write_leaves_everything_as_it_was(tmp_path, monkeypatch, capsys):
    """A killed run's recording (cut after its last chunk, the tail in its journal) whose
    folder cannot be written: recover says so (exit code 2) and leaves the file and its
    journal as they were; once it can write, the recording is made whole."""
    import tempfile

    path = tmp_path / "killed.mcap"
    data = craft()
    last_chunk_end = [item.end for item in scan(data) if item.kind == "chunk"][-1]
    path.write_bytes(data[:last_chunk_end])
    rows, layout = _rows(3, t0=0.06, step0=6)
    _journal(path, rows, layout)
    before = (path.read_bytes(), journal_path(path).read_bytes())

    def refuse(*a, **k):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    assert recover_main([str(path)]) == 2
    assert "cannot write the recovered recording" in capsys.readouterr().err
    with pytest.raises(LoggingError, match="Permission denied"):
        recover(path)
    assert (path.read_bytes(), journal_path(path).read_bytes()) == before
    monkeypatch.undo()
    rec = recover(path)
    assert len(rec) == 9 and rec.complete and not journal_path(path).exists()
    np.testing.assert_array_equal(rec.step, np.arange(9))


# --------------------------------------------------------------------------------------
# --connect: peers that are closed, silent, or stop halfway
# --------------------------------------------------------------------------------------


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


# --------------------------------------------------------------------------------------
# Journals left by killed runs
# --------------------------------------------------------------------------------------


def _journal(path: Path, rows: np.ndarray, layout: dict, meta: dict | None = None) -> None:
    """A journal as a killed run leaves it: its qchain metadata, a rows channel of
    ``layout``, ``rows`` as one block."""
    from qchain.recording.journal import ROWS_ENCODING, ROWS_TOPIC

    with open(journal_path(path), "wb") as fh:
        w = Writer(fh, chunk_size=1 << 40, compression=CompressionType.NONE)
        w.start(profile="", library="qchain journal")
        m = info_metadata(arm_info(N_SEG), "crafted")
        m.update(meta or {})
        w.add_metadata("qchain", seal(m))
        sid = w.register_schema("qchain.RecordRows", "", b"")
        cid = w.register_channel(ROWS_TOPIC, ROWS_ENCODING, sid, {"layout": json.dumps(layout)})
        w.add_message(cid, 0, np.ascontiguousarray(rows, dtype=np.float64).tobytes(), 0, 0)
        w.flush()


def _rows(k: int, t0: float = 0.0, step0: int = 0) -> tuple[np.ndarray, dict]:
    from qchain.recording.records import Batch

    states = good_states(k)
    b = read_recording(io.BytesIO(craft(states))).batch()
    rows = b.rows()
    rows[:, 0] += t0
    rows[:, 1] += step0
    return rows, Batch.layout.fget(b).to_json()


def test_a_journal_alone_reads_and_bad_rows_are_refused(tmp_path):
    path = tmp_path / "killed.mcap"
    rows, layout = _rows(5)
    _journal(path, rows, layout)
    rec = read_recording(path)
    assert len(rec) == 5 and rec.recovered == 5
    assert_valid(rec)
    for k, (col, value) in enumerate([(0, np.nan), (0, 1e30), (1, 2.5), (1, -1.0), (1, np.inf)]):
        bad = rows.copy()
        bad[2, col] = value
        _journal(path, bad, layout)
        err = refused(path, "journal")
        assert str(journal_path(path)) in str(err) and ("time" in str(err) or "step" in str(err))


def test_a_journal_with_a_bad_layout_is_reported_not_a_crash(tmp_path):
    path = tmp_path / "killed.mcap"
    path.write_bytes(craft())
    rows, layout = _rows(3, t0=1.0, step0=100)
    for k, lay in enumerate([{**layout, "nq": "six"}, {**layout, "P": 0}, {**layout, "n": 2**30},
                             {**layout, "nq": layout["nq"] + 1}, [1, 2]]):
        _journal(path, rows, lay)
        rec = read_recording(path)  # the file's records; the journal's rows not used
        assert len(rec) == 6 and rec.recovered == 0
        assert any(d.startswith("journal:") for d in rec.damage), rec.damage
    from qchain.recording.records import RecordLayout

    other = RecordLayout(9, 9, 9, 3, POINTS)  # whole rows of another arm: refused, named
    rows3 = np.zeros((3, other.row_width))
    rows3[:, 0], rows3[:, 1] = [1.0, 1.1, 1.2], [100, 101, 102]
    _journal(path, rows3, other.to_json())
    rec = read_recording(path)  # the file's own records read; the journal said, kept, not merged
    assert len(rec) == 6 and rec.recovered == 0
    assert "rows are of 3 segment(s), the recording's 2: not merged" in rec.journal_unread
    assert any("rows are of 3 segment(s)" in d for d in rec.damage)
    with pytest.raises(LoggingError, match="cannot be \\(wholly\\) merged"):
        recover(path)
    assert journal_path(path).exists()
    _journal(path, rows, layout)
    rec = read_recording(path)  # a complete file (outcome, summary): never merged, said
    assert len(rec) == 6 and rec.recovered == 0 and "complete" in rec.journal_unread
    from qchain.recording.scan import scan

    whole = craft()
    path.write_bytes(whole[: [it.end for it in scan(whole) if it.kind == "chunk"][-1]])  # killed: no outcome
    rec = read_recording(path)
    assert len(rec) == 9 and rec.recovered == 3
    path.write_bytes(b"")
    journal_path(path).write_bytes(b"not a journal at all")
    refused(path, "no recording file, and its journal")


# --------------------------------------------------------------------------------------
# The property: mutate a valid recording, the reading ends well and in time
# --------------------------------------------------------------------------------------


class Valid:
    """A small recording written by RunLogger (all four channels, a few chunks), and a
    folder for its mutants (a short repr for hypothesis' reports)."""

    def __init__(self, data: bytes, folder: Path):
        self.data, self.folder = data, folder

    def __repr__(self) -> str:
        return f"<a valid recording of {len(self.data)} bytes>"


@pytest.fixture(scope="module")
def valid_small(tmp_path_factory):
    records = arm_records(24, dt=1e-2, n=N_SEG, P=POINTS)
    buf = io.BytesIO()
    with RunLogger(arm_info(N_SEG), buf, flush_interval=0.07, quiet=True) as log:
        for r in records:
            log.log(r)
    valid = Valid(buf.getvalue(), tmp_path_factory.mktemp("mutants"))
    assert len(read_recording(io.BytesIO(valid.data))) == 24
    return valid


JSON_VALUES = st.one_of(
    st.none(), st.booleans(), st.text(max_size=5),
    st.floats(allow_nan=False, allow_infinity=False), st.sampled_from([1e308, -1e308, 2**64, 10**30, -(2**63)]),
    st.integers(-(2**70), 2**70),
    st.integers(1, 3000).map(lambda d: json.loads("[" * d + "]" * d) if d < 900 else {"deep": d}),
    st.lists(st.floats(allow_nan=False, allow_infinity=False), max_size=12),
    st.dictionaries(st.text(max_size=3), st.integers(), max_size=3),
)
STATE_FIELDS = ["t", "step", "q", "v", "p", "kinetic", "potential", "total", "base", "tips", "backbone"]
INFO_FIELDS = ["n_segments", "radii", "chamber_radii", "chamber_angles", "pressure_ref", "params", "q_names",
               "duration", "scene", "name"]


@st.composite
def mutants(draw, data: bytes):
    """A mutant of ``data``: bits flipped, cut, bytes inserted, or a recording crafted with a
    state's or the run information's value replaced, or metadata nested deep."""
    kind = draw(st.sampled_from(["flip", "cut", "insert", "state", "info", "deep"]))
    if kind == "flip":
        out = bytearray(data)
        for _ in range(draw(st.integers(1, 8))):
            out[draw(st.integers(0, len(data) - 1))] ^= 1 << draw(st.integers(0, 7))
        return bytes(out)
    if kind == "cut":
        return data[: draw(st.integers(0, len(data) - 1))]
    if kind == "insert":
        at = draw(st.integers(0, len(data)))
        junk = draw(st.one_of(st.binary(min_size=1, max_size=64),
                              st.sampled_from([b"\x06" + bytes(8), b"\x0c" + struct.pack("<Q", 2**63),
                                               b"\x06" * 40, b"\x89MCAP0\r\n"])))
        return data[:at] + junk + data[at:]
    if kind == "state":
        states = good_states(draw(st.integers(1, 8)))
        k = draw(st.integers(0, len(states) - 1))
        states[k][draw(st.sampled_from(STATE_FIELDS))] = draw(JSON_VALUES)
        return craft(states, chunks=draw(st.integers(1, 3)))
    if kind == "info":
        return craft(info=info_json(**{draw(st.sampled_from(INFO_FIELDS)): draw(JSON_VALUES)}))
    d = draw(st.integers(100, 200_000))  # nesting deep enough to overflow a recursive parser
    return craft(meta={draw(st.sampled_from(["info", "channels"])): "[" * d + "]" * d})


@settings(max_examples=250, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(data=st.data())
def test_mutated_recordings_read_well_or_are_refused_in_time(valid_small, data):
    """Bit flips, cuts, inserted bytes, state and run-information values replaced (deep
    nesting, huge numbers, wrong types): each reading ends within 5 s with either a
    recording whose values are finite (or said non-finite), times and steps in range and
    shapes consistent, or a RecordingFormatError naming the file. Nothing else is raised."""
    good, folder = valid_small.data, valid_small.folder
    mutant = data.draw(mutants(good), label="mutant")
    path = folder / "mutant.mcap"
    path.write_bytes(mutant)
    t0 = time.monotonic()
    try:
        rec = read_recording(path)
    except RecordingFormatError as exc:
        assert str(path) in str(exc), str(exc)
    else:
        assert_valid(rec)
        traj = rec.to_trajectory()
        assert len(traj.t) == len(rec)
    assert time.monotonic() - t0 < 5.0
