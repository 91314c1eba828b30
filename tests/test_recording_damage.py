"""Damaged recordings: a flipped bit loses at most its own chunk, and damaged metadata is
reported, never used; a cut, a missing or a reordered chunk is a gap that is said, and mutated
recordings read well or are refused in bounded time."""

from __future__ import annotations

import io
import json
import struct
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from helpers import deadline
from logging_fixtures import arm_info, arm_records
from qchain.cli.recording import replay_main
from qchain.logging import LoggingWarning, RecordingFormatError, RunLogger, read_mcap, read_recording, replay
from qchain.recording.scan import scan
from support import (
    N_LOGGED,
    N_SEG,
    N_WHOLE,
    POINTS,
    assert_valid,
    craft,
    craft_chunks,
    good_states,
    info_json,
    write,
    write_journal,
)

N = 600


@pytest.fixture(scope="module")
def clean():
    """A recording of N records in about 12 chunks, and where its records are."""
    records = arm_records(N, dt=1e-3)
    buf = io.BytesIO()
    with RunLogger(arm_info(), buf, flush_interval=0.05, quiet=True) as log:
        for r in records:
            log.log(r)
    data = buf.getvalue()
    chunks, metas = [], []
    first = 0
    for item in scan(data):
        if item.kind == "chunk":
            k = sum(1 for r in item.records if type(r).__name__ == "Message" and r.channel_id == 1)
            chunks.append((item.offset, item.end, first, first + k))
            first += k
        elif item.kind == "metadata":
            metas.append((item.offset, item.end, item.record.name))
    assert first == N and len(chunks) >= 10
    t = np.array([r.t for r in records])
    q = np.array([r.q for r in records])
    return data, chunks, metas, t, q


def _flip(data: bytes, pos: int, bit: int) -> bytes:
    b = bytearray(data)
    b[pos] ^= 1 << bit
    return bytes(b)


@pytest.mark.slow
def test_a_flipped_bit_in_a_chunk_loses_only_that_chunk(clean):
    """90 single-bit flips at random places inside chunks: each recording reads; every
    record outside the damaged chunk is there, equal to what was logged; the records lost are
    those of that chunk at most, and the gap names the time range around them."""
    data, chunks, _, t, q = clean
    rng = np.random.default_rng(17)
    lost_only_itself = 0
    for _ in range(90):
        c = int(rng.integers(len(chunks)))
        a, b, first, last = chunks[c]
        pos = int(rng.integers(a, b))
        rec = read_recording(io.BytesIO(_flip(data, pos, int(rng.integers(8)))))
        idx = np.searchsorted(t, rec.t)
        np.testing.assert_array_equal(rec.t, t[idx])
        np.testing.assert_array_equal(rec.q, q[idx])
        missing = sorted(set(range(N)) - set(idx.tolist()))
        assert set(missing) <= set(range(first, last)), (pos, missing[:3])
        if missing:
            assert missing == list(range(first, last))  # the whole chunk, nothing else
            (gap,) = rec.gaps
            assert gap.after_t == (t[first - 1] if first else None) and gap.before_t == (t[last] if last < N else None)
            assert rec.to_trajectory().success is False and "are missing" in rec.to_trajectory().message
        else:  # a bit the CRC does not cover and the reading does not need (a chunk's time fields)
            assert not rec.gaps
        lost_only_itself += 1
    assert lost_only_itself == 90


@pytest.mark.slow
def test_flips_outside_the_chunks_lose_nothing(clean):
    """Flips in the header, metadata, message indexes, summary and footer: every record
    still reads; a damaged qchain metadata record is reported (its CRC32 seal fails) and
    its intact second copy is used; a damaged outcome is reported and not used."""
    data, chunks, metas, t, q = clean
    inside = np.zeros(len(data), dtype=bool)
    for a, b, _, _ in chunks:
        inside[a:b] = True
    outside = np.flatnonzero(~inside[8:]) + 8
    rng = np.random.default_rng(18)
    for pos in rng.choice(outside, 60, replace=False).tolist():
        flipped = _flip(data, pos, int(rng.integers(8)))
        rec = read_recording(io.BytesIO(flipped))
        np.testing.assert_array_equal(rec.t, t)
        np.testing.assert_array_equal(rec.q, q)
        assert not rec.gaps
        assert rec.info == arm_info()
        for a, b, name in metas:
            if a <= pos < b:
                assert rec.damage, (pos, name)
                if name == "qchain.outcome":
                    assert rec.outcome is None
    # the first qchain metadata copy damaged: reported, the second copy is used
    a, b, name = metas[0]
    assert name == "qchain"
    scene_at = data.index(b"synthetic", a)  # inside the scene text
    rec = read_recording(io.BytesIO(_flip(data, scene_at, 0)))
    assert rec.info.scene == arm_info().scene and any("fails its checksum" in d for d in rec.damage)


