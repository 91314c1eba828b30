"""``qchain info`` and ``qchain run`` on scenes with obstacles: the obstacles, the law and its
time scale listed; a run of the example arm on the ground, recorded, whose summary says the
contact's time scale and whether it limited the steps; an arm starting inside an obstacle
is bad input."""

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

