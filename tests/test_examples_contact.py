"""The contact examples (examples/wrap_pole.py, examples/push_wall.py, examples/carry_payload.py)
run with ``--quick`` and what they show holds: the arm wraps the pole and holds it, its contact
forces balancing its own; the wall's force after each pressure step settles on the static
balance's, and is zero below the pressure at which the free arm reaches the wall; the lifted
payload settles on the static shape, which is the bare arm's carrying the payload's weight."""

import math

import numpy as np
import pytest

from support import EXAMPLES, is_png




@pytest.fixture(scope="module")
def wrap(examples, tmp_path_factory):
    out_dir = tmp_path_factory.mktemp("wrap_pole")
    return examples("wrap_pole").main(["--quick", "--out", str(out_dir)]), out_dir


@pytest.fixture(scope="module")
def carry(examples, tmp_path_factory):
    out_dir = tmp_path_factory.mktemp("carry_payload")
    return examples("carry_payload").main(["--quick", "--out", str(out_dir)]), out_dir


@pytest.fixture(scope="module")
def push(examples, tmp_path_factory):
    out_dir = tmp_path_factory.mktemp("push_wall")
    return examples("push_wall").main(["--quick", "--out", str(out_dir)]), out_dir


@pytest.mark.slow
def test_wrap_pole_runs_and_draws(wrap):
    out, out_dir = wrap
    traj = out["trajectory"]
    assert traj.success and math.isclose(traj.t[-1], 1.2)
    assert is_png(out["png"]) and out["png"].parent == out_dir


@pytest.mark.slow
def test_wrap_pole_holds_the_pole(wrap):
    """Once the curl closes on the pole the contact persists to the end, the arm turns more
    than half a turn round the pole and its contacts cover more than half the circumference."""
    out, _ = wrap
    n = out["contacts_on_pole"]
    assert n[0] == 0  # it starts straight, clear of the pole
    closed = int(np.argmax(n >= 10))
    assert n[closed] >= 10 and closed < len(n) - 20  # the grasp closes well before the end
    assert n[closed:].min() >= 8  # and never lets go
    assert out["wrap_deg"] > 180.0 and out["span_deg"] > 180.0
    assert out["max_penetration"] < 0.15 * 0.015  # the contact stays shallow: under 15% of the arm's radius


@pytest.mark.slow
def test_wrap_pole_squeezes_and_is_balanced_by_the_contacts(wrap):
    """A grip presses from around the pole: the forces largely cancel (resultant well below the
    sum of their magnitudes), friction acts, and at the end the pressure, elastic and damping
    forces are balanced by the contact forces alone (inertia negligible: settled)."""
    out, _ = wrap
    assert out["grip"][-1] > 0.1  # N
    assert out["resultant"][-1] < 0.5 * out["grip"][-1]
    assert out["friction"][-1] > 0.0
    assert out["balance"] < 1e-2
    # the frictionless static shape (Newton, from the final shape) is near: friction holds the
    # arm a few mm from it at most
    assert out["static"].success and out["to_static"] < 0.01


@pytest.mark.slow
def test_push_wall_runs_and_draws(push):
    out, out_dir = push
    assert out["trajectory"].success and is_png(out["png"]) and out["png"].parent == out_dir
    assert list(out["levels"]) == [3e4, 9e4, 1.5e5]


@pytest.mark.slow
def test_push_wall_settles_on_the_static_force(push):
    """After each pressure step the damped arm comes to rest: the wall's force there equals the
    static balance's (qchain.equilibrium with env=) to 1e-5 (relative), and the force grows with pressure."""
    out, _ = push
    settled, static = out["settled"], out["static"]
    touching = static > 0
    assert touching.sum() == 2
    assert np.allclose(settled[touching], static[touching], rtol=1e-5, atol=0)
    assert np.all(np.diff(static) > 0) and static[-1] > 0.2  # N


