"""Contact in a recording: the obstacles recorded once in RunInfo (Environment.describe), each
sample's active contacts in the rows, the MCAP (/qchain/contacts JSON, /qchain/contact_forces
and /qchain/obstacles as Foxglove scene updates) and the Rerun view, read back exactly;
recordings without contact read as before."""

from __future__ import annotations

import io
import json
import warnings

import numpy as np
import pytest
from logging_fixtures import arm_info, arm_records
from mcap.reader import make_reader
from test_logging import _check_foxglove_readable, _check_json_schema, _rrd_columns

from qchain.logging import TOPICS, RunInfo, RunLogger, read_recording
from qchain.recording.mcap_sink import CONTACTS_SCHEMA
from qchain.recording.records import (
    CONTACT_TOPICS,
    CONTACT_WIDTH,
    ContactSet,
    LoggingWarning,
    RecordLayout,
    pack_contacts,
)
from qchain.recording.rerun_sink import _quat_rot
from qchain.recording.scenery import force_scale, reach

#: one obstacle of each type, as Environment.describe gives them (world frame, m)
OBSTACLES = [
    {"type": "halfspace", "point": [0.0, 0.0, -0.01], "normal": [0.0, 0.0, 1.0], "motion": None},
    {"type": "sphere", "center": [0.1, 0.0, 0.2], "radius": 0.05, "motion": None},
    {"type": "capsule", "a": [0.0, 0.1, 0.0], "b": [0.0, 0.1, 0.3], "radius": 0.02, "motion": None},
    {"type": "cylinder", "a": [-0.1, 0.0, 0.0], "b": [-0.1, 0.2, 0.0], "radius": 0.03,
     "motion": {"velocity": [0.0, 0.0, 0.0], "amplitude": [0.01, 0.0, 0.0], "frequency": 2.0, "phase": 0.0}},
    {"type": "box", "center": [0.2, 0.2, 0.1], "half_extents": [0.05, 0.1, 0.02],
     "rotation": [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], "motion": None},
]
MAX_CONTACTS = 6
FORCE_REF = 2.0


def _info(**kw):
    d = arm_info().to_json()
    d.update({"obstacles": OBSTACLES, "max_contacts": MAX_CONTACTS, "force_ref": FORCE_REF, **kw})
    return RunInfo.from_json(d)


