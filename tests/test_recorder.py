"""ChainRecorder: a simulated chain's samples as step records, frames computed in batches;
each sample checked where it enters, one recorder for one run."""

from __future__ import annotations

import io

import numpy as np
import pytest

from logging_fixtures import arm_info
from qchain.logging import RecordLayout, RunInfo, RunLogger, read_recording
from qchain.recording.recorder import ChainRecorder
from qchain.sim.simulation import simulate
from support import soft_arm
from test_chain import make_chain


def _info(ch):
    return RunInfo(n_segments=ch.n, radii=[s.radius for s in ch.segments], scene="", params={})


class _Rows:
    """A stand-in logger that keeps what log_rows gets."""

    flush_interval = 0.1

    def __init__(self):
        self.calls = []

    def log_rows(self, rows, layout):
        self.calls.append((rows.copy(), layout))


@pytest.mark.slow
def test_recorded_run_equals_the_trajectory_and_the_chain_frames():
    """Every sample of a simulation, logged through the recorder and read back from the MCAP:
    t, q, v, p and the energies as simulate returned them, step = sample index, and the
    backbone and tip frames equal to Chain.frames of each sample, bit for bit."""
    ch = make_chain("paper", "floating")
    q0 = ch.neutral()
    q0[ch.q_slice(0)] = [ch.segments[0].length, 0.3, 2.0]  # paper coordinates: bent away from kappa = 0
    q0[ch.q_slice(2)] = [ch.segments[2].length, -1.0, 1.5]
    buf = io.BytesIO()
    with RunLogger(_info(ch), buf) as log, ChainRecorder(log, ch, points_per_segment=7) as rec:
        traj = simulate(ch, q0, np.zeros(ch.nv), (0.0, 0.3), pressure=np.full(3 * ch.n, 2e4),
                        t_eval=np.linspace(0.0, 0.3, 61), on_sample=rec)
    assert traj.success and rec.n_samples == 61
    buf.seek(0)
    r = read_recording(buf)
    assert len(r) == 61
    np.testing.assert_array_equal(r.t, traj.t)
    np.testing.assert_array_equal(r.step, np.arange(61))
    for f in ("q", "v", "p"):
        np.testing.assert_array_equal(getattr(r, f), getattr(traj, f))
    np.testing.assert_array_equal(r.energy[:, 0], traj.kinetic_energy)
    np.testing.assert_array_equal(r.energy[:, 1], traj.potential_energy)
    np.testing.assert_array_equal(r.energy[:, 2], traj.kinetic_energy + traj.potential_energy)
    for k in (0, 17, 60):
        X, bb = ch.frames(traj.q[k], 7, t=traj.t[k])
        np.testing.assert_array_equal(r.backbone[k], bb)
        np.testing.assert_array_equal(r.tip_frames[k, :, :3], [x.translation for x in X[1:]])
        for j, x in enumerate(X[1:]):  # quaternion (x, y, z, w) of the tip rotation
            qx, qy, qz, qw = r.tip_frames[k, j, 3:]
            w2 = np.array([[1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qz * qw), 2 * (qx * qz + qy * qw)],
                           [2 * (qx * qy + qz * qw), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qx * qw)],
                           [2 * (qx * qz - qy * qw), 2 * (qy * qz + qx * qw), 1 - 2 * (qx * qx + qy * qy)]])
            assert np.abs(w2 - x.rotation).max() < 1e-15


def test_batches_are_bounded_in_count_and_simulation_time():
    ch = make_chain()
    log = _Rows()
    rec = ChainRecorder(log, ch, max_batch=8, max_wall=1e9)
    q = ch.neutral()
    v, p = np.zeros(ch.nv), np.zeros(3 * ch.n)
    ts = np.concatenate([np.arange(0.0, 0.5, 0.01), np.arange(0.5, 2.0, 0.05)])  # 100 Hz, then 20 Hz
    for t in ts:
        rec(t, q, v, p, energies=(1.0, 2.0))
    rec.flush()
    rows = np.concatenate([c[0] for c in log.calls])
    np.testing.assert_array_equal(rows[:, 0], ts)
    np.testing.assert_array_equal(rows[:, 1], np.arange(len(ts)))
    for batch, layout in log.calls:
        assert layout == RecordLayout(ch.nq, ch.nv, 3 * ch.n, ch.n, 12)
        assert 1 <= len(batch) <= 8
        assert batch[-1, 0] - batch[0, 0] < 0.1  # the logger's flush_interval
    assert max(len(b) for b, _ in log.calls) == 8  # 100 Hz: the count bound
    assert [len(b) for b, _ in log.calls][-14:] == [2] * 14  # 20 Hz: the time bound (t, t + 0.05)
    e = rows[:, layout.slices["energy"]]
    np.testing.assert_array_equal(e, np.tile([1.0, 2.0, 3.0], (len(ts), 1)))


