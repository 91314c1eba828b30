"""Every example runs (``--quick``) and produces its outputs, which say what they should."""

import math
import subprocess
import sys

import numpy as np
import pytest

from support import EXAMPLES, is_png




def test_step_response(examples, tmp_path, capsys):
    out = examples("step_response").main(["--quick", "--out", str(tmp_path)])
    traj = out["trajectory"]
    assert traj.success and math.isclose(traj.t[-1], 0.25)
    assert is_png(out["png"]) and out["png"].parent == tmp_path
    from qchain.scene import load_scene

    sc = load_scene(EXAMPLES / "scenes" / "step_response.toml")
    ch = sc.build().chain
    tip = np.array([ch.tip_placement(q).translation for q in traj.q])
    before = traj.t < 0.05
    assert np.all(tip[before, 0] == 0.0)  # nothing bends before the step (symmetric, planar)
    assert tip[-1, 0] < -0.005  # chamber 1 on +x lengthens its side: the tip goes to -x
    assert out["overshoot_percent"] > 0.0  # lightly damped: it overshoots the static shape
    assert "overshoot" in capsys.readouterr().out


def test_wave_arm(examples, tmp_path):
    out = examples("wave_arm").main(["--quick", "--out", str(tmp_path)])
    assert out["trajectory"].success and is_png(out["png"])
    tip = out["tip"]
    assert np.abs(tip[:, 1]).max() < 1e-9  # p2 == p3: the arm stays in the x-z plane
    assert np.ptp(tip[:, 0]) > 0.005


@pytest.mark.slow
def test_floating_arm(examples, tmp_path, capsys):
    out = examples("floating_arm").main(["--quick", "--out", str(tmp_path)])
    assert out["trajectory"].success
    assert all(is_png(p) for p in out["pngs"])
    rel_lin, rel_ang = out["relative_drift"]
    assert rel_lin < 1e-8 and rel_ang < 1e-8  # DOP853 at rtol 1e-10: the momentum stays put
    assert "largest drift" in capsys.readouterr().out


def test_moving_base(examples, tmp_path):
    out = examples("moving_base").main(["--quick", "--out", str(tmp_path)])
    traj = out["trajectory"]
    assert traj.success and is_png(out["png"])
    # the mount follows the scene's motion exactly (mount frame x = world x here)
    assert np.allclose(out["mount"][:, 0], 0.02 * np.sin(2 * np.pi * 1.5 * traj.t), rtol=0, atol=1e-15)
    assert np.ptp(out["tip"][:, 0]) > 0.005


def test_equilibrium_gallery(examples, tmp_path):
    out = examples("equilibrium_gallery").main(["--quick", "--out", str(tmp_path)])
    assert is_png(out["png"]) and len(out["shapes"]) == 6
    from qchain.scene import load_scene

    ch = load_scene(EXAMPLES / "scenes" / "equilibrium_gallery.toml").build().chain
    for label, q, tip in out["shapes"]:
        bends = [math.hypot(*q[ch.q_slice(j)][1:]) for j in range(ch.n)]
        if label in ("0,0,0 | 0,0,0", "60,60,60 | 60,60,60"):  # no pressure difference: no bend
            assert max(bends) < 1e-9
        else:
            assert max(bends) > 1.0  # 1/m
    # equal pressures stretch the arm
    q_eq = out["shapes"][-1][1]
    assert all(q_eq[ch.q_slice(j)][0] > 0.105 for j in range(ch.n))
    assert out["trajectory"].success and np.isfinite(out["distance_to_static_mm"])


def test_tip_control(examples, tmp_path, capsys):
    out = examples("tip_control").main(["--quick", "--out", str(tmp_path)])
    traj = out["trajectory"]
    assert traj.success and is_png(out["png"])
    err = out["error"]
    assert err[0] > 0.05 and err[-1] < 0.5 * err[0]  # on its way to the target
    assert np.all(traj.p >= 0.0) and np.all(traj.p <= 1e5)
    assert "tip error" in capsys.readouterr().out



