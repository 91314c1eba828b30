"""``qchain info`` and ``qchain run`` on scenes with obstacles: the obstacles, the law and its
time scale listed; a run of the example arm on the ground, recorded, whose summary says the
contact's time scale and whether it limited the steps; an arm starting inside an obstacle
is bad input."""

import io
import math
import re
from pathlib import Path

import numpy as np
import pytest

from qchain.cli.main import main
from qchain.scene import load_scene

EXAMPLE = Path(__file__).parents[1] / "examples" / "scenes" / "arm_on_ground.toml"


def test_info_lists_the_obstacles_and_the_contact_law_with_its_time_scale(capsys):
    assert main(["info", str(EXAMPLE)]) == 0
    out = capsys.readouterr().out
    sc = load_scene(EXAMPLE)
    T = sc.environment.time_scale(sc.build().chain)
    # the example's segments: 0.05 kg and 0.1 m each, 16 points; k = 1e6, e = 1.5, g = 9.81: one point's period
    m, ell = 0.05 / 16, 0.1 / 16
    d = (m * 9.81 / (ell * 1e6)) ** (1 / 1.5)
    assert T == pytest.approx(2 * math.pi / math.sqrt(1.5 * ell * 1e6 * math.sqrt(d) / m), rel=1e-12)
    assert "obstacles: 1\n" in out and '  - obstacles[0] "ground": half-space through (0, 0, 0) m, normal (0, 0, 1)' in out
    assert re.search(r"contact: stiffness 1e\+06 N/m\^2\.5 per m, exponent 1\.5, damping [0-9.]+ s/m, mu_static 0\.6, "
                     r"mu_dynamic 0\.5, slip velocity 0\.001 m/s, Stribeck velocity 0\.01 m/s, 16 contact points a "
                     r"segment", out), out
    assert f"  time scale {T * 1e3:.3g} ms" in out
    assert "planar: uy locked at 0 in every segment: gravity, pressures (p2 == p3), initial state and base motion, " \
           "obstacles and loads symmetric about the base x-z plane" in out


