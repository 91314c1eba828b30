"""qchain.logging: MCAP and Rerun recording of a run, replay, crash safety, loopback serving."""

from __future__ import annotations

import argparse
import io
import json
import os
import signal
import subprocess
import sys
import time
import urllib.request
import warnings
from pathlib import Path

import numpy as np
import pytest
from logging_fixtures import arm_info, arm_record, arm_records
from mcap.reader import make_reader
from mcap.writer import Writer

import qchain
from qchain.logging import (
    DEFAULT_FLUSH_INTERVAL, TOPICS, LoggingError, LoggingWarning, RecordingFormatError, RecordLayout, RunInfo,
    RunLogger, StepRecord, default_mcap_path, prepare_writer, read_mcap, read_recording, replay)
from qchain.cli.recording import add_logging_arguments, logger_from_args, replay_main
from qchain.sim.trajectory import Trajectory

TESTS = Path(__file__).resolve().parent


def _stack(records, field):
    return np.array([getattr(r, field) for r in records])


def _assert_records_equal(rec, records):
    """Every field of the read recording equals the logged records, bit for bit (NaN = NaN)."""
    assert len(rec) == len(records)
    if not records:
        return
    np.testing.assert_array_equal(rec.t, _stack(records, "t"))
    np.testing.assert_array_equal(rec.step, _stack(records, "step"))
    for f in ("q", "v", "p", "backbone", "tip_frames"):
        np.testing.assert_array_equal(getattr(rec, f), _stack(records, f), err_msg=f)
    np.testing.assert_array_equal(rec.energy[:, 0], _stack(records, "kinetic"))
    np.testing.assert_array_equal(rec.energy[:, 1], _stack(records, "potential"))
    np.testing.assert_array_equal(rec.energy[:, 2], _stack(records, "total"))


def _check_json_schema(value, schema, path="$"):
    """A small JSON-schema check (type, properties, required, items): enough to show each
    message has the documented form of its schema. A number may be null (how a non-finite
    value is written)."""
    t = schema.get("type")
    if t is not None:
        kinds = {"object": dict, "array": list, "string": str, "boolean": bool, "integer": int, "number": (int, float)}
        ok = isinstance(value, kinds[t]) and not (t in ("integer", "number") and isinstance(value, bool))
        assert ok or (t == "number" and value is None), f"{path}: {value!r} is not of type {t}"
    if isinstance(value, dict):
        for key in schema.get("required", []):
            assert key in value, f"{path}: required key {key!r} missing"
        for key, sub in schema.get("properties", {}).items():
            if key in value:
                _check_json_schema(value[key], sub, f"{path}.{key}")
    if isinstance(value, list) and "items" in schema:
        for i, item in enumerate(value):
            _check_json_schema(item, schema["items"], f"{path}[{i}]")


def _check_foxglove_readable(schema, path="$"):
    """The constraints of Foxglove's JSON-schema reader: every object has "properties", every
    "type" is one string of object/array/string/number/integer/boolean, arrays say their items."""
    assert isinstance(schema.get("type"), str), f"{path}: type must be a single string"
    assert schema["type"] in ("object", "array", "string", "number", "integer", "boolean"), path
    if schema["type"] == "object":
        assert isinstance(schema.get("properties"), dict), f"{path}: an object needs properties"
        for key, sub in schema["properties"].items():
            _check_foxglove_readable(sub, f"{path}.{key}")
    if schema["type"] == "array":
        _check_foxglove_readable(schema["items"], f"{path}[]")


def _log_all(records, info=None, mcap=None, **kw):
    with RunLogger(info or arm_info(), mcap, quiet=True, **kw) as log:
        for r in records:
            log.log(r)
    return log


# --------------------------------------------------------------------------------------
# MCAP round trip
# --------------------------------------------------------------------------------------


def test_mcap_round_trip_in_memory_is_exact():
    records = arm_records(300, dt=1e-3)
    records[7].v[2] = np.nan  # a non-finite value travels as JSON null and comes back NaN
    records[8].p[0] = np.inf  # ... every non-finite value comes back as NaN
    base = 2**32 - 150  # step numbers past the MCAP sequence range wrap there, not in the data
    for r in records:
        r.step += base
    info = arm_info()
    buf = io.BytesIO()
    summary = _log_all(records, info, buf).close()
    assert summary["n_records"] == 300 and summary["last_t"] == records[-1].t

    buf.seek(0)
    rec = read_recording(buf)
    records[8].p[0] = np.nan
    _assert_records_equal(rec, records)
    assert not rec.truncated and rec.stop_reason == "" and rec.gaps == [] and rec.damage == []
    assert rec.outcome["success"] == "true" and rec.outcome["message"] == "finished"
    assert rec.outcome["n_records"] == "300"
    # metadata: scene, model parameters, qchain version, segment radii
    assert rec.info.scene == info.scene and rec.info.params == info.params
    assert rec.info.qchain_version == qchain.__version__
    assert rec.info.radii == info.radii and rec.info.n_segments == 3
    assert rec.metadata["scene"] == info.scene
    assert json.loads(rec.metadata["params"]) == info.params

    # the file as the mcap package sees it: summary, counts, times, sequences, schemas
    buf.seek(0)
    reader = make_reader(buf)
    stats = reader.get_summary().statistics
    assert stats.message_count == 4 * 300
    assert sorted(stats.channel_message_counts.values()) == [300] * 4
    topics = {ch.topic: ch for ch in reader.get_summary().channels.values()}
    assert set(topics) == set(TOPICS.values())
    assert stats.message_start_time == round(records[0].t * 1e9) and stats.message_end_time == round(records[-1].t * 1e9)
    schema_names = {s.name for s in reader.get_summary().schemas.values()}
    assert schema_names == {"qchain.State", "foxglove.FrameTransforms", "foxglove.SceneUpdate", "foxglove.PointCloud"}
    seen = {k: 0 for k in TOPICS.values()}
    for schema, channel, msg in reader.iter_messages():
        k = seen[channel.topic]
        r = records[k]
        assert msg.log_time == msg.publish_time == round(r.t * 1e9)
        assert msg.sequence == r.step & 0xFFFFFFFF
        if channel.topic == TOPICS["state"]:
            assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
            if k in (0, 7, 8, 299):
                _check_json_schema(json.loads(msg.data), json.loads(schema.data))
            if k == 0:
                _check_foxglove_readable(json.loads(schema.data))
        else:
            assert schema.encoding == "protobuf" and channel.message_encoding == "protobuf"
        seen[channel.topic] += 1
    assert set(seen.values()) == {300}
    assert [m.name for m in reader.iter_metadata()] == ["qchain", "qchain.outcome", "qchain"]