def test_waiting_samples_are_logged_when_the_simulation_raises():
    ch = make_chain()
    log = _Rows()
    q, v, p = ch.neutral(), np.zeros(ch.nv), np.zeros(3 * ch.n)
    with pytest.raises(RuntimeError, match="boom"):
        with ChainRecorder(log, ch) as rec:
            rec(0.0, q, v, p, energies=(0.0, 0.0))
            rec(0.01, q, v, p, energies=(0.0, 0.0))
            raise RuntimeError("boom")
    assert len(log.calls) == 1 and len(log.calls[0][0]) == 2


def test_energies_are_computed_when_simulate_does_not_pass_them(rng):
    ch = make_chain()
    log = _Rows()
    q = ch.neutral()
    q[ch.q_slice(1)] = [ch.segments[1].length, 1.0, -2.0]
    v = rng.normal(size=ch.nv) * 0.1
    with ChainRecorder(log, ch) as rec:
        rec(0.0, q, v, np.zeros(3 * ch.n))
    e = log.calls[0][0][0, log.calls[0][1].slices["energy"]]
    assert e[0] == ch.kinetic_energy(q, v) and e[1] == ch.potential_energy(q) and e[2] == e[0] + e[1]


def test_recorder_arguments_are_checked():
    ch = make_chain()
    log = _Rows()
    with pytest.raises(ValueError, match="points_per_segment must be an int >= 2, got 1"):
        ChainRecorder(log, ch, points_per_segment=1)
    with pytest.raises(ValueError, match="max_batch must be an int >= 1, got 0"):
        ChainRecorder(log, ch, max_batch=0)
    with pytest.raises(ValueError, match="max_wall must be > 0 s, got -1"):
        ChainRecorder(log, ch, max_wall=-1)


def test_samples_are_copied_and_their_shapes_checked():
    """A caller that reuses its arrays in place (a solver's state buffers) logs the values
    each call saw; a sample of the wrong size is refused at the call, naming the shapes."""
    ch = make_chain()
    log = _Rows()
    q, v, p = ch.neutral(), np.zeros(ch.nv), np.zeros(3 * ch.n)
    with ChainRecorder(log, ch) as rec:
        for k in range(3):
            v[:] = k
            p[:] = 10.0 * k
            rec(0.01 * k, q, v, p, energies=(float(k), 0.0))
        with pytest.raises(ValueError, match=r"q, v, p must have shapes .*got .*\(%d,\)" % (3 * ch.n - 1)):
            rec(0.03, q, v, p[:-1], energies=(0.0, 0.0))
    rows, layout = log.calls[0]
    assert len(log.calls) == 1 and len(rows) == 3
    sl = layout.slices
    np.testing.assert_array_equal(rows[:, sl["v"]], np.repeat([[0.0], [1.0], [2.0]], ch.nv, axis=1))
    np.testing.assert_array_equal(rows[:, sl["p"]], np.repeat([[0.0], [10.0], [20.0]], 3 * ch.n, axis=1))
    np.testing.assert_array_equal(rows[:, sl["energy"]], [[0.0, 0.0, 0.0], [1.0, 0.0, 1.0], [2.0, 0.0, 2.0]])


def test_a_batch_of_samples_logs_what_the_samples_one_by_one_log():
    """record_batch (samples as arrays, for a caller that has them so) gives the rows the
    per-sample calls give, cut into batches spanning less than the logger's flush_interval."""
    ch = make_chain()
    rng = np.random.default_rng(3)
    K = 40
    t = np.cumsum(rng.uniform(0.005, 0.02, K))
    q = np.tile(ch.neutral(), (K, 1))
    q[:, ch.q_slice(1)] += rng.normal(scale=[0.0, 0.5, 0.5], size=(K, 3))
    v, p = rng.normal(size=(K, ch.nv)), rng.uniform(0, 3e4, (K, 3 * ch.n))
    ke, pe = rng.uniform(size=K), rng.uniform(size=K)
    one, batch = _Rows(), _Rows()
    with ChainRecorder(one, ch, max_wall=1e9) as rec:
        for k in range(K):
            rec(t[k], q[k], v[k], p[k], energies=(ke[k], pe[k]))
    with ChainRecorder(batch, ch) as rec:
        rec.record_batch(t, q, v, p, ke, pe)
        assert rec.taken == K
    rows_one = np.concatenate([c[0] for c in one.calls])
    rows_batch = np.concatenate([c[0] for c in batch.calls])
    np.testing.assert_array_equal(rows_batch, rows_one)
    for rows, _ in batch.calls:
        assert rows[-1, 0] - rows[0, 0] < _Rows.flush_interval


