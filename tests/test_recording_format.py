"""A recording's content against its format: crafted state messages, channels and metadata that the
format does not allow are refused naming the file, never used."""

import io
import json

import numpy as np
import pytest
from mcap.records import Channel
from mcap.writer import CompressionType, Writer

from logging_fixtures import arm_info
from qchain.cli.recording import replay_main
from qchain.logging import TOPICS, LoggingWarning, RecordingFormatError, read_mcap, read_recording, replay
from qchain.recording.mcap_sink import info_metadata
from qchain.recording.records import seal
from qchain.recording.scan import scan
from support import (
    N_SEG,
    assert_valid,
    craft,
    craft_chunks,
    good_states,
    info_json,
    refused_recording,
    state_dicts,
    write,
)


def test_a_channel_declared_twice_keeps_its_first_declaration(tmp_path):
    """The state channel's id declared again as another topic: before, every state message
    was dropped silently (0 records, complete). Now the first declaration holds and the
    second is reported."""
    def redeclare(w, cid):
        w._Writer__chunk_builder.add_channel(Channel(id=cid, schema_id=1, topic=TOPICS["tf"],
                                                     message_encoding="protobuf", metadata={}))

    p = tmp_path / "twice.mcap"
    p.write_bytes(craft_chunks(before=redeclare))
    rec = read_recording(p)
    assert len(rec) == 6
    assert any(f"declares channel 1 again as '{TOPICS['tf']}'" in d for d in rec.damage), rec.damage


def test_messages_on_a_channel_never_declared_are_said(tmp_path):
    states = state_dicts(6)
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


def test_a_duration_past_the_recordable_range_is_refused_not_a_crash(tmp_path, capsys):
    """RunInfo.duration 1e308 (finite): before, the replay crashed in Rerun's time
    conversion (OverflowError, exit code 1). Now RunInfo refuses it, writing and reading."""
    info = json.loads(json.dumps(arm_info(N_SEG).to_json()))
    info["duration"] = 1e308
    p = tmp_path / "long.mcap"
    p.write_bytes(craft_chunks(info=info))
    with pytest.raises(RecordingFormatError, match="duration must be None or a time > 0 s and <= 4294967295 s"):
        read_recording(p)
    assert replay_main([str(p), "--rrd", str(tmp_path / "o.rrd")]) == 2
    assert "Traceback" not in capsys.readouterr().err
    with pytest.raises(ValueError, match="duration"):
        arm_info(N_SEG, duration=1e10)


def test_a_crafted_recording_reads_back(tmp_path):
    """The crafting above makes a recording the reader takes (so the refusals below are
    about what was changed)."""
    states = good_states()
    rec = read_recording(write(tmp_path, craft(states)))
    assert len(rec) == 6 and rec.complete and not rec.damage and not rec.nonfinite
    np.testing.assert_array_equal(rec.q, [s["q"] for s in states])
    assert_valid(rec)


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
    refused_recording(write(tmp_path, craft(states)), match)


def test_more_series_than_the_segments_have_are_refused(tmp_path):
    """q, v or p longer than 3 n + 7 (n segments and a floating base) in every record: a
    recording of 2 segments cannot have 100 coordinates (nor a layout and plots of them)."""
    for key in ("q", "v", "p"):
        states = good_states()
        for s in states:
            s[key] = list(range(100))
        refused_recording(write(tmp_path, craft(states), f"{key}.mcap"), f"{key} has 100 entries; 2 segment(s) have at most 13")


def test_a_state_with_other_fields_is_refused(tmp_path):
    states = good_states()
    states[1]["extra"] = 1.0
    refused_recording(write(tmp_path, craft(states), "extra.mcap"), "expected the fields")
    states = good_states()
    del states[4]["v"]
    refused_recording(write(tmp_path, craft(states), "missing.mcap"), "expected the fields")
    refused_recording(write(tmp_path, craft([b"[1, 2, 3]"]), "list.mcap"), "found a JSON list")


def test_shapes_that_change_between_records_are_refused(tmp_path):
    states = good_states(8)
    states[7]["q"] = states[7]["q"][:-1]  # the last record, in the second chunk
    err = refused_recording(write(tmp_path, craft(states)), "q has the shape (5,), the others (6,)")
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
            refused_recording(p, match)


def test_an_outcome_of_the_wrong_kind_is_reported_not_used(tmp_path):
    for k, bad in enumerate([{"success": "maybe"}, {"success": "true", "status": "abc"},
                             {"success": "false", "nfev": "1" * 5000}, {"success": "true", "last_t": "nan"}]):
        rec = read_recording(write(tmp_path, craft(outcome=bad), f"o{k}.mcap"))
        assert rec.outcome is None and any("qchain.outcome" in d and "not usable" in d for d in rec.damage)
        traj = rec.to_trajectory()
        assert traj.success is False and len(traj.t) == 6