def test_track_circle(examples, tmp_path, capsys):
    """A short run of every controller on both arms: the RMS tip error it reports is the one
    recomputed from the saved states (forward kinematics against the circle), the pressures
    saved stay within the bounds, and the table is printed."""
    mod = examples("track_circle")
    out = mod.main(["--duration", "0.1", "--out", str(tmp_path)])
    assert is_png(out["png"]) and out["png"].parent == tmp_path
    ch, circle = out["chain"], out["circle"]
    res = out["results"]
    assert [(r["name"], r["case"]) for r in res] == [(n, c) for n, _ in mod.CONTROLLERS for c in ("matched", "mismatched")]
    printed = capsys.readouterr().out
    for r in res:
        run = np.load(tmp_path / f"{r['key']}.npz")
        assert math.isclose(run["t"][-1], 0.1)
        tip = np.array([ch.tip_placement(q).translation for q in run["q"]])
        rms = np.sqrt(np.mean(np.sum((tip - circle.point(run["t"])) ** 2, axis=1)))
        assert r["rms_mm"] == pytest.approx(rms * 1e3, rel=1e-12)
        assert f"{r['rms_mm']:.3f}" in printed
        assert np.all(run["p"] >= 0.0) and np.all(run["p"] <= mod.P_MAX)
        sig = np.load(tmp_path / f"{r['key']}-signals.npz")
        assert len(sig["t"]) >= 0.1 * r["rate"] and np.all(sig["p"] >= 0.0) and np.all(sig["p"] <= mod.P_MAX)
        assert r["compute_us"] == pytest.approx(np.median(sig["compute_s"]) * 1e6)
        assert r["p_rms_kpa"] == pytest.approx(np.sqrt(np.mean(run["p"] ** 2)) / 1e3)
    # the mismatched arm: moduli one standard error up and 20 g at the tip
    plant = mod.mismatched(ch)
    assert plant.payload.mass == pytest.approx(0.02)
    assert plant.segments[0].youngs_modulus == pytest.approx(ch.segments[0].youngs_modulus * (1 + mod.E_REL_STDERR))


def test_reach_obstacle(examples, tmp_path, capsys):
    """A short run: the straight approach runs into the ball and is held by it (the contact
    force it reports is the one of the arm's contacts; the tip's backbone point stays outside
    the ball, the tip no nearer the target than half the start's distance), the via-point
    approach heads for its first via point without touching; the pressures stay within the bounds."""
    mod = examples("reach_obstacle")
    out = mod.main(["--quick", "--out", str(tmp_path)])
    assert is_png(out["png"]) and out["png"].parent == tmp_path
    ch, env, vias = out["chain"], out["env"], out["vias"]
    straight, by_via = out["results"]["straight"], out["results"]["via points"]
    for r in (straight, by_via):
        traj = r["trajectory"]
        assert traj.success and math.isclose(traj.t[-1], 0.5)
        assert np.all(traj.p >= 0.0) and np.all(traj.p <= mod.P_MAX)
        ball = env.obstacles[0]
        assert np.linalg.norm(r["tip"] - ball.center, axis=1).min() > ball.radius
    k = int(np.argmax(straight["force"]))
    traj = straight["trajectory"]
    c = ch.contacts(traj.q[k], traj.v[k], env)
    assert straight["force"].max() > 0.5 and straight["force"][k] == pytest.approx(np.linalg.norm(c.force.sum(axis=0)))
    assert straight["error"][-1] > 0.5 * straight["error"][0]
    assert np.all(by_via["force"] == 0.0)
    d = np.linalg.norm(by_via["tip"][by_via["trajectory"].t < mod.SWITCHES[0]] - vias[0], axis=1)
    assert d[-1] < 0.5 * d[0]
    assert "final tip error" in capsys.readouterr().out

