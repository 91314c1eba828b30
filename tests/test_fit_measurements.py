"""Measurements for the fit (qchain.fit.measurements): read from ROS 2 bags (MCAP written by
qchain's BagWriter, SQLite written by rosbags' own writer), from /tf of a qchain bag, from
qchain recordings and CSV; put on one clock; and every bad input said where it enters."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from test_recording_ros2 import recorded  # noqa: F401  (the module fixture: a recording and its bag)

from qchain.fit import MeasurementError, MeasurementWarning, bag_topics, read_bag, read_csv, read_qchain
from qchain.recording.ros2 import BagWriter, stamp

T0 = 1_700_000_000.0  # s: a wall-clock epoch, as a real recorder stamps


def _mocap_bag(path: Path, t_pose, pos, t_p, p, *, pose_topic="/mocap/tip", quat=None, names=None, stamps=None):
    """A bag as a lab would record it: PoseStamped from motion capture, JointState pressures;
    ``stamps`` the poses' header stamps where they differ from their log times ``t_pose``."""
    with open(path, "wb") as fh:
        w = BagWriter(fh)
        names = names or [f"chamber_{k}" for k in range(p.shape[1])]
        for k, t in enumerate(t_p):
            w.write("/pressures", "sensor_msgs/msg/JointState", T0 + t,
                    {"header": {"stamp": stamp(T0 + t), "frame_id": ""}, "name": names, "effort": list(p[k])})
        for k, t in enumerate(t_pose):
            o = quat[k] if quat is not None else (0.0, 0.0, 0.0, 1.0)
            st = t if stamps is None else stamps[k]
            w.write(pose_topic, "geometry_msgs/msg/PoseStamped", T0 + t,
                    {"header": {"stamp": stamp(T0 + st), "frame_id": "world"},
                     "pose": {"position": dict(zip("xyz", map(float, pos[k]))),
                              "orientation": dict(zip("xyzw", map(float, o)))}})
        w.finish()
    return path


def _streams(K=101, Kp=51, delay=0.013):
    t_pose = delay + np.arange(K) * 0.01  # 100 Hz, starting after the pressures
    t_p = np.arange(Kp) * 0.02  # 50 Hz
    pos = np.stack([0.1 * np.sin(t_pose), 0.01 * t_pose, 0.25 - 0.01 * t_pose], axis=1)
    p = np.stack([1e3 * t_p, 2e3 * t_p, 3e3 * t_p], axis=1)
    return t_pose, pos, t_p, p


def test_a_mocap_bag_reads_back_on_the_pressures_clock(tmp_path):
    t_pose, pos, t_p, p = _streams()
    bag = _mocap_bag(tmp_path / "lab.mcap", t_pose, pos, t_p, p)
    assert bag_topics(bag) == {"/pressures": "sensor_msgs/msg/JointState",
                               "/mocap/tip": "geometry_msgs/msg/PoseStamped"}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the poses after the last pressure sample are said:
        with pytest.raises(MeasurementWarning, match=r"2 measured samples outside the pressures' span \[0, 1\] s"):
            read_bag(bag, pressure_topic="/pressures", pose_topic="/mocap/tip")
    with pytest.warns(MeasurementWarning, match="outside the pressures' span"):
        m = read_bag(bag, pressure_topic="/pressures", pose_topic="/mocap/tip")
    # the first pressure sample is t = 0; stamps kept to the ns (a float of 1.7e9 s holds 0.2 us)
    np.testing.assert_allclose(m.t, t_pose[:-2], atol=1e-6)
    np.testing.assert_array_equal(m.points[:, 0], pos[:-2])
    assert m.where == ((-1, 1.0),) and m.orientations is None and m.n_values == 3 * 99
    np.testing.assert_allclose(m.pressures(0.5), [500.0, 1000.0, 1500.0], rtol=1e-6)
    np.testing.assert_allclose(m.pressures.times, t_p, atol=1e-6)
    # a window, and the pressures in another order by name
    m2 = read_bag(bag, pressure_topic="/pressures", pose_topic="/mocap/tip", start=0.2, stop=0.6,
                  pressure_names=["chamber_2", "chamber_1", "chamber_0"])
    # the poses in [0.2, 0.6] s (0.203 .. 0.593); the run starts at the pressure sample at or before 0.2 s
    assert m2.n_samples == 40 and 0.0 < m2.t[0] <= 0.02 + 0.013 + 1e-6
    first = 0.203
    np.testing.assert_allclose(m2.pressures(m2.t[0]), [3e3 * first, 2e3 * first, 1e3 * first], rtol=1e-5)


