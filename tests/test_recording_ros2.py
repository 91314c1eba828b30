"""A recording as a ROS 2 bag (qchain.recording.ros2, ``qchain export``, ``qchain run --ros2``):
written with mcap-ros2-support, read back by an independent reader (rosbags' MCAP storage
and CDR deserialiser) with every message intact; a bag is whole or not there."""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pytest
from logging_fixtures import arm_records
from mcap.reader import make_reader
from test_recording_contacts import OBSTACLES, _contacts, _info, _logged

from qchain.cli.main import main
from qchain.logging import ROS2_TOPICS, export_ros2, read_recording

K = 40


def _ros2_messages(path: Path) -> dict[str, list]:
    """Every message of the bag by topic, as (log time ns, message), deserialised by rosbags."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    out: dict[str, list] = {}
    with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types == ROS2_TOPICS
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    return out


@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    """A recording of K records with obstacles (one of them moving) and contacts, and its bag."""
    folder = tmp_path_factory.mktemp("ros2")
    rec_path, bag = folder / "run.mcap", folder / "run-ros2.mcap"
    names = [(f"segment {i + 1} {c} [{u}]", f"segment {i + 1} d{c}/dt [{u}/s]") for i in range(3)
             for c, u in (("l", "m"), ("ux", "1/m"), ("uy", "1/m"))]
    info = _info(q_names=[a for a, _ in names], v_names=[b for _, b in names])
    rec_path.write_bytes(_logged(arm_records(K, dt=1e-2), _contacts(K), info=info).getvalue())
    count = export_ros2(rec_path, bag)
    return read_recording(rec_path), bag, count


def _quat_matrix(q) -> np.ndarray:
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_every_record_comes_back_from_the_bag_through_rosbags(recorded):
    rec, bag, count = recorded
    msgs = _ros2_messages(bag)
    n = rec.info.n_segments
    assert count == 4 * K and {t: len(m) for t, m in msgs.items()} == {t: K for t in ROS2_TOPICS}
    for k in range(K):
        lt = round(rec.t[k] * 1e9)
        # coordinates and rates, bit for bit (CDR float64), named per segment
        t, js = msgs["/joint_states"][k]
        assert t == lt and js.header.stamp.sec * 10**9 + js.header.stamp.nanosec == lt
        assert list(js.name) == [f"segment_{i + 1}_{c}" for i in range(n) for c in ("l", "ux", "uy")]
        np.testing.assert_array_equal(js.position, rec.q[k, -3 * n:])
        np.testing.assert_array_equal(js.velocity, rec.v[k, -3 * n:])
        t, pr = msgs["/qchain/pressures"][k]
        assert t == lt and list(pr.name) == [f"segment_{i + 1}_chamber_{j + 1}" for i in range(n) for j in range(3)]
        np.testing.assert_array_equal(pr.effort, rec.p[k])
        # the frame tree composed from world: each tip's world placement as recorded
        t, tf = msgs["/tf"][k]
        X = {"world": (np.eye(3), np.zeros(3))}
        for tr in tf.transforms:
            R0, p0 = X[tr.header.frame_id]
            r, p = tr.transform.rotation, tr.transform.translation
            X[tr.child_frame_id] = (R0 @ _quat_matrix((r.x, r.y, r.z, r.w)), p0 + R0 @ np.array([p.x, p.y, p.z]))
        np.testing.assert_allclose(X["base"][1], rec.base[k, :3], atol=1e-15)
        for i in range(n):
            R, p = X[f"segment_{i + 1}_tip"]
            np.testing.assert_allclose(p, rec.tip_frames[k, i, :3], atol=1e-14)
            np.testing.assert_allclose(R, _quat_matrix(rec.tip_frames[k, i, 3:]), atol=1e-13)
        # the backbone as line strips, as recorded, and the obstacles
        t, ma = msgs["/qchain/markers"][k]
        strips = [m for m in ma.markers if m.ns == "backbone"]
        assert [m.id for m in strips] == list(range(n)) and all(m.type == 4 for m in strips)
        for i, m in enumerate(strips):
            np.testing.assert_array_equal([[p.x, p.y, p.z] for p in m.points], rec.backbone[k, i])
            assert m.scale.x == 2 * rec.info.radii[i] and m.header.frame_id == "world"


def test_the_obstacles_are_markers_and_the_moving_one_follows_its_law(recorded):
    rec, bag, _ = recorded
    msgs = _ros2_messages(bag)["/qchain/markers"]
    for k in (0, 7, K - 1):
        obs = {m.id: m for m in msgs[k][1].markers if m.ns == "obstacles"}
        sphere = obs[3 * 1]
        assert sphere.type == 2 and sphere.scale.x == 2 * OBSTACLES[1]["radius"]
        assert [sphere.pose.position.x, sphere.pose.position.y, sphere.pose.position.z] == OBSTACLES[1]["center"]
        capsule_ends = [obs[3 * 2 + 1], obs[3 * 2 + 2]]  # the capsule's two balls at its ends
        assert [[m.pose.position.x, m.pose.position.y, m.pose.position.z] for m in capsule_ends] == \
            [OBSTACLES[2]["a"], OBSTACLES[2]["b"]]
        # the cylinder moves: amplitude 0.01 m along x at 2 Hz; its marker is at the midpoint of its axis
        cyl, m = OBSTACLES[3], OBSTACLES[3]["motion"]
        shift = m["amplitude"][0] * math.sin(2 * math.pi * m["frequency"] * rec.t[k] + m["phase"])
        mid = 0.5 * (np.array(cyl["a"]) + np.array(cyl["b"])) + [shift, 0.0, 0.0]
        c = obs[3 * 3]
        assert c.type == 3
        np.testing.assert_allclose([c.pose.position.x, c.pose.position.y, c.pose.position.z], mid, atol=1e-15)
        assert obs[3 * 4].type == 1  # the box


def test_the_bag_is_a_ros2_profile_mcap_with_the_runs_description(recorded):
    rec, bag, _ = recorded
    with open(bag, "rb") as fh:
        reader = make_reader(fh)
        assert reader.get_header().profile == "ros2"
        schemas = {s.name: s.encoding for s in reader.get_summary().schemas.values()}
        assert schemas == {t: "ros2msg" for t in ROS2_TOPICS.values()}
        assert {c.message_encoding for c in reader.get_summary().channels.values()} == {"cdr"}
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert meta["qchain"] == rec.metadata  # the recording's sealed description, as it is


def test_export_refuses_bad_paths_and_leaves_nothing_half_written(recorded, tmp_path):
    rec, bag, _ = recorded
    with pytest.raises(ValueError, match=r"out must be an \.mcap file .* got '.*bag\.db3'"):
        export_ros2(rec.path, tmp_path / "bag.db3")
    with pytest.raises(ValueError, match="out is the recording itself"):
        export_ros2(rec.path, rec.path)
    # an unreadable recording: an earlier bag at the output stays as it was, no temporary file is left
    broken = tmp_path / "broken.mcap"
    broken.write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 100)
    out = tmp_path / "old.mcap"
    out.write_bytes(b"an earlier bag")
    with pytest.raises(Exception) as err:
        export_ros2(broken, out)
    assert "broken.mcap" in str(err.value)
    assert out.read_bytes() == b"an earlier bag" and sorted(p.name for p in tmp_path.iterdir()) == \
        ["broken.mcap", "old.mcap"]


def test_qchain_export_writes_the_bag_and_says_so(recorded, tmp_path, capsys):
    rec, bag, count = recorded
    out = tmp_path / "cli.mcap"
    assert main(["export", rec.path, "-o", str(out)]) == 0
    assert f"wrote {out} (ROS 2 bag, {count} messages)" in capsys.readouterr().out
    assert {t: len(m) for t, m in _ros2_messages(out).items()} == {t: K for t in ROS2_TOPICS}
    assert main(["export", str(tmp_path / "missing.mcap"), "-o", str(tmp_path / "x.mcap")]) == 2
    assert "qchain export: error:" in capsys.readouterr().err and not (tmp_path / "x.mcap").exists()
    assert main(["export", rec.path, "-o", rec.path]) == 2
    assert "is the recording" in capsys.readouterr().err


def test_run_refuses_a_ros2_bag_it_could_not_write(tmp_path, capsys):
    scene = Path(__file__).parents[1] / "examples" / "scenes" / "wave_arm.toml"
    assert main(["run", str(scene), "--ros2", str(tmp_path / "bag.txt"), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert "--ros2" in err and "name it *.mcap" in err
    assert main(["run", str(scene), "--ros2", str(tmp_path / "bag.mcap"), "--no-record", "--no-plots"]) == 2
    assert "--ros2 is written from the run's recording" in capsys.readouterr().err
    rec = tmp_path / "run.mcap"
    assert main(["run", str(scene), "--ros2", str(rec), "--mcap", str(rec), "--no-plots"]) == 2
    assert "--ros2" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


@pytest.mark.slow
def test_qchain_run_writes_the_ros2_bag_of_its_recording(tmp_path, capsys):
    scene = Path(__file__).parents[1] / "examples" / "scenes" / "arm_on_ground.toml"
    mcap, bag = tmp_path / "ground.mcap", tmp_path / "ground-ros2.mcap"
    assert main(["run", str(scene), "--duration", "0.2", "--mcap", str(mcap), "--ros2", str(bag), "--no-plots",
                 "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert f"wrote {bag} (ROS 2 bag, {4 * 21} messages)" in out
    rec = read_recording(mcap)
    msgs = _ros2_messages(bag)
    np.testing.assert_array_equal([m.position for _, m in msgs["/joint_states"]], rec.q)
    ground = [m for m in msgs["/qchain/markers"][0][1].markers if m.ns == "obstacles"]
    assert len(ground) == 1 and ground[0].type == 1  # the half-space as a thin box


def test_a_bag_round_trips_through_bytes_too(tmp_path):
    """write_ros2 on a stream (BytesIO): those bytes, as a file, read back by rosbags."""
    from qchain.recording.ros2 import write_ros2

    rec = read_recording(_logged(arm_records(5, dt=1e-2), _contacts(5)))
    out = io.BytesIO()
    assert write_ros2(rec, rec.info, out) == 20
    (tmp_path / "b.mcap").write_bytes(out.getvalue())
    js = _ros2_messages(tmp_path / "b.mcap")["/joint_states"]
    np.testing.assert_array_equal([m.position for _, m in js], rec.q)