@pytest.mark.slow
def test_an_example_runs_as_a_script(tmp_path):
    r = subprocess.run([sys.executable, str(EXAMPLES / "moving_base.py"), "--duration", "0.05", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert f"wrote {tmp_path / 'moving_base.png'}" in r.stdout and is_png(tmp_path / "moving_base.png")


def test_an_example_runs_another_scene(examples, tmp_path):
    """``--scene FILE`` replaces the example's own scene: here a mount shaken half as far."""
    text = (EXAMPLES / "scenes" / "moving_base.toml").read_text()
    assert text.count("amplitude = 0.02 ") == 1
    scene = tmp_path / "half.toml"
    scene.write_text(text.replace("amplitude = 0.02 ", "amplitude = 0.01 "))
    out = examples("moving_base").main(["--quick", "--out", str(tmp_path), "--scene", str(scene)])
    t = out["trajectory"].t
    assert np.allclose(out["mount"][:, 0], 0.01 * np.sin(2 * np.pi * 1.5 * t), rtol=0, atol=1e-15)


def test_bend_segment(examples, tmp_path, capsys):
    out = examples("bend_segment").main(["--quick", "--out", str(tmp_path)])
    assert is_png(out["png"]) and out["png"].parent == tmp_path
    q_rest, q_bent = out["shapes"]["rest"], out["shapes"]["chamber 1, 80 kPa"]
    assert math.hypot(*q_rest[1:]) < 1e-9 < math.hypot(*q_bent[1:])  # (l, ux, uy): only pressure bends it
    assert "wrote" in capsys.readouterr().out


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(p.stem for p in EXAMPLES.glob("*.py") if not p.stem.startswith("_")))
def test_every_example_has_the_promised_flags(name):
    """The README promises ``--quick`` and ``--out DIR`` of every example, ``--scene FILE`` of
    each that runs a scene file of ``examples/scenes/``."""
    r = subprocess.run([sys.executable, str(EXAMPLES / f"{name}.py"), "--help"], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 0, r.stderr
    assert "--quick" in r.stdout and "--out DIR" in r.stdout, r.stdout
    if (EXAMPLES / "scenes" / f"{name}.toml").is_file():
        assert "--scene FILE" in r.stdout, r.stdout


def test_calibrate(examples, tmp_path, capsys):
    """The fit from a lab-style ROS 2 bag (1 s, 0.5 mm mocap noise, 300 Pa pressure noise):
    the moduli and chamber area within 5 % of the hidden values, the damping within 25 %;
    the residuals at the noise's size; the fitted model's tip far closer to the measured one
    than the datasheet model's; the fitted scene a scene."""
    out = examples("calibrate").main(["--quick", "--out", str(tmp_path)])
    mod = examples("calibrate")
    res = out["report"].result
    hidden = np.array([mod.HIDDEN[k] for k in mod.KEYS])
    rel = np.abs(res.x / hidden - 1)
    assert np.all(rel[[0, 1, 3]] < 0.05) and rel[2] < 0.25, rel
    assert 0.4e-3 < res.sigma < 0.6e-3
    assert out["rms_after"] < out["rms_before"] / 3
    assert is_png(out["png"]) and out["bag"].stat().st_size > 0
    from qchain.scene import load_scene

    fitted = load_scene(out["fitted"]).build(reduce=False).chain
    assert fitted.segments[0].youngs_modulus == pytest.approx(res.x[0], rel=1e-9)
    assert "fitted - hidden, in standard errors" in capsys.readouterr().out


def test_reach_env(examples, tmp_path, capsys):
    """The tracking policy ends closer to the target and with a higher return than the random
    one, episode by episode (the same seeds: the same targets)."""
    pytest.importorskip("gymnasium")
    out = examples("reach_env").main(["--quick", "--out", str(tmp_path)])
    assert is_png(out["png"]) and out["png"].parent == tmp_path
    track, rand = out["results"]["tracking"], out["results"]["random"]
    assert len(track) == len(rand) == 2
    for a, b in zip(track, rand):
        assert np.array_equal(a["target"], b["target"])
        assert a["distance"] < 0.5 * b["distance"] and a["ret"] > b["ret"]
    assert "final distance" in capsys.readouterr().out


def test_tendon_arm(examples, tmp_path, capsys):
    out = examples("tendon_arm").main(["--quick", "--out", str(tmp_path)])
    traj, tips, ch = out["trajectory"], out["tips"], out["chain"]
    assert traj.success and traj.meta["engine"] == "compiled" and is_png(out["png"])
    assert np.all(traj.tension[-1] == [5.0, 4.0]) and np.all(traj.tension >= 0.0)
    assert tips[-1, 0] > 0.02  # tendon 0 on the base's +x side pulls the arm towards +x
    assert abs(tips[-1, 1]) > 0.002  # the helix, which changes side, bends it out of the x-z plane
    # segment 2 lies past tendon 0's end: only the helix (and gravity) act there
    assert np.all(ch.tendon_matrix(traj.q[-1])[6:, 0] == 0.0)
    assert "from the static shape" in capsys.readouterr().out