@pytest.mark.slow
def test_the_example_runs_recorded_and_says_the_contact_time_scale(tmp_path, capsys):
    from qchain.logging import read_mcap

    mcap, out_dir = tmp_path / "ground.mcap", tmp_path / "out"
    assert main(["run", str(EXAMPLE), "--duration", "0.3", "--mcap", str(mcap), "--out", str(out_dir),
                 "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "run: success" in out and f"recorded {mcap} (31 samples, up to t = 0.3 s)" in out
    # the same run directly: its meta is what the summary line says
    sc = load_scene(EXAMPLE)
    traj = sc.simulate(duration=0.3)
    T, limited = traj.meta["contact_time_scale"], traj.meta["step_limited_by_contact"]
    assert f"contact: time scale {T * 1e3:.3g} ms; the steps were {'limited' if limited else 'not limited'} by it" in out
    rec = read_mcap(mcap)
    data = np.load(out_dir / "trajectory.npz")
    assert rec.success and np.array_equal(rec.q, data["q"]) and np.allclose(data["q"], traj.q, rtol=0, atol=1e-12)
    # the arm fell onto the ground and lies on it: touching, sunk less than a millimetre (one contact point
    # alone on its own weight sinks (m g / (l k))^(1/e) = 0.29 mm; the points nearest the tip carry more)
    env, ch = sc.environment, sc.model.chain
    c = ch.contacts(traj.q[-1], traj.v[-1], env)
    assert len(c.segment) > 0 and 0 < c.penetration.max() < 1e-3


def test_the_summary_line_says_what_the_run_meta_says():
    """The line comes from the trajectory's meta alone (either answer), and only with obstacles."""
    from types import SimpleNamespace

    from qchain.cli.outputs import summary_lines

    sc = load_scene(EXAMPLE)
    m = sc.build()
    traj = SimpleNamespace(success=True, message="ok", t=np.array([0.0]), q=m.q0[None], v=m.v0[None],
                           p=np.zeros((1, m.chain.nu)), nfev=1, kinetic_energy=np.zeros(1),
                           potential_energy=np.zeros(1), meta={})
    assert not any(x.startswith("contact:") for x in summary_lines(sc, m, traj, 1.0))
    for limited, said in ((True, "limited by it (in contact, the mean step was under a quarter of it)"),
                          (False, "not limited by it")):
        traj.meta = {"contact_time_scale": 0.0278, "step_limited_by_contact": limited}
        lines = summary_lines(sc, m, traj, 1.0)
        assert f"contact: time scale 27.8 ms; the steps were {said}" in lines, lines


def test_an_arm_starting_inside_an_obstacle_is_bad_input(tmp_path, capsys):
    text = EXAMPLE.read_text().replace('point = [0.0, 0.0, 0.0]', 'point = [0.0, 0.0, 0.045]')
    p = tmp_path / "sunk.toml"
    p.write_text(text)
    assert main(["run", str(p), "--no-record", "--no-plots"]) == 2
    err = capsys.readouterr().err
    # the arm's axis is at z = 0.05, the ground at 0.045: 15 mm - 5 mm = 10 mm inside, every segment
    assert (f'qchain run: error: {p}: obstacles[0]: expected an arm that starts outside obstacles[0] "ground" (inside '
            "by at most 10% of a segment's radius, 1.5 mm for segment 0), found segment 0 starts inside it by 10 mm") \
        in err, err


def test_the_arm_plot_draws_the_obstacles_as_each_view_sees_them():
    """The format docs' contact example: a ground (normal +z) and a pole along y at x = 0.1 m,
    radius 0.02 m, from y = -0.2 to 0.2 m. The side view (x-z) shows the ground's line and the
    pole's end disc; the top view (x-y) no ground (it looks along its normal) and the pole as a
    flat-ended 40 mm x 400 mm band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from qchain.cli.outputs import plot_arm
    from qchain.scene import format as F
    from qchain.scene import parse_scene

    sc = parse_scene(F.EXAMPLE + "\n" + F.CONTACT_EXAMPLE)
    m = sc.build()
    traj = sc.simulate(model=m, duration=0.01)
    tip = np.array([m.chain.tip_placement(q).translation for q in traj.q])
    fig = plot_arm(m, traj, tip, "t", env=sc.environment)
    side, top = fig.axes
    try:
        (disc,), (band,) = side.patches, top.patches
        x, z = disc.get_xy().T
        assert x.min() == pytest.approx(80, abs=0.5) and x.max() == pytest.approx(120, abs=0.5)
        assert z.min() == pytest.approx(-20, abs=0.5) and z.max() == pytest.approx(20, abs=0.5)
        x, y = band.get_xy().T
        assert y.min() == pytest.approx(-200, abs=1e-9) and y.max() == pytest.approx(200, abs=1e-9)  # flat ends
        assert x.min() == pytest.approx(80, abs=0.5) and x.max() == pytest.approx(120, abs=0.5)
        ground = [ln for ln in side.get_lines() if type(ln).__name__ == "AxLine"]
        assert len(ground) == 1 and not [ln for ln in top.get_lines() if type(ln).__name__ == "AxLine"]
    finally:
        plt.close(fig)



def _touching_scene(tmp_path) -> Path:
    """The example with its base lowered to 1 mm above where the tube touches the ground
    (axis at 16 mm, radius 15 mm): the arm lands at once; 200 samples a second."""
    text = EXAMPLE.read_text().replace("position = [0.0, 0.0, 0.05]", "position = [0.0, 0.0, 0.016]")
    text = text.replace("sample_rate = 100.0", "sample_rate = 200.0")
    assert "0.016" in text and "200.0" in text
    p = tmp_path / "touching.toml"
    p.write_text(text)
    return p


def _static_kinds(rrd) -> dict:
    """entity path -> the archetypes of its static chunks, in a .rrd."""
    import rerun as rr

    kinds: dict = {}
    for chunk in rr.chunk.RrdReader(rrd).stream():
        if chunk.is_static:
            kinds.setdefault(chunk.entity_path, set()).update(
                n.split(":")[0] for n in chunk.to_record_batch().schema.names if ":" in n)
    return kinds


def _run_recorded(scene, tmp_path, capsys):
    """``qchain run`` of ``scene`` for 0.05 s into run.mcap and run.rrd (11 samples); returns
    the recording, the scene's environment and chain, and the .rrd's path."""
    from qchain.logging import read_recording

    mcap, rrd = tmp_path / "run.mcap", tmp_path / "run.rrd"
    assert main(["run", str(scene), "--duration", "0.05", "--mcap", str(mcap), "--rrd", str(rrd), "--no-plots",
                 "--no-progress"]) == 0
    assert f"recorded {mcap} (11 samples, up to t = 0.05 s)" in capsys.readouterr().out
    sc = load_scene(scene)
    return read_recording(mcap), sc.environment, sc.build().chain, rrd


def test_a_run_records_the_scenes_obstacles_and_contacts_and_draws_them(tmp_path, capsys):
    """`qchain run --mcap --rrd` of a scene with an obstacle: the recording holds the obstacles
    (Environment.describe), a capacity of segments x contact points, force_ref the weight a
    contact point carries lying flat; each sample's contacts are Chain.contacts at the recorded
    (t, q, v) (the same points and forces, so the same force sums); the .rrd of the run and of
    `qchain replay` draw the ground and the forces."""
    from test_logging import _rrd_columns

    rec, env, ch, rrd = _run_recorded(_touching_scene(tmp_path), tmp_path, capsys)
    mcap, rrd2 = tmp_path / "run.mcap", tmp_path / "replay.rrd"
    assert rec.info.obstacles == env.describe() and len(rec) == 11
    assert rec.info.max_contacts == 3 * 16 * 1
    assert rec.info.force_ref == pytest.approx(3 * 0.05 * 9.81 / (3 * 16), rel=1e-12)
    touching = 0
    for k in range(len(rec)):
        want = ch.contacts(rec.q[k], rec.v[k], env, t=float(rec.t[k]))
        got = rec.contact_set(k)
        for name in ("point", "normal", "force", "segment", "obstacle"):
            np.testing.assert_array_equal(getattr(got, name), getattr(want, name), err_msg=f"sample {k}: {name}")
        np.testing.assert_array_equal(got.force.sum(axis=0), want.force.sum(axis=0))
        touching += len(got.segment) > 0
    assert touching >= 8  # it lands at once and stays: most samples touch
    assert np.max([rec.contact_set(k).force[:, 2].sum() for k in range(len(rec))]) > 0.1  # N: the ground pushes up

    assert main(["replay", str(mcap), "--rrd", str(rrd2)]) == 0
    for path in (rrd, rrd2):
        kinds = _static_kinds(path)
        assert "Boxes3D" in kinds["/world/obstacles/0"], kinds  # the ground: a thin slab
        cols, _ = _rrd_columns(path)
        assert cols["/world/contacts/forces"]["step"] == list(range(11))
        assert not any(p.startswith("/world/obstacles/") for p in cols)  # a fixed ground: no motion
        k = int(np.argmax([len(rec.contact_set(j).segment) for j in range(len(rec))]))
        origins = np.array(cols["/world/contacts/forces"]["origins"][k]).reshape(-1, 3)
        np.testing.assert_allclose(origins, rec.contact_set(k).point, rtol=0, atol=1e-7)  # (float32)


def test_a_run_without_obstacles_makes_no_contact_call():
    """No environment, or point loads only: nothing of contact in the recording's RunInfo and
    no contacts callable for the recorder (no contact call a sample). With obstacles: the
    capacity counts up to two obstacles a point, bounded; force_ref uses standard gravity
    when the run has none."""
    from types import SimpleNamespace

    from qchain.cli.main import MAX_RUN_CONTACTS, _contact_recording
    from qchain.contact import Environment, HalfSpace, PointLoad, Sphere

    sc = load_scene(EXAMPLE)
    ch = sc.build().chain
    assert _contact_recording(ch, None) == ({}, None)
    assert _contact_recording(ch, Environment(loads=[PointLoad(0, 1.0, force=[0.0, 0.0, -1.0])])) == ({}, None)
    info, contacts = _contact_recording(ch, sc.environment)
    assert callable(contacts) and info["max_contacts"] == 48
    three = Environment([HalfSpace(), Sphere([0.2, 0.0, 0.0], 0.05), Sphere([0.3, 0.0, 0.0], 0.05)], nodes=16)
    assert _contact_recording(ch, three)[0]["max_contacts"] == 2 * 48
    long = SimpleNamespace(n=40, segments=[SimpleNamespace(mass=0.05)] * 40, payload=None, gravity=np.zeros(3))
    info, _ = _contact_recording(long, Environment([HalfSpace()], nodes=64))
    assert info["max_contacts"] == MAX_RUN_CONTACTS < 40 * 64
    assert info["force_ref"] == pytest.approx(40 * 0.05 * 9.80665 / (40 * 64), rel=1e-15)


#: the example's ground as a conveyor belt running along +x that also heaves (the recorded law)
BELT = {"velocity": [0.2, 0.0, 0.0], "amplitude": [0.0, 0.0, 5e-4], "frequency": 10.0, "phase": 0.3}


def _belt_scene(tmp_path) -> Path:
    """:func:`_touching_scene` with its ground moved by :data:`BELT`."""
    text = _touching_scene(tmp_path).read_text()
    keys = "".join(f"{k} = {v!r}\n" for k, v in BELT.items())
    text = text.replace("normal = [0.0, 0.0, 1.0]\n", "normal = [0.0, 0.0, 1.0]\n" + keys)
    assert keys in text
    p = tmp_path / "belt.toml"
    p.write_text(text)
    return p


def _belt_offset(t) -> np.ndarray:
    """u(t) (K, 3) m of BELT, written out here: velocity t + amplitude sin(2 pi frequency t + phase)."""
    t = np.asarray(t, dtype=float)[:, None]
    return (np.array(BELT["velocity"]) * t
            + np.array(BELT["amplitude"]) * np.sin(2 * np.pi * BELT["frequency"] * t + BELT["phase"]))


def test_info_shows_a_moving_obstacles_motion(tmp_path, capsys):
    assert main(["info", str(_belt_scene(tmp_path))]) == 0
    out = capsys.readouterr().out
    assert ('  - obstacles[0] "ground": half-space through (0, 0, 0) m, normal (0, 0, 1); moved by u(t) = velocity t + '
            "amplitude sin(2 pi frequency t + phase): velocity (0.2, 0, 0) m/s, amplitude (0, 0, 0.0005) m, frequency "
            "10 Hz, phase 0.3 rad") in out, out
    assert "planar: uy locked at 0 in every segment" in out  # the belt moves in the base's x-z plane


def test_a_run_records_a_moving_obstacle_where_its_law_puts_it(tmp_path, capsys):
    """`qchain run --mcap --rrd` of the touching example on a moving belt: the recording holds
    the belt's law (RunInfo.obstacles[0]["motion"]); Foxglove's obstacle message of each record
    and Rerun's translation of the belt put it where the law, written out here, puts it at the
    record's time; each sample's contacts are Chain.contacts at the recorded (t, q, v), and the
    belt's friction drags the arm along +x (it runs faster than the arm)."""
    from test_logging import _rrd_columns
    from test_recording_contacts import _foxglove

    from qchain.recording.records import CONTACT_TOPICS

    rec, env, ch, rrd = _run_recorded(_belt_scene(tmp_path), tmp_path, capsys)
    mcap = tmp_path / "run.mcap"
    assert rec.info.obstacles == env.describe() and rec.info.obstacles[0]["motion"] == BELT
    t = np.asarray(rec.t, dtype=float)
    assert len(t) == 11 and t[0] == 0.0
    want = _belt_offset(t)
    assert np.abs(want[:, 0]).max() == pytest.approx(0.01)  # it does move: 10 mm along x by the end
    # Foxglove: a scene update a record, the ground's slab carried by the law
    msgs = _foxglove(io.BytesIO(mcap.read_bytes()), CONTACT_TOPICS["obstacles"])
    assert [lt for lt, _ in msgs] == [round(x * 1e9) for x in t]
    slab = np.array([[c.pose.position.x, c.pose.position.y, c.pose.position.z]
                     for _, upd in msgs for c in upd.entities[0].cubes])
    np.testing.assert_allclose(slab - slab[0], want - want[0], rtol=0, atol=1e-12)
    # Rerun: the ground's entity translated at each record by the law (float32)
    cols, _ = _rrd_columns(rrd)
    ground = cols["/world/obstacles/0"]
    assert ground["t"] == [round(x * 1e9) for x in t]
    np.testing.assert_allclose(np.array(ground["translation"]).reshape(-1, 3), want, rtol=0, atol=1e-8)
    # the engine's contacts at each record, and the belt's friction on the arm
    drag = []
    for k in range(len(rec)):
        c_want = ch.contacts(rec.q[k], rec.v[k], env, t=float(rec.t[k]))
        got = rec.contact_set(k)
        for name in ("point", "normal", "force", "segment", "obstacle"):
            np.testing.assert_array_equal(getattr(got, name), getattr(c_want, name), err_msg=f"sample {k}: {name}")
        if len(got.segment):
            drag.append(got.force[:, 0].sum())
    assert len(drag) >= 4 and all(f > 0.0 for f in drag), drag  # (the heaving belt bounces it: 6 of 11 touch)