def test_foxglove_messages_follow_the_official_schemas():
    """The Foxglove channels decode with the published schemas (foxglove-schemas-protobuf),
    independently of the descriptors the file carries: the frame tree is world -> base ->
    segment_1_tip -> ..., its transforms composed give each tip's world placement, the
    backbone is one line strip a segment (thickness = diameter) and a point cloud."""
    from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    from qchain.recording.rerun_sink import _quat_rot

    records = arm_records(20, dt=1e-2)
    for k, r in enumerate(records):  # a base that moves and turns
        ang = 0.3 * k
        r.base_frame = np.array([0.01 * k, 0.0, 0.5, np.sin(ang / 2), 0.0, 0.0, np.cos(ang / 2)])
    buf = io.BytesIO()
    _log_all(records, mcap=buf)
    buf.seek(0)
    decoders = {TOPICS["tf"]: FrameTransforms, TOPICS["arm"]: SceneUpdate, TOPICS["points"]: PointCloud}
    got = {t: [] for t in decoders}
    reader = make_reader(buf)
    for schema, channel, msg in reader.iter_messages():
        if channel.topic in decoders:
            assert schema.name == "foxglove." + decoders[channel.topic].__name__
            m = decoders[channel.topic]()
            m.ParseFromString(msg.data)
            got[channel.topic].append(m)
    radius = arm_info().radii[0]
    for k, r in enumerate(records):
        tf = got[TOPICS["tf"]][k]
        chain = [(t.parent_frame_id, t.child_frame_id) for t in tf.transforms]
        assert chain == [("world", "base"), ("base", "segment_1_tip"), ("segment_1_tip", "segment_2_tip"),
                         ("segment_2_tip", "segment_3_tip")]
        assert all(t.timestamp.seconds * 10**9 + t.timestamp.nanos == round(r.t * 1e9) for t in tf.transforms)
        R, o = np.eye(3), np.zeros(3)  # compose parent -> child down the tree
        world = []
        for t in tf.transforms:
            q = np.array([t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w])
            o = o + R @ np.array([t.translation.x, t.translation.y, t.translation.z])
            R = R @ _quat_rot(q)
            world.append((o.copy(), R.copy()))
        np.testing.assert_allclose(world[0][0], r.base_frame[:3], atol=1e-12)
        np.testing.assert_allclose(world[0][1], _quat_rot(r.base_frame[3:]), atol=1e-12)
        for i in range(3):
            np.testing.assert_allclose(world[i + 1][0], r.tip_frames[i, :3], atol=1e-12)
            np.testing.assert_allclose(world[i + 1][1], _quat_rot(r.tip_frames[i, 3:]), atol=1e-12)
        arm = got[TOPICS["arm"]][k]
        assert [e.id for e in arm.entities] == ["segment_1", "segment_2", "segment_3"]
        for i, e in enumerate(arm.entities):
            assert e.frame_id == "world" and len(e.lines) == 1
            line = e.lines[0]
            assert line.type == 0 and line.thickness == pytest.approx(2 * radius)  # LINE_STRIP
            np.testing.assert_array_equal([(p.x, p.y, p.z) for p in line.points], r.backbone[i])
        pc = got[TOPICS["points"]][k]
        assert [f.name for f in pc.fields] == ["x", "y", "z"] and pc.point_stride == 24 and pc.frame_id == "world"
        np.testing.assert_array_equal(np.frombuffer(pc.data, dtype="<f8").reshape(-1, 3), r.backbone.reshape(-1, 3))


