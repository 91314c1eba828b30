"""A fresh set of hostile recordings and viewer peers (issue 18, tried again): what the first
round of fixes let through, kept fixed.

Each test crafts one kind (the mcap library's ``Writer`` for valid containers with hostile
content, raw bytes for the container itself) and asserts what could be false: records cut
out of a file cleanly, or counted by the file but missing, are said (a gap), never dropped
silently; a channel declared twice keeps its first declaration; records out of order are
said; a file too big to read is refused before anything is allocated; ``recover`` works
for every name ``check_outputs`` accepts and never removes a journal it could not read;
the commands' one-line errors stay one line whatever a file's name or outcome says; peers
that answer garbage or reset the connection end ``replay --connect`` with a warning and no
process left. Sockets are on 127.0.0.1 only; every wait has a deadline.
"""

from __future__ import annotations

import io
import json
import os
import struct
import time
import warnings
import zlib
from pathlib import Path

import numpy as np
import pytest
from helpers import Peer, children, closed_port_url, deadline
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from logging_fixtures import arm_info, arm_records
from mcap.records import Channel
from mcap.writer import CompressionType, Writer

from qchain.logging import (
    TOPICS, LoggingError, LoggingWarning, ReadLimits, RecordingFormatError, RunLogger, check_outputs, journal_path,
    read_mcap, read_recording, recover, replay)
from qchain.cli.recording import recover_main, replay_main
from qchain.recording.mcap_sink import info_metadata
from qchain.recording.records import seal
from qchain.recording.scan import scan

N_SEG, POINTS, N = 2, 4, 60


def _states(k: int) -> list[dict]:
    out = []
    for r in arm_records(k, dt=1e-2, n=N_SEG, P=POINTS):
        out.append({"t": r.t, "step": r.step, "q": r.q.tolist(), "v": r.v.tolist(), "p": r.p.tolist(),
                    "kinetic": r.kinetic, "potential": r.potential, "total": r.total,
                    "base": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "tips": r.tip_frames.tolist(),
                    "backbone": r.backbone.tolist()})
    return out