def test_ctrl_c_while_a_paced_batch_is_taken_records_no_sample_twice(monkeypatch):
    """``realtime``: the recorder takes an engine batch sample by sample, pausing between
    them; a Ctrl-C in a pause ends the run, and the engine hands the batch over again. The
    samples already taken are not logged twice: the records are the trajectory's first
    samples, each once, in order."""
    import qchain.recording.recorder as recorder_module
    from qchain.sim.engine.driver import Interrupted
    from test_simulate import hanging_arm

    ch = hanging_arm(2)
    pauses = []

    def sleep(s):
        pauses.append(s)
        if len(pauses) == 6:
            raise KeyboardInterrupt

    monkeypatch.setattr(recorder_module.time, "sleep", sleep)
    log = _Rows()
    with pytest.raises(Interrupted) as info:
        with ChainRecorder(log, ch, realtime=True) as rec:
            simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, 2.0), method="radau5",
                     t_eval=np.linspace(0.0, 2.0, 201), on_sample=rec)
    traj = info.value.trajectory
    assert traj.meta["engine"] == "compiled" and len(pauses) == 6  # no pause after the Ctrl-C
    t = np.concatenate([rows[:, 0] for rows, _ in log.calls])
    assert len(t) == rec.n_samples == rec.taken and len(t) >= 6
    np.testing.assert_array_equal(t, traj.t[: len(t)])  # each once, in order


# --------------------------------------------------------------------------------------
# Bad input (issue 18): refused where it enters, naming the argument, the value and the bound;
# never a foreign traceback, a hang, a crash, a silent NaN or lost data.

def test_a_recorder_checks_each_sample_where_it_enters(tmp_path):
    """A negative time or a NaN q was taken, then refused at the flush, taking the good
    samples buffered with it; times going back were recorded silently."""
    from qchain.recording.recorder import ChainRecorder

    ch = soft_arm(1)
    q, v, p = ch.neutral(), np.zeros(3), np.zeros(3)
    path = tmp_path / "r.mcap"
    with RunLogger(arm_info(1), path, quiet=True, worker="thread") as log, ChainRecorder(log, ch) as rec:
        rec(0.0, q, v, p)
        rec(0.001, q, v, p)
        for t, qq, energies, match in ((-1.0, q, None, "t must be a time >= 0"),
                                       (0.0005, q, None, "t must not go back"),
                                       (0.002, np.full(3, np.nan), None, r"q has non-finite entries"),
                                       (0.002, np.full(3, np.nan), (0.0, 0.0), r"q\[0\] must be finite"),
                                       (0.002, q, 5.0, r"energies must be \(kinetic, potential\)"),
                                       (0.002, q, (1, 2, 3), r"energies must be \(kinetic, potential\)")):
            with pytest.raises(ValueError, match=match):
                rec(t, qq, v, p, energies=energies)
        with pytest.raises(ValueError, match=r"t must not go back: t\[1\]"):
            rec.record_batch(np.array([0.3, 0.1]), np.stack([q, q]), np.zeros((2, 3)), np.zeros((2, 3)),
                             np.zeros(2), np.zeros(2))
    assert len(read_recording(path)) == 2  # the good samples kept


def test_a_recorder_used_for_two_runs_refuses_the_second_instead_of_splicing(tmp_path):
    """record_batch took a second run's samples before the first's last time as a batch
    handed over again, and dropped them: the recording spliced the two runs."""
    from qchain.recording.recorder import ChainRecorder

    ch = soft_arm(2)
    q0, v0 = ch.neutral(), np.zeros(ch.nv)
    with RunLogger(arm_info(2), tmp_path / "r.mcap", quiet=True, worker="thread") as log, \
            ChainRecorder(log, ch) as rec:
        simulate(ch, q0, v0, (0, 0.1), on_sample=rec, t_eval=np.linspace(0, 0.1, 11))
        with pytest.raises(ValueError, match=r"t must not go back: a batch from t = 0.0 s .* \(one recorder a run\)"):
            simulate(ch, q0, v0, (0, 0.2), on_sample=rec, t_eval=np.linspace(0, 0.2, 21))
    np.testing.assert_allclose(read_recording(tmp_path / "r.mcap").t, np.linspace(0, 0.1, 11))