def test_mcap_round_trip_through_writer_process(tmp_path):
    records = arm_records(400, dt=2e-3)
    path = tmp_path / "deep" / "run.mcap"
    log = _log_all(records, mcap=path)
    assert log.worker == "process" and log.worker_pid is not None
    rec = read_recording(path)
    _assert_records_equal(rec, records)
    assert not rec.truncated
    traj = read_mcap(path)
    assert isinstance(traj, Trajectory)
    assert traj.success and traj.status == 0 and traj.message == "finished"
    np.testing.assert_array_equal(traj.t, rec.t)
    np.testing.assert_array_equal(traj.q, rec.q)
    np.testing.assert_array_equal(traj.total_energy, rec.energy[:, 0] + rec.energy[:, 1])
    np.testing.assert_array_equal(traj.meta["total_energy"], _stack(records, "total"))
    assert traj.meta["backbone"].shape == (400, 3, records[0].backbone.shape[1], 3)
    assert traj.meta["scene"] == arm_info().scene and traj.meta["truncated"] is False
    # chunks are cut every 0.4 s of simulation time by default: 0 .. 0.798 s -> one cut and the
    # last chunk (the 0.5 s wall-time interval may cut more on a slow machine)
    assert DEFAULT_FLUSH_INTERVAL == 0.4
    with open(path, "rb") as fh:
        assert 2 <= make_reader(fh).get_summary().statistics.chunk_count <= 4
    # an independent MCAP reader (Rerun's, in Rust) accepts the file and its summary
    import rerun as rr

    about = rr.chunk.McapReader(path, timeline_type="duration_ns").info()
    assert about.statistics_present and about.message_count == 4 * 400 and about.metadata_count == 3
    assert {c.topic: c.message_count for c in about.channels} == {t: 400 for t in TOPICS.values()}
    assert about.message_end_time_ns == round(records[-1].t * 1e9)


def test_flush_makes_everything_logged_so_far_readable(tmp_path):
    path = tmp_path / "live.mcap"
    records = arm_records(150)
    with RunLogger(arm_info(), path, quiet=True) as log:
        for r in records[:100]:
            log.log(r)
        assert log.flush() == {"n_records": 100, "last_t": records[99].t}
        live = read_recording(path)  # the file of a running simulation, read as it stands
        assert live.truncated and live.outcome is None
        _assert_records_equal(live, records[:100])
        for r in records[100:]:
            log.log(r)
    _assert_records_equal(read_recording(path), records)


def test_flush_and_end_wake_a_pausing_writer(tmp_path, monkeypatch):
    """The writer reads the journal every WRITER_POLL seconds (records do not wake it); a
    flush and the end come over its control connection, which wakes it at once. With a
    60 s pause, both are still answered within the 20 s allowed here."""
    from qchain.recording import logger as qlogger

    monkeypatch.setattr(qlogger, "WRITER_POLL", 60.0)
    path = tmp_path / "bell.mcap"
    records = arm_records(40)
    log = RunLogger(arm_info(), path, quiet=True, worker="process")
    time.sleep(0.2)  # the writer is in its pause
    for r in records[:20]:
        log.log(r)
    assert log.flush(timeout=20.0) == {"n_records": 20, "last_t": records[19].t}
    for r in records[20:]:
        log.log(r)
    t0 = time.monotonic()
    assert log.close()["n_records"] == 40
    assert time.monotonic() - t0 < 20.0
    _assert_records_equal(read_recording(path), records)


def test_exception_in_simulation_finishes_the_log():
    buf = io.BytesIO()
    with pytest.raises(RuntimeError, match="integrator blew up"):
        with RunLogger(arm_info(), buf) as log:
            for r in arm_records(50):
                log.log(r)
            raise RuntimeError("integrator blew up")
    buf.seek(0)
    rec = read_recording(buf)
    assert len(rec) == 50 and not rec.truncated
    traj = rec.to_trajectory()
    assert not traj.success and traj.status == -1 and "integrator blew up" in traj.message
    buf.seek(0)
    assert make_reader(buf).get_summary() is not None


def test_outcome_set_by_the_simulation_is_recorded():
    buf = io.BytesIO()
    with RunLogger(arm_info(), buf) as log:
        for r in arm_records(5):
            log.log(r)
        log.set_outcome(success=False, message="left the domain: |kappa| r >= 1", status=1, nfev=1234)
    buf.seek(0)
    traj = read_mcap(buf)
    assert (traj.success, traj.status, traj.nfev) == (False, 1, 1234)
    assert traj.message == "left the domain: |kappa| r >= 1"


def test_bounded_queue_waits_for_a_slow_writer(monkeypatch):
    """Memory stays flat with the thread writer: with a writer slower than the simulation,
    log() waits once max_queue records are queued."""
    from qchain.recording.writer import Sinks

    slow = Sinks.write_rows

    def write_slowly(self, rows, layout):
        time.sleep(0.002 * len(rows))
        slow(self, rows, layout)

    monkeypatch.setattr(Sinks, "write_rows", write_slowly)
    buf = io.BytesIO()
    peak = 0
    records = arm_records(120)
    with RunLogger(arm_info(), buf, max_queue=8) as log:
        for r in records:
            log.log_columns(**_columns([r]))  # one record a batch: the queue's unit is a record
            peak = max(peak, log._thread.pending)
    assert peak <= 8 + 1
    buf.seek(0)
    assert len(read_recording(buf)) == 120