@pytest.mark.slow
def test_push_wall_no_force_before_the_free_arm_reaches_the_wall(push):
    """The pressure at which the free arm (statics without the wall) reaches the wall splits the
    levels: below it the settled and static forces are zero, above it both are positive."""
    out, _ = push
    below = out["levels"] < out["onset"]
    assert below.any() and (~below).any()
    assert np.all(out["settled"][below] == 0.0) and np.all(out["static"][below] == 0.0)
    assert np.all(out["settled"][~below] > 0.0) and np.all(out["static"][~below] > 0.0)
    assert out["max_penetration"] < 0.15 * 0.015


@pytest.mark.slow
def test_push_floor_obeys_coulomb(push):
    """The free arm lying on the floor, pulled at its tip (push_wall.py's second part), against
    Coulomb's law with the arm's weight W = m g (independent of the contact passes): the floor
    carries W; under half the static limit the arm stays put, friction cancelling the load;
    at 1.5 times it the arm slides, its momentum growing at F - mu_dynamic W."""
    out, out_dir = push
    d = out["drag"]
    W, law = d["weight"], d["law"]
    assert is_png(d["png"]) and d["png"].parent == out_dir
    hold, slide = d["runs"][0.5], d["runs"][1.5]
    for r in (hold, slide):
        assert r["trajectory"].success
        assert abs(r["normal"] - W) < 1e-4 * W
    assert abs(hold["friction"] + hold["load"]) < 1e-3 * hold["load"]
    assert abs(hold["momentum"]).max() < d["mass"] * 2 * law.slip_velocity  # creeping slower than 2 eps
    # the regularised law's creep: F = mu(s) W s / sqrt(s^2 + eps^2), solved for s by fixed point
    eps, creep = law.slip_velocity, 0.0
    for _ in range(50):
        mu = law.mu_dynamic + (law.mu_static - law.mu_dynamic) * math.exp(-((creep / law.stribeck_velocity) ** 2))
        creep = eps / math.sqrt((mu * W / hold["load"]) ** 2 - 1.0)
    assert abs(hold["momentum"][-1] / d["mass"] - creep) < 0.01 * creep
    assert slide["momentum"][-1] > 0.1  # kg m/s: well on its way
    assert abs(slide["rate"] - (slide["load"] - law.mu_dynamic * W)) < 1e-3 * (slide["load"] - law.mu_dynamic * W)
    assert abs(slide["friction"] + law.mu_dynamic * W) < 1e-3 * law.mu_dynamic * W


@pytest.mark.slow
def test_carry_payload_runs_and_draws(carry):
    out, out_dir = carry
    traj = out["trajectory"]
    assert traj.success and math.isclose(traj.t[-1], 2.5)  # --quick: the lift and its hold
    assert is_png(out["png"]) and out["png"].parent == out_dir
    P = out["chain"].payload
    assert P.mass == 0.04 and P.mass > 0.4 * sum(s.mass for s in out["chain"].segments)  # a fair share of the arm
    assert out["peak_pressure"] == 2e5


@pytest.mark.slow
def test_carry_payload_lifts_it_onto_the_static_shape(carry):
    """The scene's arm lifts its ball more than 100 mm above where it hangs; after the hold it
    has settled (the ball slower than 10 mm/s) within 1 mm of qchain.equilibrium's shape at the
    held pressures; and that shape is the bare arm's carrying the ball's weight as a tip
    PointLoad (force m g, moment (R c) x m g: the environment's load path, not the payload's)."""
    out, _ = carry
    ch, com = out["chain"], out["payload_centres"]
    hang = out["hanging"]
    assert hang.success and out["static"].success
    assert np.allclose(out["hanging_centre"], ch.tip_placement(hang.q).act(ch.payload.lever))
    assert com[0, 2] - out["hanging_centre"][2] < 2e-3  # it starts hanging (straight, a little above its sag)
    assert out["lift"] > 0.1  # m
    assert out["end_speed"] < 0.01 and out["to_static"] < 1e-3  # m/s, m
    assert out["load_vs_payload"] < 1e-9  # m