def _contacts(K, seed=0):
    """K samples' contacts, 0 .. MAX_CONTACTS of them (ragged), the first sample none."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(K):
        c = 0 if k == 0 else int(rng.integers(0, MAX_CONTACTS + 1))
        nrm = rng.normal(size=(c, 3))
        out.append(ContactSet(rng.normal(size=(c, 3)), nrm / np.linalg.norm(nrm, axis=1, keepdims=True),
                              rng.normal(size=(c, 3)), rng.integers(0, 3, c),
                              rng.integers(-3, len(OBSTACLES), c)))  # -1 - k: self-contact with segment k
    return out


def _assert_contacts_equal(rec, contacts):
    assert rec.contacts is not None and rec.contacts.shape == (len(contacts), MAX_CONTACTS, CONTACT_WIDTH)
    for k, c in enumerate(contacts):
        got = rec.contact_set(k)
        for name, a, b in zip(ContactSet._fields, got, c):
            np.testing.assert_array_equal(a, b, err_msg=f"record {k}: {name}")
        assert got.segment.dtype == got.obstacle.dtype == np.int64


def _logged(records, contacts, info=None, mcap=None, **kw):
    for r, c in zip(records, contacts):
        r.contacts = c
    buf = io.BytesIO() if mcap is None else mcap
    with RunLogger(info or _info(), buf, quiet=True, **kw) as log:
        for r in records:
            log.log(r)
    if mcap is None:
        buf.seek(0)
    return buf


def test_mcap_round_trip_with_contacts_is_exact():
    """Ragged contacts (0 to 6 a sample) come back bit for bit, at their records; the obstacles
    come back as recorded; the contact messages follow their JSON schema, which Foxglove
    reads; each channel has one message a record (the obstacles too: one of them moves)."""
    records, contacts = arm_records(60, dt=1e-2), _contacts(60)
    buf = _logged(records, contacts)
    rec = read_recording(buf)
    assert rec.damage == [] and not rec.truncated and len(rec) == 60
    _assert_contacts_equal(rec, contacts)
    assert rec.info.obstacles == OBSTACLES and rec.info.max_contacts == MAX_CONTACTS
    assert rec.info.force_ref == FORCE_REF
    np.testing.assert_array_equal(rec.q, np.array([r.q for r in records]))  # the rest is as before

    buf.seek(0)
    reader = make_reader(buf)
    counts = {ch.topic: reader.get_summary().statistics.channel_message_counts[cid]
              for cid, ch in reader.get_summary().channels.items()}
    # the obstacles: a message a record, since one of them (the cylinder) moves
    assert counts == {**{t: 60 for t in TOPICS.values()}, CONTACT_TOPICS["contacts"]: 60,
                      CONTACT_TOPICS["forces"]: 60, CONTACT_TOPICS["obstacles"]: 60}
    _check_foxglove_readable(CONTACTS_SCHEMA)
    k = 0
    for schema, channel, msg in reader.iter_messages(topics=[CONTACT_TOPICS["contacts"]]):
        assert schema.name == "qchain.Contacts" and schema.encoding == "jsonschema"
        data = json.loads(msg.data)
        _check_json_schema(data, json.loads(schema.data))
        assert data["step"] == records[k].step and msg.log_time == round(records[k].t * 1e9)
        assert len(data["point"]) == len(contacts[k].segment)
        k += 1
    assert k == 60


def test_contacts_travel_through_the_journal_and_the_writer_process(tmp_path):
    """A file written by the writer process from the run's journal (the rows carry the
    contacts) reads back the same as the in-memory stream."""
    records, contacts = arm_records(40, dt=1e-2), _contacts(40, seed=3)
    path = tmp_path / "run.mcap"
    _logged(records, contacts, mcap=path)
    rec = read_recording(path)
    assert rec.damage == [] and len(rec) == 40
    _assert_contacts_equal(rec, contacts)
    assert rec.info.obstacles == OBSTACLES


def test_a_sample_with_more_contacts_than_the_rows_hold_keeps_the_largest_forces():
    """Past max_contacts the largest forces are kept (in their order) and it is said once."""
    f = np.array([[1.0, 0, 0], [0, 5.0, 0], [0, 0, 3.0], [0.5, 0, 0]])
    c = ContactSet(np.arange(12.0).reshape(4, 3), np.tile([0, 0, 1.0], (4, 1)), f, np.array([0, 1, 2, 0]),
                   np.array([1, 0, 1, 0]))
    block, dropped = pack_contacts(c, 2)
    assert dropped == 2
    kept = ContactSet.from_block(block)
    np.testing.assert_array_equal(kept.force, f[[1, 2]])
    np.testing.assert_array_equal(kept.point, c.point[[1, 2]])
    np.testing.assert_array_equal(kept.segment, [1, 2])
    records = arm_records(3, dt=1e-2)
    big = ContactSet(*(np.repeat(x, 2, axis=0) for x in c))  # 8 contacts, 6 fit
    with pytest.warns(LoggingWarning, match="more than RunInfo.max_contacts = 6") as got:
        buf = _logged(records, [big, big, None])
    assert sum("max_contacts" in str(w.message) for w in got) == 1
    rec = read_recording(buf)
    assert len(rec.contact_set(0).segment) == 6 and len(rec.contact_set(2).segment) == 0
    assert sorted(np.linalg.norm(rec.contact_set(0).force, axis=1)) == [1.0, 1.0, 3.0, 3.0, 5.0, 5.0]


def test_bad_contacts_and_obstacles_are_refused_by_name():
    with pytest.raises(TypeError, match="contacts must have .point"):
        pack_contacts(object(), 2)
    with pytest.raises(ValueError, match="contacts: point, normal, force"):
        pack_contacts(ContactSet(np.zeros((2, 3)), np.zeros((3, 3)), np.zeros((2, 3)), [0, 0], [0, 0]), 2)
    info = _info()
    bad = ContactSet(np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), [0], [5])
    with pytest.raises(ValueError, match="contacts.obstacle must be indices into RunInfo.obstacles \\(5 of them\\)"):
        pack_contacts(bad, 2, info)
    with pytest.raises(ValueError, match="contacts.segment must be segment indices 0 .. 2"):
        pack_contacts(bad._replace(segment=[3], obstacle=[0]), 2, info)
    assert pack_contacts(bad._replace(obstacle=[-3]), 2, info)[1] == 0  # self-contact with segment 2
    record = arm_records(1, dt=1e-2)[0]
    record.contacts = bad
    with RunLogger(info, io.BytesIO(), quiet=True) as log, \
            pytest.raises(ValueError, match="contacts.obstacle must be indices"):
        log.log(record)
    with pytest.raises(ValueError, match="obstacles\\[0\\] must be a dict with a 'type'"):
        RunInfo(n_segments=1, radii=[0.01], obstacles=[{"radius": 1.0}])
    with pytest.raises(ValueError, match="obstacles must be None or a list"):
        RunInfo(n_segments=1, radii=[0.01], obstacles="ground")
    with pytest.raises(ValueError, match="max_contacts must be a whole number"):
        RunInfo(n_segments=1, radii=[0.01], max_contacts=-1)
    with pytest.raises(ValueError, match="force_ref must be > 0 N"):
        RunInfo(n_segments=1, radii=[0.01], force_ref=0.0)


def test_a_recording_without_an_environment_is_as_before():
    """No obstacles and no contact capacity: no contact channel, no contact column, the row
    layout's JSON without C; RunInfo and layouts written before contact read back."""
    info = arm_info()
    assert info.obstacles is None and info.max_contacts == 0
    buf = io.BytesIO()
    with RunLogger(info, buf, quiet=True) as log:
        for r in arm_records(10, dt=1e-2):
            log.log(r)
    buf.seek(0)
    rec = read_recording(buf)
    assert rec.contacts is None and rec.info.obstacles is None and rec.info.max_contacts == 0
    assert len(rec.contact_set(3).segment) == 0 and rec.batch().contacts is None
    buf.seek(0)
    assert {ch.topic for ch in make_reader(buf).get_summary().channels.values()} == set(TOPICS.values())
    old = {k: v for k, v in info.to_json().items() if k not in ("obstacles", "max_contacts", "force_ref")}
    assert RunInfo.from_json(old).obstacles is None
    lay = RecordLayout(9, 9, 9, 3, 12)
    assert lay.to_json() == {"nq": 9, "nv": 9, "np": 9, "n": 3, "P": 12}  # as a journal before contact
    assert RecordLayout.from_json(lay.to_json()) == lay
    withc = RecordLayout(9, 9, 9, 3, 12, 4)
    assert RecordLayout.from_json(withc.to_json()) == withc
    assert withc.row_width == lay.row_width + 4 * CONTACT_WIDTH