def test_record_and_info_validation():
    info = arm_info()
    with pytest.raises(ValueError, match="radii must have shape \\(3,\\)"):
        RunInfo(n_segments=3, radii=[0.01, 0.01])
    with pytest.raises(ValueError, match="radii must be finite and > 0"):
        RunInfo(n_segments=2, radii=[0.01, -0.01])
    with pytest.raises(ValueError, match=r"params\['solver'\]"):
        RunInfo(n_segments=1, radii=[0.01], params={"solver": object()})
    with pytest.raises(ValueError, match="n_segments must be >= 1"):
        RunInfo(n_segments=0, radii=[])
    assert RunInfo(n_segments=1, radii=[0.01], params={"K": np.eye(2)}).params == {"K": [[1.0, 0.0], [0.0, 1.0]]}

    buf = io.BytesIO()
    with RunLogger(info, buf) as log:
        good = arm_record(0.0, 0)
        first_bad = arm_record(0.0, 0)
        first_bad.backbone = first_bad.backbone[:2]
        with pytest.raises(ValueError, match=r"record.backbone must have shape \(3, P, 3\)"):
            log.log(first_bad)
        first_bad.backbone, first_bad.tip_frames = good.backbone, good.tip_frames[:, :3]
        with pytest.raises(ValueError, match=r"record.tip_frames must have shape \(3, 7\)"):
            log.log(first_bad)
        log.log(good)
        bad = arm_record(0.001, 1)
        bad.backbone = bad.backbone[:, :5]
        with pytest.raises(ValueError, match="record.backbone has shape \\(3, 5, 3\\) at step 1"):
            log.log(bad)
        wrong_q = arm_record(0.002, 2)
        wrong_q.q = wrong_q.q[:4]
        with pytest.raises(ValueError, match="record.q has shape \\(4,\\)"):
            log.log(wrong_q)
        with pytest.raises(ValueError, match="record.t must be finite and >= 0"):
            log.log(arm_record(0.0, 3).__class__(**{**arm_record(0.0, 3).__dict__, "t": -1.0}))
        lists = arm_record(0.003, 3)  # plain lists and float32 are converted
        lists.q = lists.q.tolist()
        lists.backbone = lists.backbone.astype(np.float32)
        log.log(lists)
    with pytest.raises(LoggingError, match="closed"):
        log.log(good)
    buf.seek(0)
    rec = read_recording(buf)
    assert len(rec) == 2
    np.testing.assert_array_equal(rec.q[1], np.asarray(lists.q))
    np.testing.assert_array_equal(rec.backbone[1], lists.backbone.astype(np.float64))
    with pytest.raises(ValueError, match="serve and connect exclude each other"):
        RunLogger(info, None, serve=True, connect="rerun+http://127.0.0.1:9/proxy")
    with pytest.raises(ValueError, match="flush_interval"):
        RunLogger(info, io.BytesIO(), flush_interval=0)
    with pytest.raises(ValueError, match="rerun_latency must be a finite number of seconds > 0, got nan"):
        RunLogger(info, io.BytesIO(), rerun_latency=float("nan"))


def _columns(records):
    return dict(t=_stack(records, "t"), step=_stack(records, "step"), q=_stack(records, "q"), v=_stack(records, "v"),
                p=_stack(records, "p"), kinetic=_stack(records, "kinetic"), potential=_stack(records, "potential"),
                total=_stack(records, "total"), backbone=_stack(records, "backbone"),
                tip_frames=_stack(records, "tip_frames"))


@pytest.mark.parametrize("target", ["stream", "file"])
def test_columns_and_rows_round_trip_like_single_records(target, tmp_path):
    """log_columns and log_rows (the batch ways in) give the file log() gives, in both workers."""
    records = arm_records(120, dt=5e-3)
    lay = RecordLayout(9, 9, 9, 3, records[0].backbone.shape[1])
    sl = lay.slices
    rows = np.empty((40, lay.row_width))
    for i, r in enumerate(records[80:]):
        rows[i, sl["t"]], rows[i, sl["step"]], rows[i, sl["q"]], rows[i, sl["v"]] = r.t, r.step, r.q, r.v
        rows[i, sl["p"]], rows[i, sl["energy"]] = r.p, (r.kinetic, r.potential, r.total)
        rows[i, sl["backbone"]], rows[i, sl["tip_frames"]] = r.backbone.ravel(), r.tip_frames.ravel()
        rows[i, sl["base"]] = [*r.backbone[0, 0], 0.0, 0.0, 0.0, 1.0]  # what a record without base_frame gets
    out = io.BytesIO() if target == "stream" else tmp_path / "batch.mcap"
    with RunLogger(arm_info(), out, quiet=True) as log:
        log.log_columns(**_columns(records[:50]))
        for r in records[50:80]:
            log.log(r)
        log.log_rows(rows[:25], lay)
        log.log_rows(rows[25:], lay)
        assert log.n_logged == 120
    if target == "stream":
        out.seek(0)
    _assert_records_equal(read_recording(out), records)


