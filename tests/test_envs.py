"""qchain/SoftArmReach-v0 (qchain.envs): gymnasium's checker, the vectorised form equal to the
single one bit for bit, observations in their space, the domain ends an episode, bad settings."""

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
import qchain.envs  # noqa: E402,F401  (registers the id)
from gymnasium.utils.env_checker import check_env  # noqa: E402

ID = "qchain/SoftArmReach-v0"


def test_check_env_passes():
    check_env(gym.make(ID).unwrapped, skip_render_check=True)


def test_vectorised_steps_equal_single_steps_bit_for_bit():
    N, K = 3, 8
    venv = gym.make_vec(ID, num_envs=N, vectorization_mode="vector_entry_point", max_time=0.08, workers=2)
    A = np.random.default_rng(0).uniform(-1, 1, (K, N, 9))
    obs, _ = venv.reset(seed=10)
    V, R, D = [obs], [], []
    for k in range(K):
        o, r, te, tr, _ = venv.step(A[k])
        V.append(o), R.append(r), D.append(te | tr)
    assert np.array(D).any()  # an autoreset happened inside the run
    for i in range(N):
        env = gym.make(ID, max_time=0.08)
        o, _ = env.reset(seed=10 + i)
        S, RS, auto = [o], [], False
        for k in range(K):
            if auto:
                (o, _), r, done = env.reset(), 0.0, False
            else:
                o, r, te, tr, _ = env.step(A[k, i])
                done = te or tr
            auto = done
            S.append(o), RS.append(r)
            assert venv.unwrapped.single_observation_space.contains(o)
        assert np.array_equal(np.array(S), np.array(V)[:, i])
        assert np.array_equal(np.array(RS), np.array(R)[:, i])


def test_leaving_the_domain_terminates_instead_of_raising():
    env = gym.make(ID, p_max=3e6, domain_penalty=7.0)
    env.reset(seed=0, options={"target": [0.05, 0.0, 0.3]})
    obs, r, term, trunc, info = env.step(np.array([1.0, -1.0, -1.0] * 3))
    assert term and not trunc and r == -7.0
    assert "|kappa| r_s" in info["domain_error"]
    assert env.observation_space.contains(obs)


@pytest.mark.parametrize("kw, words", [
    (dict(p_max=-2e5), "p_max must be >= -101325"),
    (dict(dt_control=0.0), "dt_control must be > 0"),
    (dict(dt_control=1e-3), "dt_control must be >= the scene's step dt = 0.002 s"),
    (dict(effort_weight=-1.0), "effort_weight must be >= 0"),
    (dict(p_min=5e4, p_max=1e4), "p_max must be > p_min = 50000 Pa"),
])
def test_bad_settings_name_parameter_value_and_bound(kw, words):
    with pytest.raises(ValueError, match=words.replace("|", r"\|")):
        gym.make(ID, **kw)


def test_a_scene_with_tendons_is_refused():
    """The actions are chamber pressures and simulate_batch has no tensions: the scene's
    tendons would be slack, so the environment says so instead."""
    from pathlib import Path

    from qchain.envs.task import ReachTask

    with pytest.raises(ValueError, match=r"takes no tendons \(\[\[tendons\]\]\)"):
        ReachTask(Path(__file__).parent.parent / "examples" / "scenes" / "hanging_tendons.toml")