def test_a_sqlite_bag_written_by_rosbags_reads_the_same(tmp_path):
    """The same streams in a bag folder with SQLite storage, written by rosbags' own writer."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    JointState, PoseStamped = ts.types["sensor_msgs/msg/JointState"], ts.types["geometry_msgs/msg/PoseStamped"]
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    Pose, Point, Quat = (ts.types[f"geometry_msgs/msg/{n}"] for n in ("Pose", "Point", "Quaternion"))
    t_pose, pos, t_p, p = _streams(K=50)
    folder = tmp_path / "lab_bag"
    with Writer(folder, version=8, storage_plugin=StoragePlugin.SQLITE3) as w:
        cp = w.add_connection("/pressures", JointState.__msgtype__, typestore=ts)
        cm = w.add_connection("/vicon/tip", PoseStamped.__msgtype__, typestore=ts)
        msgs = [(T0 + t, cp, JointState(Header(Time(int(T0 + t), round((t % 1) * 1e9)), ""), ["a", "b", "c"],
                                         np.zeros(0), np.zeros(0), p[k].copy())) for k, t in enumerate(t_p)]
        msgs += [(T0 + t, cm, PoseStamped(Header(Time(int(T0 + t), round((t % 1) * 1e9)), "world"),
                                          Pose(Point(*pos[k]), Quat(0.0, 0.0, 0.0, 1.0))))
                 for k, t in enumerate(t_pose)]
        for t, c, msg in sorted(msgs, key=lambda x: x[0]):
            w.write(c, int(round(t * 1e9)), ts.serialize_cdr(msg, c.msgtype))
    m = read_bag(folder, pressure_topic="/pressures", pose_topic="/vicon/tip")
    np.testing.assert_allclose(m.t, t_pose, atol=1e-6)
    np.testing.assert_array_equal(m.points[:, 0], pos)
    np.testing.assert_allclose(m.pressures.values, p)


def test_a_qchain_bags_tf_tree_gives_the_recorded_tip(recorded):  # noqa: F811
    rec, bag, _ = recorded
    n = rec.info.n_segments
    m = read_bag(bag, pressure_topic="/qchain/pressures", tf=("world", f"segment_{n}_tip"), orientation=True)
    np.testing.assert_allclose(m.t, rec.t, atol=1e-9)
    np.testing.assert_allclose(m.points[:, 0], rec.tip_frames[:, -1, :3], atol=1e-14)
    sign = np.sign(np.sum(m.orientations * rec.tip_frames[:, -1, 3:], axis=1))[:, None]
    np.testing.assert_allclose(sign * m.orientations, rec.tip_frames[:, -1, 3:], atol=1e-13)
    np.testing.assert_array_equal(m.pressures.values, rec.p)
    # the recording itself: the same tip, and the coordinates
    m2 = read_qchain(rec.path)
    np.testing.assert_array_equal(m2.points[:, 0], rec.tip_frames[:, -1, :3])
    m3 = read_qchain(rec.path, measure="coordinates")
    np.testing.assert_array_equal(m3.coordinates, rec.q)


def test_a_bag_without_the_topic_lists_the_topics_it_has(tmp_path, recorded):  # noqa: F811
    t_pose, pos, t_p, p = _streams()
    bag = _mocap_bag(tmp_path / "lab.mcap", t_pose, pos, t_p, p)
    with pytest.raises(MeasurementError, match=r"no topic '/tip_pose'; the bag has: /mocap/tip "
                                               r"\(geometry_msgs/msg/PoseStamped\), /pressures \(sensor_msgs/msg/JointState\)"):
        read_bag(bag, pressure_topic="/pressures", pose_topic="/tip_pose")
    with pytest.raises(MeasurementError, match=r"topic '/pressures' is sensor_msgs/msg/JointState, expected "
                                               r"geometry_msgs/msg/PoseStamped"):
        read_bag(bag, pressure_topic="/pressures", pose_topic="/pressures")
    with pytest.raises(MeasurementError, match=r"no topic '/tf'"):
        read_bag(bag, pressure_topic="/pressures", tf=("world", "tip"))
    _, qbag, _ = recorded
    with pytest.raises(MeasurementError, match=r"no message holds the chain 'world' -> 'tool0' \(its frames: "
                                               r"\['base', 'segment_1_tip'"):
        read_bag(qbag, pressure_topic="/qchain/pressures", tf=("world", "tool0"))
    with pytest.raises(MeasurementError, match="no such bag"):
        read_bag(tmp_path / "none.mcap", pressure_topic="/p", pose_topic="/x")
    with pytest.raises(MeasurementError, match="give pose_topic .* or tf=.*one of them"):
        read_bag(bag, pressure_topic="/pressures")
    with pytest.raises(MeasurementError, match="no joint 'chamber_9'"):
        read_bag(bag, pressure_topic="/pressures", pose_topic="/mocap/tip", pressure_names=["chamber_9"])


def test_timestamps_that_go_back_are_refused_naming_the_samples(tmp_path):
    t_pose, pos, t_p, p = _streams()
    stamps = t_pose.copy()
    stamps[40] = stamps[38]  # received in order, stamped back by the sender's clock
    bag = _mocap_bag(tmp_path / "back.mcap", t_pose, pos, t_p, p, stamps=stamps)
    with pytest.raises(MeasurementError, match=r"measurement timestamps go back: sample 40 at 1700000000\.393000 s "
                                               r"after sample 39 at 1700000000\.403000 s"):
        read_bag(bag, pressure_topic="/pressures", pose_topic="/mocap/tip")
    t_p = t_p.copy()
    t_p[5] = t_p[4]
    bag = _mocap_bag(tmp_path / "rep.mcap", _streams()[0], pos, t_p, p)
    with pytest.raises(MeasurementError, match=r"pressure timestamps repeat: sample 5"):
        read_bag(bag, pressure_topic="/pressures", pose_topic="/mocap/tip")


def test_nan_markers_are_left_out_and_said_and_gaps_are_said(tmp_path):
    t_pose, pos, t_p, p = _streams()
    pos = pos.copy()
    pos[10:13, 1] = np.nan  # the marker lost for three frames
    keep = np.r_[0:60, 90:100]  # and a 0.3 s gap
    bag = _mocap_bag(tmp_path / "nan.mcap", t_pose[keep], pos[keep], t_p, p)
    with pytest.warns(MeasurementWarning) as got:
        m = read_bag(bag, pressure_topic="/pressures", pose_topic="/mocap/tip")
    said = " | ".join(str(w.message) for w in got)
    assert "3 of 70 measured samples have NaN or infinite values and are left out (the first at t = 0.113 s)" in said
    assert "1 gaps in the measured samples longer than 10 x their median interval (0.01 s); the longest 0.31 s" in said
    assert m.n_samples == 70 - 3 - 1 and np.all(np.isfinite(m.points))  # the last is after the pressures
    pos[:] = np.nan
    bag = _mocap_bag(tmp_path / "allnan.mcap", t_pose, pos, t_p, p)
    with pytest.raises(MeasurementError, match="every measured sample has a NaN"):
        read_bag(bag, pressure_topic="/pressures", pose_topic="/mocap/tip")


def test_units_that_cannot_match_the_model_and_too_few_samples_are_refused(tmp_path):
    from qchain import Chain, Segment

    seg = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085,
               youngs_modulus=1e5, damping=0.01)
    arm = Chain([Segment(**seg) for _ in range(3)], base="fixed", gravity=(0, 0, -9.81))
    t_pose, pos, t_p, p = _streams()
    p9 = np.repeat(p, 3, axis=1)
    m = read_bag(_mocap_bag(tmp_path / "m.mcap", t_pose[:-1], pos[:-1], t_p, p9), pressure_topic="/pressures",
                 pose_topic="/mocap/tip")
    m.check_model(arm)  # within the 0.3 m arm's reach
    mm = read_bag(_mocap_bag(tmp_path / "mm.mcap", t_pose[:-1], 1e3 * pos[:-1], t_p, p9),
                  pressure_topic="/pressures", pose_topic="/mocap/tip")
    with pytest.raises(MeasurementError, match=r"the measured point 0 is 2\d\d\.?\d* m from the base at t = .* s, and "
                                               r"the arm is 0\.3 m long .*units that do not match \(mm for m\?\)"):
        mm.check_model(arm)
    m3 = read_bag(_mocap_bag(tmp_path / "p3.mcap", t_pose[:-1], pos[:-1], t_p, p), pressure_topic="/pressures",
                  pose_topic="/mocap/tip")
    with pytest.raises(MeasurementError, match="3 pressures a sample, the model has 9 chambers"):
        m3.check_model(arm)
    assert m.n_values == 3 * 99  # the last pose is after the last pressure sample
    m.check_enough(148)
    with pytest.raises(MeasurementError, match=r"99 samples \(297 measured numbers\) are too few for 149 parameters"):
        m.check_enough(149)


def test_csv_measurements_in_mm_with_a_missing_cell(tmp_path):
    t_pose, pos, _, _ = _streams(K=30, delay=0.0)
    lines = ["time,x_mm,y_mm,z_mm,p1,p2,p3"]
    for k, t in enumerate(t_pose):
        x, y, z = 1e3 * pos[k]
        lines.append(f"{float(t)!r},{float(x)!r},{'' if k == 4 else repr(float(y))},{float(z)!r},{1e3 * t},0,0")
    path = tmp_path / "lab.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.warns(MeasurementWarning, match="1 of 30 measured samples have NaN"):
        m = read_csv(path, time="time", points=[("x_mm", "y_mm", "z_mm")], pressures=["p1", "p2", "p3"], scale=1e-3)
    assert m.n_samples == 29
    np.testing.assert_allclose(m.points[:, 0], np.delete(pos, 4, axis=0), rtol=1e-15, atol=1e-18)
    with pytest.raises(MeasurementError, match=r"no column 'p4'; the columns: \['time', 'x_mm'"):
        read_csv(path, time="time", points=[("x_mm", "y_mm", "z_mm")], pressures=["p4"])
    path.write_text("time,x,y,z,p\n0,1,2,3,4\n0.1,abc,2,3,4\n")
    with pytest.raises(MeasurementError, match=r"line 3, column 'x': 'abc' is not a number"):
        read_csv(path, time="time", points=[("x", "y", "z")], pressures=["p"])


def test_the_pressure_sensors_noise_is_estimated_from_the_signal_itself():
    """10-30 kPa swept at 0.8 Hz (the example's drive), sampled at 100 Hz for 20 s: a white noise
    of 300 Pa on one chamber and 100 Pa on another is found within 10 %, a clean chamber
    reads below 2 Pa."""
    from qchain.fit.measurements import pressure_noise
    from qchain.sim.inputs import Table

    t = np.arange(0.0, 20.0, 0.01)
    clean = 1e4 + 2e4 * np.sin(2 * np.pi * 0.8 * t)[:, None] ** 2 * np.ones(3)
    rng = np.random.default_rng(8)
    noisy = clean + rng.normal(size=clean.shape) * [300.0, 100.0, 0.0]
    est = pressure_noise(Table(t, noisy))
    assert abs(est[0] / 300.0 - 1) < 0.1 and abs(est[1] / 100.0 - 1) < 0.1, est
    assert est[2] < 2.0, est
    with pytest.raises(MeasurementError, match="5 pressure samples, at least 6"):
        pressure_noise(Table(t[:5], noisy[:5]))


def test_a_pressure_filter_passes_the_drive_and_removes_the_noise():
    """A 4th-order zero-phase low-pass at 10 Hz: the 0.8 Hz sweep (1.6 Hz in the pressure) comes
    through within 0.01 % of its 20 kPa swing away from the ends (0.2 s), within 0.3 % at them
    (the filter's start-up, run both ways), the 300 Pa white noise of a 100 Hz sensor drops to
    under half."""
    from qchain.fit.measurements import filter_pressures
    from qchain.sim.inputs import Table

    t = np.arange(0.0, 3.0, 0.01)
    clean = (1e4 + 2e4 * np.sin(2 * np.pi * 0.8 * t - np.pi / 4) ** 2)[:, None]
    out = filter_pressures(Table(t, clean), 10.0)
    assert np.abs(out.values - clean)[20:-20].max() < 1e-4 * 2e4
    assert np.abs(out.values - clean).max() < 3e-3 * 2e4
    noise = 300.0 * np.random.default_rng(9).normal(size=(t.size, 1))
    assert filter_pressures(Table(t, noise), 10.0).values[20:-20].std() < 0.5 * 300.0
    for bad in (0.0, -1.0, 50.0, 80.0, float("nan")):
        with pytest.raises(MeasurementError, match=r"pressure_filter: cutoff .* Hz must lie in \(0, 50\) Hz"):
            filter_pressures(Table(t, clean), bad)