def _tendon_chain():
    from qchain import Chain, Segment, Tendon

    seg = Segment(length=0.2, radius=0.02, mass=0.08, chamber_area=1e-4, chamber_radius=0.01, youngs_modulus=2e5,
                  damping=0.15)
    return Chain([seg, seg], tendons=[Tendon(radius=0.015, angle=0.3, end=0), Tendon(radius=0.01, pitch=0.5)])


def test_tensions_and_tendon_paths_are_recorded_and_read_back(tmp_path):
    """A run with tendons through the recorder: each row holds the sample's tensions (the
    schedule's) and each tendon's path (Chain.tendon_paths, NaN past a tendon's end); the MCAP
    reads the tensions back bit for bit (its state messages hold them, not the paths), the
    journal's rows both; a run without tendons writes the layout of before."""
    from qchain.sim.inputs import Ramp

    ch = _tendon_chain()
    ramp = Ramp(0.0, 0.05, np.array([3.0, 2.0]), np.zeros(2))
    keep = _Rows()
    path = tmp_path / "run.mcap"
    with RunLogger(_info(ch), path, quiet=True) as log, ChainRecorder(log, ch, tension=lambda t, q, v: ramp(t)) as rec:
        real_log_rows = log.log_rows

        def both(rows, layout):
            keep.log_rows(rows, layout)
            real_log_rows(rows, layout)

        log.log_rows = both
        traj = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, 0.1), tension=ramp, method="radau5",
                        t_eval=np.linspace(0.0, 0.1, 11), on_sample=rec)
    assert traj.success
    lay = keep.calls[0][1]
    assert (lay.nt, lay.M) == (2, 2 * rec.points_per_segment)
    assert RecordLayout.from_json(lay.to_json()) == lay
    from qchain.recording.records import Batch

    b = Batch.concatenate([Batch.from_rows(r, lay) for r, lay in keep.calls])
    np.testing.assert_array_equal(b.tension, traj.tension)
    P = rec.points_per_segment
    for k in (0, 5, 10):
        short, full = ch.tendon_paths(traj.q[k], P, t=traj.t[k])
        np.testing.assert_array_equal(b.tendons[k, 0, :P], short)  # tendon 0 ends at segment 0's tip
        assert np.isnan(b.tendons[k, 0, P:]).all()
        np.testing.assert_array_equal(b.tendons[k, 1], full)
    back = read_recording(path)
    assert back.damage == [] and back.nonfinite == []
    np.testing.assert_array_equal(back.tension, traj.tension)
    np.testing.assert_array_equal(back.q, traj.q)
    assert back.tendons is None
    np.testing.assert_array_equal(Batch.from_rows(back.batch().rows(), back.batch().layout).tension, traj.tension)
    # without the tension callable (or tendons) the layout is the one of before: no tendon columns
    plain = ChainRecorder(_Rows(), ch)
    assert (plain.layout.nt, plain.layout.M) == (0, 0) and "nt" not in plain.layout.to_json()


def test_tension_recording_arguments_are_checked(tmp_path):
    ch = _tendon_chain()
    with pytest.raises(TypeError, match="tension must be None or a callable"):
        ChainRecorder(_Rows(), ch, tension=[1.0, 2.0])
    with pytest.raises(ValueError, match="the chain has no tendons"):
        ChainRecorder(_Rows(), soft_arm(2), tension=lambda t, q, v: np.zeros(0))
    rec = ChainRecorder(_Rows(), ch, tension=lambda t, q, v: np.array([1.0, -1.0]))
    with pytest.raises(ValueError, match=r"must return 2 finite tensions >= 0 N"):
        rec(0.0, ch.neutral(), np.zeros(ch.nv), np.zeros(ch.nu))
        rec.flush()
    with pytest.raises(ValueError, match="nt and M|tendon points without tendons"):
        RecordLayout.from_json({"nq": 6, "nv": 6, "np": 6, "n": 2, "P": 3, "M": 4})