def test_batch_validation():
    records = arm_records(4)
    lay = RecordLayout(9, 9, 9, 3, records[0].backbone.shape[1])
    with RunLogger(arm_info(), io.BytesIO()) as log:
        cols = _columns(records)
        with pytest.raises(ValueError, match=r"q must have a leading axis of K = 4 \(the length of t\), got shape \(3, 9\)"):
            log.log_columns(**{**cols, "q": cols["q"][:3]})
        log.log_columns(**cols)
        with pytest.raises(ValueError, match=r"backbone has rows of shape \(3, 5, 3\); the first record had \(3, 12, 3\)"):
            log.log_columns(**{**cols, "backbone": cols["backbone"][:, :, :5]})
        with pytest.raises(ValueError, match=r"t must be finite and >= 0 s, got nan at step 2"):
            log.log_columns(**{**cols, "t": np.array([0.0, 0.1, np.nan, 0.3])})
        rows = np.zeros((2, lay.row_width))
        with pytest.raises(ValueError, match=r"rows must be a float64 array of shape \(K, %d\), got float32" % lay.row_width):
            log.log_rows(rows.astype(np.float32), lay)
        with pytest.raises(ValueError, match="differs from the run's"):
            other = RecordLayout(9, 9, 9, 3, 13)
            log.log_rows(np.zeros((2, other.row_width)), other)
        with pytest.raises(TypeError, match="layout must be a RecordLayout"):
            log.log_rows(rows, (9, 9, 9, 3, 12))
        rows[1, 0] = -1.0
        with pytest.raises(ValueError, match=r"t must be finite and >= 0 s, got -1.0 at step 0"):
            log.log_rows(rows, lay)
    with RunLogger(arm_info(), io.BytesIO()) as log:
        with pytest.raises(ValueError, match="layout.n = 2 segments, but the run's RunInfo has 3"):
            log.log_rows(np.zeros((1, RecordLayout(9, 9, 9, 2, 12).row_width)), RecordLayout(9, 9, 9, 2, 12))