@pytest.mark.slow
def test_a_damaged_length_outside_the_chunks_never_swallows_a_chunk(clean):
    """Four bits of the length of every record between the chunks (the header, the metadata,
    the message indexes, the data end), flipped: a length grown past its record
    once skipped the chunk after it unread (a third of a recording lost to one bit); now a
    skipped record must end where another starts, else the reading resynchronises after it."""
    from qchain.recording.scan import MAGIC

    data, chunks, _, t, q = clean
    inside = np.zeros(len(data), dtype=bool)
    for a, b, _, _ in chunks:
        inside[a:b] = True
    between = []
    for item in scan(data):
        if not inside[item.offset] and item.kind != "footer":
            between.append(item.offset)  # up to the data end (the summary is read by its CRC)
    assert len(between) >= 10 and between[0] == len(MAGIC)
    flips = 0
    for pos in between:
        for bit in (3, 12, 20, 33):  # lengths grown by 8 B, 4 KiB (a chunk's size), 1 MiB, 8 GiB
            rec = read_recording(io.BytesIO(_flip(data, pos + 1 + bit // 8, bit % 8)))
            np.testing.assert_array_equal(rec.t, t, err_msg=f"length of the record at byte {pos}, bit {bit}")
            np.testing.assert_array_equal(rec.q, q)
            assert not rec.gaps
            flips += 1
    assert flips == 4 * len(between)


def test_damaged_metadata_is_never_used_silently(clean):
    """Both copies of the qchain metadata damaged: a clear error, not a recording whose scene
    or radii changed without a word."""
    data, _, metas, _, _ = clean
    copies = [(a, b) for a, b, name in metas if name == "qchain"]
    assert len(copies) == 2
    flipped = data
    for a, b in copies:
        flipped = _flip(flipped, flipped.index(b"radii", a), 2)
    with pytest.raises(RecordingFormatError, match="qchain metadata record is damaged"):
        read_recording(io.BytesIO(flipped))


@pytest.mark.slow
def test_a_flipped_bit_in_a_chunk_size_field_loses_nothing(clean):
    """Flips in each chunk's declared uncompressed size (a little larger, much larger, beyond
    any reading budget): the size is not trusted, the data decompress within the budget
    and match the chunk's CRC, so every record reads back equal; the damaged field is
    reported, and the file is never refused as a decompression bomb."""
    import struct

    data, chunks, _, t, q = clean
    for a, _, _, _ in chunks[::3]:
        for bit in (3, 40, 62):
            pos = a + 9 + 16 + bit // 8  # the uncompressed size field (after start and end times)
            flipped = _flip(data, pos, bit % 8)
            assert struct.unpack_from("<Q", flipped, a + 25)[0] != struct.unpack_from("<Q", data, a + 25)[0]
            rec = read_recording(io.BytesIO(flipped))
            np.testing.assert_array_equal(rec.t, t)
            np.testing.assert_array_equal(rec.q, q)
            assert not rec.gaps
            assert [d for d in rec.damage if "declares" in d] == \
                [f"the chunk at byte {a} declares {struct.unpack_from('<Q', flipped, a + 25)[0]} bytes uncompressed, "
                 f"its data are {struct.unpack_from('<Q', data, a + 25)[0]} (they match its CRC: read, nothing lost)"]


def test_the_search_past_damage_is_linear(clean):
    """4 MB of bytes that each look like the start of a chunk record, after a damaged one:
    the search for the next trusted record examines each once (it took 66 s, quadratic in
    the damaged bytes, before); every record reads."""
    import time

    data, chunks, _, t, q = clean
    at = chunks[1][0]
    junk = (b"\x06\x05" + bytes(7)) * ((4 << 20) // 9)
    t0 = time.monotonic()
    rec = read_recording(io.BytesIO(data[:at] + junk + data[at:]))
    assert time.monotonic() - t0 < 10.0
    np.testing.assert_array_equal(rec.t, t)
    np.testing.assert_array_equal(rec.q, q)
    assert any(f"byte {at}" in d for d in rec.damage)


# --------------------------------------------------------------------------------------
# Hostile input (issue 18): what once ended in a foreign traceback, a hang, a crash, a silent
# NaN or lost data, kept fixed.

@pytest.mark.parametrize("cut_into", [9, 100, 1000, 5000])
def test_a_file_cut_inside_its_first_chunk_keeps_its_metadata(whole, tmp_path, cut_into):
    """A record skipped by its length must end where another starts, or fill its own
    fields exactly: a cut chunk after the metadata is the file's end, not damage of the
    metadata (whose loss would refuse the whole file)."""
    data, rows, layout, meta = whole
    first = next(it for it in scan(data) if it.kind == "chunk")
    path = tmp_path / "run.mcap"
    path.write_bytes(data[: first.offset + cut_into])
    write_journal(path, rows, layout, meta)
    rec = read_recording(path)
    assert len(rec) == N_WHOLE and not any("metadata" in d for d in rec.damage), rec.damage


def _said(rec) -> bool:
    """The reading says something is missing."""
    return bool(rec.gaps or rec.truncated) and not rec.complete and not rec.to_trajectory().success


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
    assert len(rec) == N_LOGGED - n
    assert _said(rec), (rec.gaps, rec.truncated, rec.damage)
    assert f"counts {N_LOGGED} records, {N_LOGGED - n} were read: {n} missing" in rec.to_trajectory().message


def test_an_outcome_counting_more_records_than_the_file_holds_is_a_gap(tmp_path, capsys):
    p = tmp_path / "short.mcap"
    p.write_bytes(craft_chunks(outcome={"success": "true", "status": "0", "message": "ok", "n_records": "1000"}))
    rec = read_recording(p)
    assert len(rec) == 6 and rec.gaps and not rec.complete
    assert "counts 1000 records, 6 were read: 994 missing" in rec.gaps[0].reason
    assert replay_main([str(p), "--rrd", str(tmp_path / "o.rrd")]) == 0
    assert "994 missing" in capsys.readouterr().out
    # the count of a file that holds all its records says nothing
    p.write_bytes(craft_chunks())
    assert read_recording(p).complete


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
    assert len(rec) >= N_LOGGED and np.any(np.diff(rec.t) < 0)
    assert rec.disorder.startswith("records out of order: ")
    assert rec.disorder in read_mcap(p).message
    with pytest.warns(LoggingWarning, match="records out of order"):
        replay(p, rrd=tmp_path / "o.rrd")
    assert replay_main([str(p), "--rrd", str(tmp_path / "o2.rrd")]) == 0
    assert "records out of order" in capsys.readouterr().out
    assert read_recording(io.BytesIO(data)).disorder == ""


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
    assert len(rec) >= N_LOGGED - lost
    if len(rec) < N_LOGGED:
        assert _said(rec) or rec.damage, (rec.gaps, rec.truncated, rec.damage)


def test_an_intact_chunk_with_a_wrong_size_field_loses_nothing(tmp_path):
    """A chunk whose data match its CRC but not its declared size: read, the size reported."""
    body = craft()
    item = next(it for it in scan(body) if it.kind == "chunk")
    size_at = item.offset + 9 + 16
    bad = body[:size_at] + struct.pack("<Q", 7) + body[size_at + 8:]
    rec = read_recording(write(tmp_path, bad))
    assert len(rec) == 6 and not rec.gaps
    assert any(f"the chunk at byte {item.offset} declares 7 bytes" in d for d in rec.damage)


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


@pytest.mark.slow
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
