"""``recover`` and the journal a killed run leaves: what the file lost is filled from the journal,
a journal that cannot be read or is not the file's own is never merged nor deleted, links and
modes are kept."""

import io
import json
import os
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import CompressionType, Writer

from helpers import deadline
from logging_fixtures import arm_info, arm_records
from qchain.cli.recording import recover_main
from qchain.logging import LoggingError, RunLogger, check_outputs, read_mcap, read_recording, recover
from qchain.recording.journal import JournalReader, JournalWriter, journal_path
from qchain.recording.mcap_sink import info_metadata
from qchain.recording.records import seal
from qchain.recording.scan import scan
from support import N_SEG, N_WHOLE, POINTS, assert_valid, craft, good_states, refused_recording, write_journal


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
    write_journal(path, rows, layout, meta)
    rec = read_recording(path)
    np.testing.assert_array_equal(rec.step, np.arange(N_WHOLE))
    np.testing.assert_array_equal(rec.t, rows[:, 0])
    assert not rec.gaps and rec.recovered > 0
    assert any("its records read from the run's journal" in d for d in rec.damage), rec.damage
    recover(path)
    again = read_recording(path)
    assert len(again) == N_WHOLE and not again.gaps and not again.truncated
    assert not journal_path(path).exists()


def test_a_damaged_journal_is_read_as_far_as_it_goes_and_never_deleted(whole, tmp_path):
    """Its first chunk (the rows channel's declaration) damaged: its later chunks read by
    the layout sealed outside the chunks; recover refuses and leaves both files as they
    were (the journal once went with the damaged chunk's rows and every later one)."""
    data, rows, layout, meta = whole
    path = tmp_path / "run.mcap"
    path.write_bytes(_killed(data)[: len(data) // 2])
    write_journal(path, rows, layout, meta)
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
    assert rec.step[-1] == N_WHOLE - 1 and rec.journal_unread
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
    assert len(rec) == N_WHOLE and "symbolic links" in rec.journal_unread


def test_a_bad_journal_row_leaves_the_files_own_records_readable(whole, tmp_path):
    data, rows, layout, meta = whole
    path = tmp_path / "run.mcap"
    path.write_bytes(_killed(data)[: len(data) // 2])
    bad = rows.copy()
    bad[N_WHOLE // 2 + 1, 0] = np.nan  # inside a block (its first and last times are the chunk's)
    write_journal(path, bad, layout, meta)
    rec = read_recording(path)
    assert len(rec) > 0 and "has the time nan (expected" in rec.journal_unread, rec.journal_unread
    with pytest.raises(LoggingError):
        recover(path)
    assert journal_path(path).exists()


def test_recover_through_a_link_replaces_the_file_it_names(whole, tmp_path):
    """The link was replaced by a regular file, the file it named left truncated."""
    data, rows, layout, meta = whole
    real = tmp_path / "real"
    real.mkdir()
    target = real / "run.mcap"
    target.write_bytes(_killed(data)[: len(data) // 2])
    link = tmp_path / "run.mcap"
    link.symlink_to(target)
    write_journal(link, rows, layout, meta)
    recover(link)
    assert link.is_symlink() and os.readlink(link) == str(target)
    rec = read_recording(target)
    assert len(rec) == N_WHOLE and not rec.truncated


def test_recover_refuses_a_link_to_its_own_journal_or_to_a_file_with_a_journal(whole, tmp_path):
    """A link to its own journal: recover wrote the journal over itself, then deleted it (every
    record lost). A link to a killed run's file: the journal beside that file was ignored."""
    data, rows, layout, meta = whole
    a = tmp_path / "a"
    a.mkdir()
    path = a / "r.mcap"
    write_journal(path, rows, layout, meta)
    path.symlink_to(journal_path(path).name)
    before = journal_path(path).read_bytes()
    with pytest.raises(LoggingError, match="is a link to its own journal"):
        recover(path)
    assert journal_path(path).read_bytes() == before
    b = tmp_path / "b"
    b.mkdir()
    target = b / "s.mcap"
    target.write_bytes(_killed(data)[: len(data) // 2])
    write_journal(target, rows, layout, meta)
    link = b / "r.mcap"
    link.symlink_to(target.name)
    with pytest.raises(LoggingError, match=r"has a journal of its own .* recover .*s\.mcap"):
        recover(link)
    from qchain.logging import check_outputs

    with pytest.raises(LoggingError, match=r"s\.mcap\.journal holds the records of a run that was killed"):
        check_outputs(link)  # a run through the link would write over that file
    recover(target)
    assert len(read_recording(target)) == N_WHOLE


def test_journal_rows_with_no_place_keep_the_journal(whole, tmp_path):
    """Rows after the file's last step but before its last time were dropped without a word,
    and recover then deleted the journal that held them."""
    data, rows, layout, meta = whole
    path = tmp_path / "run.mcap"
    path.write_bytes(_killed(data)[: len(data) // 2])
    k = len(read_recording(path, journal=False))
    odd = rows.copy()
    odd[k:, 0] -= 0.05
    write_journal(path, odd, layout, meta)
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
    write_journal(path, rows, layout, meta)
    recover(path)
    assert (path.stat().st_mode & 0o777) == 0o644


def test_recover_leaves_a_complete_recording_as_it_is(whole, tmp_path, capsys):
    from qchain.cli.recording import recover_main

    data, _, _, _ = whole
    path = tmp_path / "run.mcap"
    path.write_bytes(data)
    assert recover_main([str(path)]) == 0
    assert "nothing to recover" in capsys.readouterr().out and path.read_bytes() == data


def _killed_at(path: Path, data: bytes, keep_chunks: int) -> int:
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
        _killed_at(p, data, 4)
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
    _killed_at(p, data, 3)
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
    _killed_at(base, before, 1)
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
    _killed_at(base, whole, 1)
    rec = read_recording(base)
    assert rec.recovered > 0 and not rec.journal_unread
    # the same run's own journal beside its complete file, nothing more in it: silent
    base.write_bytes(whole)
    _journal_of(base, read_recording(io.BytesIO(whole)), "run-a", 6)
    rec = read_recording(base)
    assert len(rec) == 6 and rec.complete and not rec.journal_unread


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
    _crafted_journal(path, rows, layout)
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


def _crafted_journal(path: Path, rows: np.ndarray, layout: dict, meta: dict | None = None) -> None:
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
    _crafted_journal(path, rows, layout)
    rec = read_recording(path)
    assert len(rec) == 5 and rec.recovered == 5
    assert_valid(rec)
    for k, (col, value) in enumerate([(0, np.nan), (0, 1e30), (1, 2.5), (1, -1.0), (1, np.inf)]):
        bad = rows.copy()
        bad[2, col] = value
        _crafted_journal(path, bad, layout)
        err = refused_recording(path, "journal")
        assert str(journal_path(path)) in str(err) and ("time" in str(err) or "step" in str(err))


def test_a_journal_with_a_bad_layout_is_reported_not_a_crash(tmp_path):
    path = tmp_path / "killed.mcap"
    path.write_bytes(craft())
    rows, layout = _rows(3, t0=1.0, step0=100)
    for k, lay in enumerate([{**layout, "nq": "six"}, {**layout, "P": 0}, {**layout, "n": 2**30},
                             {**layout, "nq": layout["nq"] + 1}, [1, 2]]):
        _crafted_journal(path, rows, lay)
        rec = read_recording(path)  # the file's records; the journal's rows not used
        assert len(rec) == 6 and rec.recovered == 0
        assert any(d.startswith("journal:") for d in rec.damage), rec.damage
    from qchain.recording.records import RecordLayout

    other = RecordLayout(9, 9, 9, 3, POINTS)  # whole rows of another arm: refused, named
    rows3 = np.zeros((3, other.row_width))
    rows3[:, 0], rows3[:, 1] = [1.0, 1.1, 1.2], [100, 101, 102]
    _crafted_journal(path, rows3, other.to_json())
    rec = read_recording(path)  # the file's own records read; the journal said, kept, not merged
    assert len(rec) == 6 and rec.recovered == 0
    assert "rows are of 3 segment(s), the recording's 2: not merged" in rec.journal_unread
    assert any("rows are of 3 segment(s)" in d for d in rec.damage)
    with pytest.raises(LoggingError, match="cannot be \\(wholly\\) merged"):
        recover(path)
    assert journal_path(path).exists()
    _crafted_journal(path, rows, layout)
    rec = read_recording(path)  # a complete file (outcome, summary): never merged, said
    assert len(rec) == 6 and rec.recovered == 0 and "complete" in rec.journal_unread
    from qchain.recording.scan import scan

    whole = craft()
    path.write_bytes(whole[: [it.end for it in scan(whole) if it.kind == "chunk"][-1]])  # killed: no outcome
    rec = read_recording(path)
    assert len(rec) == 9 and rec.recovered == 3
    path.write_bytes(b"")
    journal_path(path).write_bytes(b"not a journal at all")
    refused_recording(path, "no recording file, and its journal")


def test_recover_refuses_arguments_of_the_wrong_type(tmp_path):
    for bad in (None, 123, 1.5, [str(tmp_path)]):
        with pytest.raises(TypeError, match="recover: path must be a path"):
            recover(bad)