def test_prepared_writer_is_taken_by_the_next_logger(tmp_path):
    """prepare_writer starts the writer process ahead (qchain run does it before building the
    model); the next logger uses it, and its file is right. The writer is a plain
    `python -m qchain.recording.writer`: importing qchain loads no model code."""
    from qchain.recording import writer as qwriter

    prepare_writer()
    prepare_writer()  # one spare is enough
    assert len(qwriter._SPARES) == 1
    pid = qwriter._SPARES[0][0].pid
    deadline = time.monotonic() + 30.0
    cmdline = b""
    while not cmdline and time.monotonic() < deadline:  # empty until its exec is done
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            cmdline = fh.read()
        time.sleep(0.01)
    assert cmdline.split(b"\0")[1:3] == [b"-m", b"qchain.recording.writer"]
    records = arm_records(30)
    log = _log_all(records, mcap=tmp_path / "pre.mcap")
    assert log.worker_pid == pid and not qwriter._SPARES
    _assert_records_equal(read_recording(tmp_path / "pre.mcap"), records)
    assert not (tmp_path / "pre.mcap.journal").exists()  # removed once the recording is whole
    code = ("import sys, qchain.recording.writer, qchain.recording.mcap_sink; "
            "print(sorted(m for m in ('pinocchio', 'numba', 'scipy', 'qchain.arm.chain') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.stdout.strip() == "[]", out.stderr


def test_a_prepared_writer_writes_a_relative_path_where_the_run_is(tmp_path, monkeypatch):
    """A spare writer started in one working folder, taken by a run in another: the run's
    relative recording path is the run's (it was written beside the spare's folder)."""
    from qchain.recording import writer as qwriter

    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    monkeypatch.chdir(tmp_path / "a")
    prepare_writer()
    pid = qwriter._SPARES[-1][0].pid
    monkeypatch.chdir(tmp_path / "b")
    records = arm_records(20)
    log = _log_all(records, mcap="m.mcap")
    assert log.worker_pid == pid
    _assert_records_equal(read_recording(tmp_path / "b" / "m.mcap"), records)
    assert not (tmp_path / "a" / "m.mcap").exists()


@pytest.mark.skipif(not hasattr(signal, "SIGSTOP"), reason="needs SIGSTOP")
def test_a_file_logger_does_not_wait_for_its_writer(tmp_path):
    """The simulating process only appends to the journal: a stopped writer holds nothing
    up, and close() waits for it to finish. A writer that dies before answering leaves the
    records in the journal: close() finishes the recording from it in this process, warns,
    and the file is whole."""
    from qchain.recording import writer as qwriter

    records = arm_records(40)
    prepare_writer()
    writer = qwriter._SPARES[-1][0]
    os.kill(writer.pid, signal.SIGSTOP)
    try:
        t0 = time.monotonic()
        log = RunLogger(arm_info(), tmp_path / "stopped.mcap", quiet=True, startup_timeout=1.0)
        assert log.worker_pid == writer.pid
        for r in records:
            log.log(r)
        assert time.monotonic() - t0 < 5.0
    finally:
        os.kill(writer.pid, signal.SIGCONT)
    log.close()
    _assert_records_equal(read_recording(tmp_path / "stopped.mcap"), records)

    prepare_writer()
    writer = qwriter._SPARES[-1][0]
    os.kill(writer.pid, signal.SIGSTOP)
    log = RunLogger(arm_info(), tmp_path / "dead.mcap", quiet=True, startup_timeout=1.0)
    for r in records:
        log.log(r)
    os.kill(writer.pid, signal.SIGKILL)
    writer.wait(10)
    with pytest.warns(LoggingWarning, match="log writer"):
        log.close()
    rec = read_recording(tmp_path / "dead.mcap")
    _assert_records_equal(rec, records)
    assert not rec.truncated and "finished from the journal" in rec.outcome["message"]
    assert not (tmp_path / "dead.mcap.journal").exists()


def test_an_unwritable_output_fails_where_it_is_given(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(LoggingError, match=r"cannot write mcap file .*file/run\.mcap"):
        RunLogger(arm_info(), blocker / "run.mcap", quiet=True)


# --------------------------------------------------------------------------------------
# Rerun
# --------------------------------------------------------------------------------------


def _rrd_columns(path):
    """entity path -> {"t": sim_time ns, "step": ..., component: values} of its temporal rows,
    in step order."""
    import pyarrow as pa
    import rerun as rr

    reader = rr.chunk.RrdReader(path)
    out: dict[str, dict] = {}
    for chunk in reader.stream():
        if chunk.is_static:
            continue
        rb = chunk.to_record_batch()
        cols = out.setdefault(chunk.entity_path, {})
        for name in rb.schema.names:
            col = rb.column(rb.schema.names.index(name))
            if name == "sim_time":
                cols.setdefault("t", []).extend(col.cast(pa.int64()).to_pylist())
            elif name == "step" or ":" in name:
                cols.setdefault(name.split(":")[-1], []).extend(col.to_pylist())
    for cols in out.values():
        order = np.argsort(cols["step"], kind="stable")
        for k in cols:
            cols[k] = [cols[k][i] for i in order]
    return out, reader


def test_rerun_gets_its_first_batch_at_once(tmp_path):
    """Rerun's first batch (its start: blueprint, static geometry) does not wait for
    rerun_latency, so it overlaps the run instead of delaying its end; the later records
    gather for rerun_latency as before."""
    records = arm_records(40, dt=1e-3)
    rrd = tmp_path / "run.rrd"
    with RunLogger(arm_info(), io.BytesIO(), rrd=rrd, worker="thread", rerun_latency=60.0, quiet=True) as log:
        for r in records[:20]:
            log.log(r)
        sinks = log._thread.sinks
        deadline = time.monotonic() + 30.0
        while not (sinks.rerun is not None and sinks.rerun.started) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert sinks.rerun is not None and sinks.rerun.started  # long before the 60 s latency
        for r in records[20:]:
            log.log(r)
        time.sleep(0.6)  # the thread's idle ticks: the records now wait for the latency
        assert 20 <= sinks._rr_count < 40 and sinks.n_records == 40
    cols, _ = _rrd_columns(rrd)
    assert cols["/plots/q/segment_1"]["step"] == [r.step for r in records]


def test_rrd_round_trip(tmp_path):
    records = arm_records(250, dt=1e-3)
    rrd = tmp_path / "run.rrd"
    _log_all(records, mcap=io.BytesIO(), rrd=rrd)
    cols, reader = _rrd_columns(rrd)
    assert len(reader.blueprints()) == 1
    assert {"/plots/q/segment_1", "/plots/q/segment_3", "/plots/v", "/plots/pressure", "/plots/energy",
            "/arm/backbone", "/arm/tip_axes", "/arm/pressure"} <= set(cols)
    t_ns = [round(r.t * 1e9) for r in records]
    steps = [r.step for r in records]
    for entity, field, sl in (("/plots/q/segment_2", "q", slice(3, 6)), ("/plots/v", "v", slice(None)),
                              ("/plots/pressure", "p", slice(None))):
        c = cols[entity]
        assert c["step"] == steps and c["t"] == t_ns
        np.testing.assert_array_equal(np.array(c["scalars"]), _stack(records, field)[:, sl])
    energy = np.array(cols["/plots/energy"]["scalars"])
    np.testing.assert_array_equal(energy, np.c_[_stack(records, "kinetic"), _stack(records, "potential"),
                                                _stack(records, "total")])
    strips = cols["/arm/backbone"]["strips"]
    assert len(strips) == 250 and cols["/arm/backbone"]["t"] == t_ns
    np.testing.assert_array_equal(np.array(strips[100]), records[100].backbone.astype(np.float32))
    # tip axes: 3 a tip, from the tip position, of length 2.5 radii along the tip frame's axes
    arrows = cols["/arm/tip_axes"]
    origins, vectors = np.array(arrows["origins"][40]), np.array(arrows["vectors"][40])
    assert origins.shape == vectors.shape == (9, 3)
    np.testing.assert_allclose(origins[::3], records[40].tip_frames[:, :3], rtol=1e-6)
    radius = arm_info().radii[0]
    np.testing.assert_allclose(np.linalg.norm(vectors, axis=1), 2.5 * radius, rtol=1e-5)
    # the z axes point along the end of each arc
    ends = records[40].backbone[:, -1] - records[40].backbone[:, -2]
    cos = np.sum(vectors[2::3] * ends, axis=1) / np.linalg.norm(vectors[2::3], axis=1) / np.linalg.norm(ends, axis=1)
    assert np.all(cos > 0.99)
    # pressure arrows: 3 a tip plate, length by pressure (half a segment at pressure_ref)
    pv = np.array(cols["/arm/pressure"]["vectors"][40])
    lengths = np.linalg.norm(pv, axis=1)
    seg_len = np.linalg.norm(np.diff(records[0].backbone, axis=1), axis=2).sum(axis=1)  # at the first record
    expected = 0.5 * np.repeat(seg_len, 3) * records[40].p / arm_info().pressure_ref
    np.testing.assert_allclose(lengths, expected, rtol=1e-5)


def test_rerun_display_rate_thins_only_the_viewer(tmp_path):
    records = arm_records(200, dt=1e-3)
    rrd = tmp_path / "thin.rrd"
    buf = io.BytesIO()
    _log_all(records, mcap=buf, rrd=rrd, rerun_rate=100.0)  # 100 records a simulated second
    cols, _ = _rrd_columns(rrd)
    assert cols["/plots/q/segment_1"]["step"] == list(range(0, 200, 10))
    buf.seek(0)
    assert len(read_recording(buf)) == 200
    with pytest.raises(ValueError, match="rerun_rate"):
        RunLogger(arm_info(), io.BytesIO(), rerun_rate=0)


def test_replay_to_rrd_keeps_original_times(tmp_path):
    records = arm_records(120, dt=5e-3)
    path = tmp_path / "run.mcap"
    with open(path, "wb") as fh:
        _log_all(records, mcap=fh)
    out = tmp_path / "replay.rrd"
    session = replay(path, rrd=out, batch=50)
    assert session.viewer_url is None and len(session.recording) == 120
    cols, _ = _rrd_columns(out)
    c = cols["/plots/energy"]
    assert c["step"] == [r.step for r in records]
    assert c["t"] == [round(r.t * 1e9) for r in records]
    np.testing.assert_array_equal(np.array(c["scalars"])[:, 2], _stack(records, "total"))
    with pytest.raises(ValueError, match="needs a target"):
        replay(path)


def test_unreachable_viewer_does_not_stop_the_run(tmp_path):
    import socket

    with socket.socket() as s:  # a loopback port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"rerun+http://127.0.0.1:{port}/proxy"
    path = tmp_path / "run.mcap"
    records = arm_records(200)
    with pytest.warns(LoggingWarning) as caught:
        log = _log_all(records, mcap=path, connect=url)
    ours = [w for w in caught if issubclass(w.category, LoggingWarning)]
    assert len(ours) == 1
    text = str(ours[0].message)
    assert url in text and "no Rerun viewer can be reached" in text and "MCAP" in text
    assert log.close()["n_records"] == 200
    _assert_records_equal(read_recording(path), records)


def _listening_sockets(pid):
    """(address, port) of the TCP sockets process ``pid`` listens on (from /proc)."""
    inodes = set()
    for fd in os.listdir(f"/proc/{pid}/fd"):
        try:
            link = os.readlink(f"/proc/{pid}/fd/{fd}")
        except OSError:
            continue
        if link.startswith("socket:["):
            inodes.add(link[8:-1])
    found = []
    for table, v6 in (("/proc/net/tcp", False), ("/proc/net/tcp6", True)):
        if not os.path.exists(table):
            continue
        for line in open(table).read().splitlines()[1:]:
            cols = line.split()
            local, state, inode = cols[1], cols[3], cols[9]
            if state != "0A" or inode not in inodes:  # 0A = LISTEN
                continue
            hexaddr, hexport = local.split(":")
            if v6:
                raw = bytes.fromhex(hexaddr)
                words = [raw[i : i + 4][::-1] for i in range(0, 16, 4)]
                import ipaddress

                addr = str(ipaddress.IPv6Address(b"".join(words)))
            else:
                addr = ".".join(str(b) for b in bytes.fromhex(hexaddr)[::-1])
            found.append((addr, int(hexport, 16)))
    return found


def test_serving_binds_only_loopback(tmp_path):
    from urllib.parse import parse_qs, urlsplit

    path = tmp_path / "run.mcap"
    log = RunLogger(arm_info(), path, serve=True, quiet=True)
    try:
        for r in arm_records(20):
            log.log(r)
        assert log.viewer_url.startswith("http://127.0.0.1:")
        web_port = urlsplit(log.viewer_url).port
        grpc_url = parse_qs(urlsplit(log.viewer_url).query)["url"][0]
        assert grpc_url == log.grpc_url and urlsplit(grpc_url).hostname == "127.0.0.1"
        grpc_port = urlsplit(grpc_url).port
        sockets = _listening_sockets(log.worker_pid) + _listening_sockets(log.web_pid)
        assert ("127.0.0.1", grpc_port) in sockets and ("127.0.0.1", web_port) in sockets
        assert all(addr == "127.0.0.1" for addr, _ in sockets), sockets
        with urllib.request.urlopen(log.viewer_url, timeout=10) as resp:  # the viewer page is served
            assert resp.status == 200 and b"<html" in resp.read(4096).lower()
    finally:
        log.close()
    _assert_records_equal(read_recording(path), arm_records(20))


# --------------------------------------------------------------------------------------
# Truncated and foreign files
# --------------------------------------------------------------------------------------


def test_file_cut_at_half_replays_its_first_part(tmp_path, capsys):
    records = arm_records(600, dt=1e-3)
    path = tmp_path / "run.mcap"
    with open(path, "wb") as fh:
        _log_all(records, mcap=fh, flush_interval=0.1)
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])

    rec = read_recording(cut)
    assert rec.truncated and rec.stop_reason
    assert 0 < len(rec) < 600
    _assert_records_equal(rec, records[: len(rec)])
    # at most one chunk (0.1 s of simulation time) of the first half is lost
    assert rec.t[-1] >= records[299].t - 0.1 - 1e-9
    traj = read_mcap(cut)
    assert not traj.success and "truncated" in traj.message and f"{rec.t[-1]:.6g}" in traj.message
    assert traj.meta["stopped_at"] == rec.t[-1]

    out = tmp_path / "cut.rrd"
    with pytest.warns(LoggingWarning, match="is truncated; replaying up to t = "):
        replay(cut, rrd=out)
    cols, _ = _rrd_columns(out)
    assert cols["/plots/q/segment_1"]["step"] == rec.step.tolist()

    assert replay_main([str(cut), "--rrd", str(tmp_path / "cut2.rrd")]) == 0
    printed = capsys.readouterr().out
    assert f"replayed {len(rec)} steps" in printed and f"stops at t = {rec.t[-1]:.6g} s" in printed