def _foxglove(buf, topic):
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate

    buf.seek(0)
    out = []
    for schema, _, msg in make_reader(buf).iter_messages(topics=[topic]):
        assert schema.name == "foxglove.SceneUpdate"
        m = SceneUpdate()
        m.ParseFromString(msg.data)
        out.append((msg.log_time, m))
    return out


def _q(p):
    return np.array([p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w])


def test_foxglove_draws_forces_as_arrows_at_the_points_and_the_obstacles_as_shapes():
    """Decoded with the published schemas (foxglove-schemas-protobuf): one arrow a contact, its
    tail at the contact point, along the force, force_ref drawn a quarter of the reach long;
    the obstacles at the first record's time, lifetime 0 (the whole run), each as its
    primitive, where and as large as recorded (the moving cylinder's law is zero at t = 0)."""
    records, contacts = arm_records(20, dt=1e-2), _contacts(20, seed=5)
    buf = _logged(records, contacts)
    scale = force_scale(reach(_info(), records[0].backbone), FORCE_REF)
    # no segment lengths in params: the reach is the drawn arm's (0.3 m), at least 8 x the radii
    assert scale == pytest.approx(0.25 * max(0.3, 8 * 3 * 0.015) / FORCE_REF)
    forces = _foxglove(buf, CONTACT_TOPICS["forces"])
    assert len(forces) == 20
    for (lt, upd), r, c in zip(forces, records, contacts):
        assert lt == round(r.t * 1e9) and [e.id for e in upd.entities] == ["contact_forces"]
        arrows = upd.entities[0].arrows
        assert len(arrows) == len(c.segment)
        for a, x, f in zip(arrows, c.point, c.force):
            np.testing.assert_allclose([a.pose.position.x, a.pose.position.y, a.pose.position.z], x, rtol=0,
                                       atol=1e-15)
            along = _quat_rot(_q(a.pose))[:, 0]  # an arrow points along its pose's x axis
            np.testing.assert_allclose(along, f / np.linalg.norm(f), atol=1e-12)
            assert a.shaft_length + a.head_length == pytest.approx(np.linalg.norm(f) * scale, rel=1e-12)
    (lt, upd) = _foxglove(buf, CONTACT_TOPICS["obstacles"])[0]
    assert lt == round(records[0].t * 1e9) and records[0].t == 0.0
    e = {x.id: x for x in upd.entities}
    assert list(e) == [f"obstacle_{i}" for i in range(5)]
    assert all(x.lifetime.seconds == 0 and x.lifetime.nanos == 0 and x.frame_id == "world" for x in e.values())
    ground = e["obstacle_0"].cubes[0]  # a wide thin slab whose top face is the plane
    assert ground.pose.position.z + 0.5 * ground.size.z == pytest.approx(-0.01, abs=1e-15)
    assert ground.size.x == ground.size.y >= 4 * 0.3 and ground.size.z < 1e-2 * ground.size.x
    ball = e["obstacle_1"].spheres[0]
    assert (ball.size.x, ball.size.y, ball.size.z) == (0.1, 0.1, 0.1)
    assert (ball.pose.position.x, ball.pose.position.y, ball.pose.position.z) == (0.1, 0.0, 0.2)
    caps = e["obstacle_2"]  # a cylinder between the ends and a ball at each
    assert len(caps.cylinders) == 1 and len(caps.spheres) == 2
    assert caps.cylinders[0].size.z == pytest.approx(0.3) and caps.spheres[1].pose.position.z == 0.3
    pole = e["obstacle_3"].cylinders[0]  # axis (z of the primitive) along a -> b = +y
    np.testing.assert_allclose(_quat_rot(_q(pole.pose))[:, 2], [0.0, 1.0, 0.0], atol=1e-15)
    assert (pole.size.x, pole.size.z) == (pytest.approx(0.06), pytest.approx(0.2))
    assert (pole.pose.position.x, pole.pose.position.y) == (-0.1, pytest.approx(0.1))
    box = e["obstacle_4"].cubes[0]
    np.testing.assert_allclose(_quat_rot(_q(box.pose)), OBSTACLES[4]["rotation"], atol=1e-15)
    assert (box.size.x, box.size.y, box.size.z) == (0.1, 0.2, 0.04)