def craft(states=None, *, info: dict | None = None, outcome: dict | None = None, chunks: int = 2,
          before=None) -> bytes:
    """A state-only qchain recording (sealed metadata, zstd chunks); ``before(writer, cid)``
    may add records ahead of the messages."""
    states = _states(6) if states is None else states
    buf = io.BytesIO()
    w = Writer(buf, chunk_size=1 << 40, compression=CompressionType.ZSTD)
    w.start(profile="", library="crafted")
    sid = w.register_schema("qchain.State", "jsonschema", b"{}")
    cid = w.register_channel(TOPICS["state"], "json", sid)
    m = info_metadata(arm_info(N_SEG), "crafted")
    if info is not None:
        m["info"] = json.dumps(info)
    m["channels"] = json.dumps({str(cid): TOPICS["state"]})
    w.add_metadata("qchain", seal(m))
    if before is not None:
        before(w, cid)
    per = max(1, -(-len(states) // chunks))
    for k, s in enumerate(states):
        w.add_message(cid, k, json.dumps(s).encode(), k, k)
        if (k + 1) % per == 0:
            w.flush()
    w.add_metadata("qchain.outcome", seal(outcome or {"success": "true", "status": "0", "message": "ok",
                                                      "n_records": str(len(states))}))
    w.finish()
    return buf.getvalue()


@pytest.fixture(scope="module")
def logged():
    """A recording written by RunLogger (four channels, 11 chunks) and its chunks:
    (offset, end, state records inside)."""
    buf = io.BytesIO()
    with RunLogger(arm_info(N_SEG), buf, flush_interval=0.05, quiet=True) as log:
        for r in arm_records(N, dt=1e-2, n=N_SEG, P=POINTS):
            log.log(r)
    data = buf.getvalue()
    rec = read_recording(io.BytesIO(data))
    state = {int(k) for k, v in json.loads(rec.metadata["channels"]).items() if v == TOPICS["state"]}
    chunks = [(it.offset, it.end, sum(1 for r in it.records if type(r).__name__ == "Message"
                                      and r.channel_id in state))
              for it in scan(data) if it.kind == "chunk"]
    assert sum(n for _, _, n in chunks) == N and len(chunks) >= 8
    return data, chunks


def _said(rec) -> bool:
    """The reading says something is missing."""
    return bool(rec.gaps or rec.truncated) and not rec.complete and not rec.to_trajectory().success


# --------------------------------------------------------------------------------------
# Records missing without damage: said, never silent
# --------------------------------------------------------------------------------------


@settings(max_examples=12, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(k=st.integers(0, 10), summary=st.booleans())
def test_a_chunk_cut_out_cleanly_is_a_gap_not_silence(logged, k, summary):
    """A whole chunk removed byte-exactly (nothing damaged is left to find; the summary
    either kept as is or dropped): before, the file read back N - n records as complete and
    successful. Now the outcome's count (and the summary's) makes it a gap."""
    data, chunks = logged
    a, e, n = chunks[k % len(chunks)]
    cut = data[:a] + data[e:]
    if not summary:  # the file ends after its data: the outcome record is in the data section
        cut = cut[: [it.end for it in scan(cut) if it.kind == "metadata"][-1]]
    rec = read_recording(io.BytesIO(cut))
    assert len(rec) == N - n
    assert _said(rec), (rec.gaps, rec.truncated, rec.damage)
    assert f"counts {N} records, {N - n} were read: {n} missing" in rec.to_trajectory().message


def test_an_outcome_counting_more_records_than_the_file_holds_is_a_gap(tmp_path, capsys):
    p = tmp_path / "short.mcap"
    p.write_bytes(craft(outcome={"success": "true", "status": "0", "message": "ok", "n_records": "1000"}))
    rec = read_recording(p)
    assert len(rec) == 6 and rec.gaps and not rec.complete
    assert "counts 1000 records, 6 were read: 994 missing" in rec.gaps[0].reason
    assert replay_main([str(p), "--rrd", str(tmp_path / "o.rrd")]) == 0
    assert "994 missing" in capsys.readouterr().out
    # the count of a file that holds all its records says nothing
    p.write_bytes(craft())
    assert read_recording(p).complete


def test_a_channel_declared_twice_keeps_its_first_declaration(tmp_path):
    """The state channel's id declared again as another topic: before, every state message
    was dropped silently (0 records, complete). Now the first declaration holds and the
    second is reported."""
    def redeclare(w, cid):
        w._Writer__chunk_builder.add_channel(Channel(id=cid, schema_id=1, topic=TOPICS["tf"],
                                                     message_encoding="protobuf", metadata={}))

    p = tmp_path / "twice.mcap"
    p.write_bytes(craft(before=redeclare))
    rec = read_recording(p)
    assert len(rec) == 6
    assert any(f"declares channel 1 again as '{TOPICS['tf']}'" in d for d in rec.damage), rec.damage


def test_messages_on_a_channel_never_declared_are_said(tmp_path):
    states = _states(6)
    buf = io.BytesIO()
    w = Writer(buf, chunk_size=1 << 40, compression=CompressionType.NONE)
    w.start(profile="", library="crafted")
    sid = w.register_schema("qchain.State", "jsonschema", b"{}")
    cid = w.register_channel(TOPICS["state"], "json", sid)
    m = info_metadata(arm_info(N_SEG), "crafted")
    m["channels"] = json.dumps({str(cid): TOPICS["state"]})
    w.add_metadata("qchain", seal(m))
    for k, s in enumerate(states):
        w.add_message(cid if k != 3 else 99, k, json.dumps(s).encode(), k, k)
    w.add_metadata("qchain.outcome", seal({"success": "true", "status": "0", "message": "ok", "n_records": "6"}))
    w.finish()
    rec = read_recording(io.BytesIO(buf.getvalue()))
    assert len(rec) == 5
    assert any("1 message(s) on channel(s) 99 that no channel record declares" in d for d in rec.damage)
    assert rec.gaps and "1 missing" in rec.gaps[0].reason  # and the outcome's count says one is missing


# --------------------------------------------------------------------------------------
# Records out of order
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("how", ["swapped", "duplicated"])
def test_records_out_of_order_are_said(logged, tmp_path, capsys, how):
    """Two chunks swapped, or one duplicated: every record is read, and the time going back
    is said in the recording, the trajectory, a warning and the replay's summary (before:
    accepted silently, the time axis going backwards)."""
    data, chunks = logged
    (a1, e1, _), (a2, e2, _) = chunks[1], chunks[2]
    bad = data[:a1] + data[a2:e2] + data[a1:e1] + data[e2:] if how == "swapped" else data[:e2] + data[a2:e2] + data[e2:]
    p = tmp_path / "order.mcap"
    p.write_bytes(bad)
    rec = read_recording(p)
    assert len(rec) >= N and np.any(np.diff(rec.t) < 0)
    assert rec.disorder.startswith("records out of order: ")
    assert rec.disorder in read_mcap(p).message
    with pytest.warns(LoggingWarning, match="records out of order"):
        replay(p, rrd=tmp_path / "o.rrd")
    assert replay_main([str(p), "--rrd", str(tmp_path / "o2.rrd")]) == 0
    assert "records out of order" in capsys.readouterr().out
    assert read_recording(io.BytesIO(data)).disorder == ""


# --------------------------------------------------------------------------------------
# Sizes: files too big, bombs of the other codec, lengths of 2**63
# --------------------------------------------------------------------------------------


def test_a_file_bigger_than_the_limit_is_refused_before_it_is_read(tmp_path, capsys):
    """A sparse file of 64 GiB (before: a MemoryError, 'out of memory' with exit code 1, or
    the whole file read into memory): refused from its size, naming the file and the limit."""
    p = tmp_path / "huge.mcap"
    with open(p, "wb") as fh:
        fh.write(b"\x89MCAP0\r\n")
        fh.truncate(64 << 30)
    t0 = time.monotonic()
    with deadline(20, "reading a 64 GiB sparse file"):
        with pytest.raises(RecordingFormatError, match=r"huge\.mcap: the file is 68719476736 bytes .*"
                                                       r"ReadLimits\.max_file_bytes"):
            read_recording(p)
        assert recover_main([str(p)]) == 2
    assert time.monotonic() - t0 < 10
    err = capsys.readouterr().err
    assert err.startswith(f"qchain recover: error: {p}: the file is") and err.count("\n") == 1
    assert os.path.getsize(p) == 64 << 30
    small = tmp_path / "small.mcap"
    small.write_bytes(craft())
    with pytest.raises(RecordingFormatError, match="more than the 0.0009766 MiB"):
        read_recording(small, limits=ReadLimits(max_file_bytes=1024))
    with pytest.raises(ValueError, match="max_file_bytes"):
        ReadLimits(max_file_bytes=0)


def test_an_lz4_bomb_is_refused_within_the_budget(tmp_path):
    """The zstd bombs were tested; lz4 (at most 255:1, 64 MiB of zeros in 256 KiB) too: refused
    by the budget, naming the file, the byte and the limit to raise."""
    import lz4.frame

    good = craft()
    raw = bytes(64 << 20)
    bomb = lz4.frame.compress(raw, compression_level=0)
    c = b"lz4"
    body = struct.pack("<QQQII", 0, 0, len(raw), zlib.crc32(raw), len(c)) + c + struct.pack("<Q", len(bomb)) + bomb
    first = next(it.offset for it in scan(good) if it.kind == "chunk")
    p = tmp_path / "lz4bomb.mcap"
    p.write_bytes(good[:first] + struct.pack("<BQ", 0x06, len(body)) + body + good[first:])
    with deadline(20, "an lz4 bomb"):
        with pytest.raises(RecordingFormatError, match=rf"{p.name}: at byte {first}.*ReadLimits\.expansion"):
            read_recording(p, limits=ReadLimits(expansion=8.0, slack_bytes=1 << 20))
        assert len(read_recording(p)) == 6  # within the default budget: decompressed, its zeros are damage


@pytest.mark.parametrize("opcode", [0x01, 0x03, 0x05, 0x09, 0x0C, 0x80])
def test_a_record_claiming_2_63_bytes_loses_nothing(tmp_path, opcode):
    good = craft()
    first = next(it.offset for it in scan(good) if it.kind == "chunk")
    p = tmp_path / "long.mcap"
    p.write_bytes(good[:first] + struct.pack("<BQ", opcode, 1 << 63) + bytes(16) + good[first:])
    with deadline(10, "a record of 2**63 bytes"):
        rec = read_recording(p)
    assert len(rec) == 6 and rec.damage


def test_a_duration_past_the_recordable_range_is_refused_not_a_crash(tmp_path, capsys):
    """RunInfo.duration 1e308 (finite): before, the replay crashed in Rerun's time
    conversion (OverflowError, exit code 1). Now RunInfo refuses it, writing and reading."""
    info = json.loads(json.dumps(arm_info(N_SEG).to_json()))
    info["duration"] = 1e308
    p = tmp_path / "long.mcap"
    p.write_bytes(craft(info=info))
    with pytest.raises(RecordingFormatError, match="duration must be None or a time > 0 s and <= 4294967295 s"):
        read_recording(p)
    assert replay_main([str(p), "--rrd", str(tmp_path / "o.rrd")]) == 2
    assert "Traceback" not in capsys.readouterr().err
    with pytest.raises(ValueError, match="duration"):
        arm_info(N_SEG, duration=1e10)


# --------------------------------------------------------------------------------------
# recover: names, journals it cannot read
# --------------------------------------------------------------------------------------


def _killed(path: Path, data: bytes, keep_chunks: int) -> int:
    """``path`` as a killed run leaves it: ``data`` cut after its first ``keep_chunks`` chunks."""
    ends = [it.end for it in scan(data) if it.kind == "chunk"]
    path.write_bytes(data[: ends[keep_chunks - 1]])
    return ends[keep_chunks - 1]


def test_recover_works_for_the_longest_name_check_outputs_accepts(tmp_path, logged):
    """Before: the temporary file was named after the recording plus 20 bytes, and a name
    check_outputs accepts (NAME_MAX - len('.journal')) failed with 'File name too long'.
    Also a name of NAME_MAX bytes (no journal can exist beside it)."""
    data, chunks = logged
    limit = os.pathconf(tmp_path, "PC_NAME_MAX")
    for size in (limit - len(".journal"), limit):
        folder = tmp_path / str(size)
        folder.mkdir()
        p = folder / ("r" * (size - len(".mcap")) + ".mcap")
        if size < limit:
            check_outputs(p)  # accepted for a run
        _killed(p, data, 4)
        kept = sum(n for _, _, n in chunks[:4])
        rec = recover(p)
        assert len(rec) == kept and rec.complete
        assert os.listdir(folder) == [p.name]


@pytest.mark.parametrize("journal", ["folder", "junk", "fifo"])
def test_recover_never_removes_a_journal_it_could_not_read(tmp_path, logged, journal, capsys):
    """A killed run's file beside a journal that cannot be read: before, recover wrote the
    file and removed the journal (or failed after writing). Now it refuses, changing
    nothing, and says how to go on."""
    data, _ = logged
    p = tmp_path / "killed.mcap"
    _killed(p, data, 3)
    jp = journal_path(p)
    if journal == "folder":
        jp.mkdir()
    elif journal == "junk":
        jp.write_bytes(b"\x89MCAP0\r\n" + b"\x06" * 5000)
    else:
        os.mkfifo(jp)
    before = p.read_bytes()
    with deadline(20, "recover beside an unreadable journal"):
        assert recover_main([str(p)]) == 2 if journal != "junk" else True
        err = capsys.readouterr().err
        if journal != "junk":
            assert "its journal" in err and "nothing was changed" in err and err.count("\n") == 1, err
            with pytest.raises(LoggingError, match="move it away to recover the file without it"):
                recover(p)
        else:  # junk chunks after its magic: read as damage, nothing in it; recover takes what there is
            recover(p)
    assert os.path.lexists(jp) or journal == "junk"
    if journal != "junk":
        assert p.read_bytes() == before


# --------------------------------------------------------------------------------------
# What the commands print: one line per error, whatever a file's name or outcome holds
# --------------------------------------------------------------------------------------


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
    p.write_bytes(craft(outcome={"success": "false", "status": "1", "message": "a\nb\x1b[2Jc\r", "n_records": "6"}))
    assert replay_main([str(p), "--rrd", str(tmp_path / "o.rrd")]) == 0
    out = capsys.readouterr().out
    assert "the run ended: a\\nb\\x1b[2Jc\\r" in out and "\x1b" not in out and "\r" not in out


# --------------------------------------------------------------------------------------
# Bit flips and cuts: never fewer records than the intact chunks hold, never silently
# --------------------------------------------------------------------------------------


@settings(max_examples=40, deadline=None, derandomize=True, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_flips_and_cuts_lose_only_their_chunk_and_say_so(logged, data):
    good, chunks = logged
    if data.draw(st.booleans(), label="cut"):
        at = data.draw(st.integers(len(b"\x89MCAP0\r\n"), len(good) - 1), label="cut at")
        mutant = good[:at]
        lost = sum(n for a, e, n in chunks if e > at)
    else:
        at = data.draw(st.integers(8, len(good) - 1), label="flip at")
        mutant = bytearray(good)
        mutant[at] ^= 1 << data.draw(st.integers(0, 7), label="bit")
        mutant = bytes(mutant)
        lost = sum(n for a, e, n in chunks if a <= at < e)
    with deadline(10, "reading a mutant"):
        try:
            rec = read_recording(io.BytesIO(mutant))
        except RecordingFormatError:
            assert at < chunks[0][0]  # only a file cut or flipped before its first chunk may be refused
            return
    assert len(rec) >= N - lost
    if len(rec) < N:
        assert _said(rec) or rec.damage, (rec.gaps, rec.truncated, rec.damage)


# --------------------------------------------------------------------------------------
# Peers that answer garbage or reset
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("mode, why", [("garbage", "not as an HTTP/2 (gRPC) server"),
                                       ("reset", "Connection reset by peer"),
                                       ("settings-then-reset", "")])
def test_replay_to_a_peer_that_answers_garbage_or_resets(tmp_path, mode, why):
    """Each ends within its deadline with sent False, one warning naming the URL, the
    recording read whole, and no process left."""
    p = tmp_path / "rec.mcap"
    p.write_bytes(craft(_states(200), chunks=4))
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


# --------------------------------------------------------------------------------------
# layout -o, another run's journal, text streams, flags
# --------------------------------------------------------------------------------------


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


def _run(path: Path, rid: str, k: int) -> None:
    with RunLogger(arm_info(N_SEG), path, flush_interval=0.05, quiet=True, recording_id=rid) as log:
        for r in arm_records(k, dt=1e-2, n=N_SEG, P=POINTS):
            log.log(r)


def _journal_of(path: Path, rec, rid: str | None, keep: int) -> None:
    """A killed run's journal beside ``path``: ``rec``'s first ``keep`` records, under ``rid``."""
    from qchain.recording.journal import JournalWriter
    from qchain.recording.records import Batch

    meta = info_metadata(arm_info(N_SEG), rid or "x")
    if rid is None:  # an older journal: no recording_id in its header
        del meta["recording_id"]
    b = Batch(rec.t, rec.step, rec.q, rec.v, rec.p, rec.energy, rec.base, rec.backbone, rec.tip_frames)
    jw = JournalWriter(journal_path(path), meta, str(path))
    jw.start(b.layout)
    jw.append(b.rows()[:keep])
    jw.release(remove=False)  # killed: no outcome, no summary


def test_another_run_s_journal_is_never_merged(tmp_path, capsys):
    """Before: another killed run's journal copied beside a complete recording was merged
    by read_recording, replay and recover (6 records read back as 224, and recover replaced
    the complete file with steps of both runs). Now: the journal names its run's
    recording_id; one of another run is not merged (journal_unread says so) and recover
    changes nothing."""
    base, other = tmp_path / "base.mcap", tmp_path / "other.mcap"
    _run(base, "run-a", 6)
    _run(other, "run-b", 40)
    orec = read_recording(other)
    _journal_of(base, orec, "run-b", 40)
    before = base.read_bytes()
    rec = read_recording(base)
    assert len(rec) == 6 and rec.recovered == 0 and rec.complete
    assert "another run's" in rec.journal_unread and "run-b" in rec.journal_unread
    assert len(read_mcap(base).t) == 6
    assert recover_main([str(base)]) == 2
    err = capsys.readouterr().err
    assert "another run's" in err and err.count("\n") == 1, err
    assert base.read_bytes() == before and journal_path(base).exists()
    # the same beside a killed (truncated) file of run-a: still not merged
    _killed(base, before, 1)
    rec = read_recording(base)
    assert rec.recovered == 0 and "another run's" in rec.journal_unread
    assert set(rec.step.tolist()) <= set(read_recording(io.BytesIO(before)).step.tolist())


def test_a_journal_without_id_is_merged_only_into_a_truncated_file(tmp_path):
    """An older journal (no recording_id): beside a complete file its records are not
    merged (said); beside a truncated file they are, as before."""
    base = tmp_path / "base.mcap"
    _run(base, "run-a", 6)
    whole = base.read_bytes()
    big = tmp_path / "big.mcap"
    _run(big, "run-a", 40)
    brec = read_recording(big)
    _journal_of(base, brec, None, 40)
    rec = read_recording(base)
    assert len(rec) == 6 and rec.recovered == 0 and "complete" in rec.journal_unread
    _killed(base, whole, 1)
    rec = read_recording(base)
    assert rec.recovered > 0 and not rec.journal_unread
    # the same run's own journal beside its complete file, nothing more in it: silent
    base.write_bytes(whole)
    _journal_of(base, read_recording(io.BytesIO(whole)), "run-a", 6)
    rec = read_recording(base)
    assert len(rec) == 6 and rec.complete and not rec.journal_unread


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
    assert len(read_recording(p, journal=False)) == N