def test_any_cut_reads_a_prefix_or_fails_clearly():
    """Cut anywhere, a recording reads as a prefix of what was logged, or (cut inside its
    first records) raises RecordingFormatError; nothing else escapes."""
    records = arm_records(120, dt=1e-3)
    buf = io.BytesIO()
    _log_all(records, mcap=buf, flush_interval=0.01)
    data = buf.getvalue()
    sizes = sorted({*range(0, len(data), max(1, len(data) // 41)), len(data) - 1, len(data) - 9, len(data)})
    prefixes = []
    for size in sizes:
        cut = io.BytesIO(data[:size])
        try:
            rec = read_recording(cut)
        except RecordingFormatError as exc:
            assert size < 4096, f"a cut at {size} of {len(data)} bytes failed: {exc}"
            continue
        _assert_records_equal(rec, records[: len(rec)])
        assert rec.truncated == (size < len(data))
        prefixes.append(len(rec))
    assert prefixes == sorted(prefixes) and prefixes[-1] == 120
    assert len(set(prefixes)) > 8  # one more chunk (0.01 s) readable every few cuts


def test_not_a_qchain_mcap_gets_a_clear_error(tmp_path, capsys):
    junk = tmp_path / "notes.mcap"
    junk.write_bytes(b"just some text, not a recording\n" * 10)
    with pytest.raises(RecordingFormatError, match=r"notes\.mcap: not an MCAP file"):
        read_mcap(junk)
    empty = tmp_path / "empty.mcap"
    empty.write_bytes(b"")
    with pytest.raises(RecordingFormatError, match=r"empty\.mcap: the file is empty"):
        read_mcap(empty)
    other = tmp_path / "other.mcap"  # a valid MCAP written by another program
    with open(other, "wb") as fh:
        w = Writer(fh)
        w.start()
        sid = w.register_schema("x", "jsonschema", b"{}")
        cid = w.register_channel("/imu", "json", sid)
        w.add_message(cid, 0, b"{}", 0)
        w.finish()
    with pytest.raises(RecordingFormatError, match=r"other\.mcap: an MCAP file, but not a qchain recording"):
        read_mcap(other)
    assert issubclass(RecordingFormatError, qchain.QchainError) and issubclass(RecordingFormatError, ValueError)
    assert replay_main([str(other), "--rrd", str(tmp_path / "x.rrd")]) == 2
    assert "not a qchain recording" in capsys.readouterr().err


# --------------------------------------------------------------------------------------
# Command line support
# --------------------------------------------------------------------------------------


def test_command_line_helpers(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    parser = argparse.ArgumentParser(prog="qchain run")
    parser.add_argument("scene")
    add_logging_arguments(parser)
    args = parser.parse_args(["arm.toml"])
    assert (args.mcap, args.serve, args.connect, args.rrd, args.bind, args.rerun_rate) == (
        None, False, None, None, "127.0.0.1", None)
    info = arm_info(scene_path="scenes/arm.toml")
    default = default_mcap_path(info.scene_path)
    assert default.parent == Path("runs") and default.name.startswith("arm-") and default.suffix == ".mcap"
    with logger_from_args(args, info, quiet=True) as log:
        for r in arm_records(10):
            log.log(r)
    made = sorted(Path("runs").glob("arm-*.mcap"))
    assert len(made) == 1 and len(read_recording(made[0])) == 10
    assert default_mcap_path(info.scene_path, now=None) != made[0] or len(made) == 1
    args = parser.parse_args(["arm.toml", "--mcap", "out/x.mcap", "--rrd", "out/x.rrd"])
    with logger_from_args(args, info, "ignored.mcap", quiet=True) as log:
        log.log(arm_record(0.0, 0))
    assert Path("out/x.mcap").exists() and Path("out/x.rrd").exists() and not Path("ignored.mcap").exists()
    args = parser.parse_args(["arm.toml", "--serve", "--connect", "rerun+http://127.0.0.1:9876/proxy"])
    with pytest.raises(ValueError, match="--serve and --connect"):
        logger_from_args(args, info)
    stamp = __import__("datetime").datetime(2026, 1, 2, 3, 4, 5)
    Path("runs/arm-20260102-030405.mcap").touch()
    assert default_mcap_path("arm.toml", now=stamp) == Path("runs/arm-20260102-030405-1.mcap")


def test_step_record_is_a_plain_dataclass():
    r = arm_record(0.25, 250)
    assert isinstance(r, StepRecord)
    assert r.q.shape == (9,) and r.backbone.shape == (3, 12, 3) and r.tip_frames.shape == (3, 7)
    np.testing.assert_allclose(np.linalg.norm(r.tip_frames[:, 3:], axis=1), 1.0)
    np.testing.assert_allclose(r.tip_frames[:, :3], r.backbone[:, -1])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        RunInfo(n_segments=3, radii=(0.01, 0.01, 0.01))
