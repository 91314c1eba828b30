"""Reach for targets in the Gymnasium environment qchain/SoftArmReach-v0 (docs/envs.md).

Two policies, a few episodes each, the same seeds (the same targets): an incremental
task-space policy (the action moves by ``gain * pinv(J) (target - tip)``, ``J`` the static
tip's sensitivity to the actions at mid pressure, by finite differences of
:func:`qchain.equilibrium` in this script) and a random one. Prints each episode's return and
final distance; draws the first episode's tip paths against its target (``reach_env.png``).
"""

from __future__ import annotations

import sys

import numpy as np

import _common

import gymnasium  # noqa: E402

import qchain.envs  # noqa: E402,F401  (registers qchain/SoftArmReach-v0)
from qchain import equilibrium  # noqa: E402
from qchain.envs import ENV_ID  # noqa: E402


def static_jacobian(task, h: float = 0.05) -> np.ndarray:
    """d tip / d action (3, 3 n) m of the static shape at action 0 (central differences)."""
    def tip(a):
        eq = equilibrium(task.chain, task.pressures(a), q0=task.q_rest)
        return task.tip(eq.q)
    a0 = np.zeros(task.nu)
    return np.column_stack([(tip(a0 + h * e) - tip(a0 - h * e)) / (2 * h) for e in np.eye(task.nu)])


def episode(env, policy, seed):
    obs, info = env.reset(seed=seed)
    task = env.unwrapped.task
    tips, ret, a = [obs[task.slices["tip"]]], 0.0, np.zeros(task.nu)
    while True:
        a = policy(obs, a)
        obs, r, term, trunc, info = env.step(a)
        ret += r
        tips.append(obs[task.slices["tip"]])
        if term or trunc:
            return ret, info["distance"], np.array(tips), obs[task.slices["target"]]


def main(argv=None):
    args = _common.parser(__doc__, "reach_env", scene_flag=False).parse_args(argv)
    max_time = 0.4 if args.quick else 2.0
    episodes = 2 if args.quick else 4
    env = gymnasium.make(ENV_ID, max_time=max_time)
    task = env.unwrapped.task
    Jp = np.linalg.pinv(static_jacobian(task), rcond=1e-3)  # straight arm: no first-order z motion (a ~0 row)
    sl_tip, sl_target = task.slices["tip"], task.slices["target"]
    rng = np.random.default_rng(0)

    def tracking(obs, a):
        return np.clip(a + 0.5 * Jp @ (obs[sl_target] - obs[sl_tip]), -1.0, 1.0)

    def random(obs, a):
        return rng.uniform(-1.0, 1.0, task.nu)

    results = {}
    for name, policy in (("tracking", tracking), ("random", random)):
        results[name] = []
        for k in range(episodes):
            ret, dist, tips, target = episode(env, policy, seed=k)
            results[name].append(dict(ret=ret, distance=dist, tips=tips, target=target))
            print(f"{name:>8} episode {k}: return {ret:8.3f} m, final distance {dist * 1e3:6.1f} mm")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 5))
    for name, c in (("tracking", "C0"), ("random", "C1")):
        tips = results[name][0]["tips"] * 1e3
        ax.plot(tips[:, 0], tips[:, 1], color=c, label=f"{name} policy")
    tgt = results["tracking"][0]["target"] * 1e3
    ax.plot(tgt[0], tgt[1], "k*", ms=12, label="target")
    ax.set(xlabel="x (mm)", ylabel="y (mm)", title="tip path seen from above, episode 0", aspect="equal")
    ax.legend()
    png = _common.save_figure(fig, args.out, "reach_env.png")
    env.close()
    return {"results": results, "png": png}


if __name__ == "__main__":
    main(sys.argv[1:])