@pytest.mark.parametrize("how", ["live", "replay"])
def test_rerun_draws_the_obstacles_once_and_the_forces_as_arrows(tmp_path, how):
    """The .rrd of the run (live) and of `qchain replay` holds each obstacle as a static shape
    of its kind, the moving one translated at each record by its law, and, for every record,
    the contact forces as arrows from the contact points (scaled by force_ref) and the points."""
    import rerun as rr

    from qchain.recording.replay import replay

    records, contacts = arm_records(12, dt=1e-2), _contacts(12, seed=7)
    rrd = tmp_path / "run.rrd"
    if how == "live":
        _logged(records, contacts, rrd=rrd)
    else:
        path = tmp_path / "run.mcap"
        _logged(records, contacts, mcap=path)
        assert len(replay(path, rrd=rrd, batch=5).recording) == 12
    cols, _ = _rrd_columns(rrd)
    static = {}
    for chunk in rr.chunk.RrdReader(rrd).stream():
        if chunk.is_static and chunk.entity_path.startswith("/world/obstacles/"):
            static.setdefault(chunk.entity_path, set()).update(chunk.to_record_batch().schema.names)
    kinds = {path: {n.split(":")[0] for n in names if ":" in n} for path, names in static.items()}
    assert {p: {k for k in v if k.endswith("3D")} for p, v in kinds.items()} == {
        "/world/obstacles/0": {"Boxes3D"}, "/world/obstacles/1": {"Ellipsoids3D"},
        "/world/obstacles/2": {"Capsules3D"}, "/world/obstacles/3": {"Cylinders3D"},
        "/world/obstacles/4": {"Boxes3D"}}
    # the moving cylinder: its entity translated at every record by the engine's law, the
    # others never (their shapes are where they are at t = 0)
    assert [p for p in cols if p.startswith("/world/obstacles/")] == ["/world/obstacles/3"]
    pole = cols["/world/obstacles/3"]
    assert pole["step"] == [r.step for r in records] and pole["t"] == [round(r.t * 1e9) for r in records]
    moved = _compiled_move(OBSTACLES[3], [r.t for r in records])
    np.testing.assert_allclose(np.array(pole["translation"]).reshape(-1, 3), moved[:, :3] - OBSTACLES[3]["a"],
                               rtol=0, atol=1e-9)  # (float32 in Rerun: 1e-9 of a 1 cm swing)
    assert np.abs(moved[:, 0] - OBSTACLES[3]["a"][0]).max() > 5e-3
    scale = force_scale(reach(_info(), records[0].backbone), FORCE_REF)
    arrows, points = cols["/world/contacts/forces"], cols["/world/contacts/points"]
    assert arrows["step"] == [r.step for r in records]
    for k, c in enumerate(contacts):
        got_o = np.array(arrows["origins"][k] or np.zeros((0, 3))).reshape(-1, 3)
        got_v = np.array(arrows["vectors"][k] or np.zeros((0, 3))).reshape(-1, 3)
        np.testing.assert_allclose(got_o, c.point, rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(got_v, c.force * scale, rtol=1e-6, atol=1e-7)
        np.testing.assert_allclose(np.array(points["positions"][k] or np.zeros((0, 3))).reshape(-1, 3), c.point,
                                   rtol=1e-6, atol=1e-6)


def test_environment_describe_is_plain_data_of_its_obstacles():
    """Environment.describe(): JSON as it is (no numpy), the shapes' own parameters, motion
    None or its fields; the list is what RunInfo records."""
    from qchain.contact import Box, Capsule, Cylinder, Environment, HalfSpace, Sphere
    from qchain.contact.shapes import Motion

    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    env = Environment([HalfSpace([0, 0, -0.01]), Sphere([0.1, 0, 0.2], 0.05), Capsule([0, 0.1, 0], [0, 0.1, 0.3], 0.02),
                       Cylinder([-0.1, 0, 0], [-0.1, 0.2, 0], 0.03, motion=Motion(amplitude=[0.01, 0, 0], frequency=2.0)),
                       Box([0.2, 0.2, 0.1], [0.05, 0.1, 0.02], R)])
    d = env.describe()
    assert json.loads(json.dumps(d)) == d == OBSTACLES
    info = RunInfo(n_segments=1, radii=[0.01], obstacles=d, max_contacts=16 * len(d))
    assert RunInfo.from_json(json.loads(json.dumps(info.to_json()))).obstacles == OBSTACLES


@pytest.mark.slow
def test_the_recorder_records_the_chains_contacts_each_sample():
    """A short run of an arm pressed against a ceiling, recorded through ChainRecorder with
    contacts=chain.contacts: each record's contacts are Chain.contacts at the recorded (t, q, v),
    recomputed independently after the run; the ceiling does push (contacts are there)."""
    from support import SEGMENT

    from qchain import Chain, Segment
    from qchain.contact import ContactLaw, Environment, HalfSpace
    from qchain.recording.recorder import ChainRecorder, series_names
    from qchain.sim.simulation import simulate

    ch = Chain([Segment(**SEGMENT) for _ in range(2)], gravity=[0.0, 0.0, -9.81])
    q0 = ch.neutral()
    # standing straight up (tip at z = 0.2 m) under a ceiling 2 mm lower than the tube's top
    env = Environment([HalfSpace([0.0, 0.0, 0.2], [0.0, 0.0, -1.0])], ContactLaw(stiffness=1e5, damping=1.0),
                      nodes=8)
    assert len(ch.contacts(q0, np.zeros(ch.nv), env).segment) > 0
    qn, vn = series_names(ch)
    info = RunInfo(n_segments=2, radii=[s.radius for s in ch.segments], q_names=qn, v_names=vn,
                   obstacles=env.describe(), max_contacts=ch.n * env.nodes * len(env.obstacles))
    buf = io.BytesIO()
    with warnings.catch_warnings():
        warnings.simplefilter("error", LoggingWarning)  # nothing dropped: the capacity holds them all
        with RunLogger(info, buf, quiet=True) as log, \
                ChainRecorder(log, ch, contacts=lambda t, q, v: ch.contacts(q, v, env, t)) as rec:
            traj = simulate(ch, q0, np.zeros(ch.nv), (0.0, 0.02), method="dopri5", env=env,
                            t_eval=np.linspace(0.0, 0.02, 11), on_sample=rec)
    assert traj.success
    buf.seek(0)
    r = read_recording(buf)
    assert len(r) == 11 and r.info.obstacles == env.describe()
    assert len(r.contact_set(0).segment) > 0
    for k in range(11):
        want = ch.contacts(r.q[k], r.v[k], env, t=float(r.t[k]))
        got = r.contact_set(k)
        for name in ("point", "normal", "force", "segment", "obstacle"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=name)


def test_the_foxglove_layout_shows_the_obstacles_and_forces_of_a_contact_run():
    """The 3D panel of a run with an environment draws /qchain/obstacles and
    /qchain/contact_forces with the arm; a run without one's layout does not name them."""
    from qchain.logging import foxglove_layout

    def topics(info):
        layout = json.loads(foxglove_layout(info, 9, 9, 9).to_json())
        found = []

        def walk(x):
            if isinstance(x, dict):
                if "topics" in x and isinstance(x["topics"], dict):
                    found.append(x["topics"])
                for v in x.values():
                    walk(v)
            elif isinstance(x, list):
                for v in x:
                    walk(v)

        walk(layout)
        assert len(found) == 1
        return found[0]

    with_env = topics(_info())
    assert with_env[CONTACT_TOPICS["obstacles"]]["visible"] is True
    assert with_env[CONTACT_TOPICS["forces"]]["visible"] is True
    assert with_env[TOPICS["arm"]]["visible"] is True
    assert not set(CONTACT_TOPICS.values()) & set(topics(arm_info()))


def test_a_killed_runs_contacts_come_back_from_its_journal_and_recover_keeps_them(tmp_path):
    """A killed run's file (cut after its last chunk, a chunk inside damaged) and its journal
    (rows with the contacts): reading merges the journal's records with their contacts, and
    `recover` writes a whole recording holding every record's contacts."""
    from support import write_journal

    from qchain.logging import recover
    from qchain.recording.journal import journal_path
    from qchain.recording.mcap_sink import info_metadata
    from qchain.recording.scan import scan

    records, contacts = arm_records(60, dt=1e-2), _contacts(60, seed=11)
    info = _info()
    data = _logged(records, contacts, info=info, flush_interval=0.05).getvalue()
    whole = read_recording(io.BytesIO(data))
    chunks = [it for it in scan(data) if it.kind == "chunk"]
    assert len(chunks) >= 6
    cut = bytearray(data[: chunks[-1].end])  # no summary, no footer: as a killed run leaves it
    cut[chunks[1].offset + 60] ^= 0x10  # a chunk inside lost to a flipped bit
    path = tmp_path / "run.mcap"
    path.write_bytes(bytes(cut))
    b = whole.batch()
    write_journal(path, b.rows(), b.layout, info_metadata(info, whole.metadata["recording_id"]))
    assert b.layout.C == MAX_CONTACTS
    rec = read_recording(path)
    assert rec.recovered > 0 and not rec.gaps and len(rec) == 60
    _assert_contacts_equal(rec, contacts)
    recover(path)
    assert not journal_path(path).exists()
    again = read_recording(path)
    assert not again.truncated and not again.gaps and again.info.obstacles == OBSTACLES
    _assert_contacts_equal(again, contacts)


def test_the_shapes_orientations_turn_their_axes_where_the_obstacles_say():
    """quat_from_matrix gives back the matrix (random rotations and half turns, where the
    trace is -1), quat_between turns a onto b (opposite directions too)."""
    from scipy.spatial.transform import Rotation

    from qchain.recording.scenery import quat_between, quat_from_matrix

    mats = list(Rotation.random(200, random_state=3).as_matrix())
    mats += [np.diag(d) for d in ([1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0])]
    for R in mats:
        np.testing.assert_allclose(_quat_rot(quat_from_matrix(R)), R, atol=1e-12)
    rng = np.random.default_rng(4)
    for a, b in [*rng.normal(size=(50, 2, 3)), ([0, 0, 1.0], [0, 0, -1.0]), ([1.0, 0, 0], [-2.0, 0, 0])]:
        got = _quat_rot(quat_between(a, b)) @ (np.asarray(a) / np.linalg.norm(a))
        np.testing.assert_allclose(got, np.asarray(b) / np.linalg.norm(b), atol=1e-12)


def _compiled_move(ob: dict, t) -> np.ndarray:
    """The obstacle ``ob`` (RunInfo.obstacles form) moved to the times ``t`` (K,) by the
    engine's compiled ``qchain.contact.distance.move``: its parameter rows (K, PARAMS)."""
    from qchain.contact.distance import CAPSULE, CYLINDER, MOTION, PARAMS, SPHERE, move

    kind = {"sphere": SPHERE, "capsule": CAPSULE, "cylinder": CYLINDER}[ob["type"]]
    row = np.zeros((1, PARAMS))
    if kind == SPHERE:
        row[0, :4] = [*ob["center"], ob["radius"]]
    else:
        row[0, :7] = [*ob["a"], *ob["b"], ob["radius"]]
    mo = np.zeros((1, MOTION))
    m = ob["motion"]
    mo[0] = [*m["velocity"], *m["amplitude"], m["frequency"], m["phase"]]
    out = []
    for tk in np.atleast_1d(t):
        prm_t, vel = np.empty((1, PARAMS)), np.empty((1, 3))
        move(np.array([kind]), row, mo, float(tk), prm_t, vel)
        out.append(prm_t[0].copy())
    return np.array(out)


def test_the_viewers_motion_law_is_the_engines():
    """scenery.motion_offset (numpy, for the writer process and replays) gives the translation
    the compiled engine moves an obstacle by (qchain.contact.distance.move), for drifting and
    oscillating motions over long times; None is at rest."""
    from qchain.recording.scenery import motion_offset

    rng = np.random.default_rng(12)
    t = np.concatenate([[0.0], np.sort(rng.uniform(0.0, 50.0, 200))])
    for _ in range(20):
        m = {"velocity": rng.normal(size=3).tolist(), "amplitude": rng.uniform(-0.1, 0.1, 3).tolist(),
             "frequency": float(rng.uniform(0.0, 20.0)), "phase": float(rng.uniform(-np.pi, np.pi))}
        ob = {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": 0.1, "motion": m}
        want = _compiled_move(ob, t)[:, :3]
        got = motion_offset(m, t)
        np.testing.assert_allclose(got, want, rtol=0, atol=4 * np.finfo(float).eps * max(1.0, np.abs(want).max()))
        assert np.abs(got).max() > 0.0
    np.testing.assert_array_equal(motion_offset(None, t), np.zeros((t.size, 3)))


def test_a_bad_motion_law_is_refused_where_runinfo_takes_it():
    base = {"type": "sphere", "center": [0.0, 0.0, 0.0], "radius": 0.1}
    good = {"velocity": [0.0, 0.0, 0.0], "amplitude": [0.01, 0.0, 0.0], "frequency": 1.0, "phase": 0.0}
    RunInfo(n_segments=1, radii=[0.01], obstacles=[{**base, "motion": good}])
    for key, value, said in (("velocity", [0.0, 1.0], "3 finite numbers"),
                             ("amplitude", [0.0, float("nan"), 0.0], "3 finite numbers"),
                             ("frequency", "2", "a finite number"), ("phase", None, "a finite number")):
        with pytest.raises(ValueError, match=f"obstacles\\[1\\]\\['motion'\\]\\['{key}'\\] must be {said}, got"):
            RunInfo(n_segments=1, radii=[0.01],
                    obstacles=[{**base, "motion": None}, {**base, "motion": {**good, key: value}}])
    with pytest.raises(ValueError, match="obstacles\\[0\\]\\['motion'\\] must be None or a dict"):
        RunInfo(n_segments=1, radii=[0.01], obstacles=[{**base, "motion": [1.0, 2.0]}])


def test_foxglove_moves_a_moving_obstacle_each_record_and_draws_fixed_ones_once():
    """With a moving obstacle, /qchain/obstacles holds a scene update a record (what Foxglove
    shows after a seek is the topic's last message, so each holds every obstacle): the
    cylinder's centre is where the engine's law moves its axis at that record's time, the
    fixed obstacles stay where they are; a moving capsule's end balls go with it. Without a
    moving obstacle, a single message."""
    records, contacts = arm_records(25, dt=1.7e-2), _contacts(25, seed=8)
    buf = _logged(records, contacts)
    msgs = _foxglove(buf, CONTACT_TOPICS["obstacles"])
    assert [lt for lt, _ in msgs] == [round(r.t * 1e9) for r in records]
    first = {e.id: e for e in msgs[0][1].entities}
    moved = _compiled_move(OBSTACLES[3], [r.t for r in records])
    assert np.abs(moved[:, 0] - OBSTACLES[3]["a"][0]).max() > 5e-3  # it does move (by up to 1 cm)
    for (lt, upd), prm in zip(msgs, moved):
        e = {x.id: x for x in upd.entities}
        assert list(e) == [f"obstacle_{i}" for i in range(5)]
        assert all(x.lifetime.seconds == 0 and x.lifetime.nanos == 0 for x in e.values())
        pole = e["obstacle_3"].cylinders[0].pose.position
        np.testing.assert_allclose([pole.x, pole.y, pole.z], 0.5 * (prm[0:3] + prm[3:6]), rtol=0, atol=1e-15)
        for i in (0, 1, 2, 4):
            assert _prims(e[f"obstacle_{i}"]) == _prims(first[f"obstacle_{i}"])
    # a moving capsule: its cylinder and both end balls go along
    drift = {"velocity": [0.0, 0.3, -0.1], "amplitude": [0.0, 0.0, 0.02], "frequency": 3.0, "phase": 0.5}
    caps = dict(OBSTACLES[2], motion=drift)
    msgs = _foxglove(_logged(arm_records(10, dt=2e-2), _contacts(10, seed=9),
                             info=_info(obstacles=[*OBSTACLES[:2], caps, *OBSTACLES[3:]])), CONTACT_TOPICS["obstacles"])
    moved = _compiled_move(caps, [r.t for r in arm_records(10, dt=2e-2)])
    assert len(msgs) == 10 and np.abs(moved[-1, :3] - caps["a"]).max() > 0.05
    for (_, upd), prm in zip(msgs, moved):
        e = {x.id: x for x in upd.entities}["obstacle_2"]
        got = [[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in (*e.cylinders, *e.spheres)]
        np.testing.assert_allclose(got, [0.5 * (prm[0:3] + prm[3:6]), prm[0:3], prm[3:6]], rtol=0, atol=1e-15)
    fixed = _info(obstacles=[dict(ob, motion=None) for ob in OBSTACLES])
    msgs = _foxglove(_logged(arm_records(25, dt=1.7e-2), _contacts(25, seed=8), info=fixed),
                     CONTACT_TOPICS["obstacles"])
    assert len(msgs) == 1 and msgs[0][0] == 0


def _prims(entity):
    """A scene entity's primitives (everything but its timestamp), serialised."""
    return [p.SerializeToString() for kind in ("cubes", "spheres", "cylinders") for p in getattr(entity, kind)]
