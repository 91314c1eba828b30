"""``qchain/SoftArmReach-v0`` vectorised: N arms stepped in one batch of compiled rollouts
(:func:`qchain.simulate_batch` on threads) instead of N Python environments (docs/envs.md)."""

from __future__ import annotations

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from ..batch.rollouts import simulate_batch
from ..batch.threads import ThreadPool
from ..checks import bounds as B
from ..checks.convert import as_real_array
from .task import ReachTask


class SoftArmReachVec(VectorEnv):
    """``num_envs`` copies of :class:`qchain.envs.reach.SoftArmReachEnv` stepped together.

    Every :meth:`step` runs the sub-environments' control periods as one
    :func:`qchain.simulate_batch` call on a :class:`qchain.batch.threads.ThreadPool` (the
    compiled engine releases Python's lock: no Python between rollouts). Sub-environment
    ``i`` gives what a :class:`~qchain.envs.reach.SoftArmReachEnv` gives with the same seed
    and actions, bit for bit (each rollout of a batch equals :func:`qchain.simulate`).

    Parameters
    ----------
    num_envs : int
        Sub-environments, 1 to 4096 (:data:`qchain.checks.bounds.ENV_COUNT`).
    scene : None, path or Scene
        The arm, as :class:`~qchain.envs.reach.SoftArmReachEnv`'s.
    workers : int or None
        Threads of the batch (None: one a core this process may use).
    render_mode : None
    **settings
        :class:`~qchain.envs.task.ReachTask`'s settings.

    Autoreset: gymnasium's next-step mode (``metadata["autoreset_mode"]``): the step after a
    sub-environment ends resets it (its action is ignored; reward 0, not terminated nor
    truncated). ``reset(seed=s)`` seeds sub-environment ``i`` with ``s + i`` (a list: one seed
    each), as :class:`gymnasium.vector.SyncVectorEnv` does; ``options``: ``reset_mask`` (N,)
    bool, ``target`` (3,) or (N, 3) m. ``infos``: the single environment's keys as arrays
    (N,), each with its ``_key`` mask.
    """

    metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP, "render_modes": []}

    def __init__(self, num_envs: int = 1, scene=None, workers: int | None = None, render_mode=None, **settings):
        if render_mode is not None:
            raise ValueError(f"render_mode must be None (SoftArmReach-v0 does not render), got {render_mode!r}")
        self.render_mode = None
        self.num_envs = B.ENV_COUNT.check("num_envs", num_envs)
        self.task = task = ReachTask(scene, **settings)
        self.pool = ThreadPool(workers)
        self.single_action_space = task.action_space
        self.single_observation_space = task.observation_space
        self.action_space = batch_space(task.action_space, self.num_envs)
        self.observation_space = batch_space(task.observation_space, self.num_envs)
        N = self.num_envs
        self._Q = np.tile(task.q_rest, (N, 1))
        self._V = np.tile(task.v_rest, (N, 1))
        self._targets = np.tile(task.tip(task.q_rest), (N, 1))
        self._elapsed = np.zeros(N)
        self._autoreset = np.zeros(N, dtype=bool)
        self._rngs: list[np.random.Generator | None] = [None] * N

    # ------------------------------------------------------------------ reset

    def _rng(self, i: int) -> np.random.Generator:
        if self._rngs[i] is None:  # never seeded: a random seed, as gymnasium.Env does
            self._rngs[i], _ = seeding.np_random()
        return self._rngs[i]

    def _reset_one(self, i: int, seed=None, target=None) -> dict:
        task = self.task
        if seed is not None:
            self._rngs[i], _ = seeding.np_random(seed)  # what gymnasium.Env.reset(seed=) does
        self._targets[i] = task.draw_target(self._rng(i)) if target is None else task.check_target(target)
        self._Q[i], self._V[i] = task.q_rest, task.v_rest
        self._elapsed[i] = 0.0
        self._autoreset[i] = False
        return {"distance": float(np.linalg.norm(task.tip(self._Q[i]) - self._targets[i])), "elapsed": 0.0}

    def reset(self, *, seed: int | list | None = None, options: dict | None = None):
        N = self.num_envs
        if seed is None:
            seeds = [None] * N
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, (bool, np.bool_)):
            seeds = [int(seed) + i for i in range(N)]
        else:
            seeds = list(seed)
            if len(seeds) != N:
                raise ValueError(f"seed: a list of seeds must have num_envs = {N} entries, got {len(seeds)}")
        options = dict(options or {})
        mask = np.asarray(options.pop("reset_mask", np.ones(N, dtype=bool)))
        if mask.shape != (N,) or mask.dtype != np.bool_:
            raise ValueError(f"options['reset_mask'] must be a bool array of shape ({N},), got {mask.dtype} {mask.shape}")
        targets = options.pop("target", None)
        if targets is not None:
            targets = as_real_array("options['target']", targets)
            targets = np.broadcast_to(targets, (N, 3)) if targets.shape in ((3,), (N, 3)) else None
            if targets is None:
                raise ValueError(f"options['target'] must have shape (3,) or ({N}, 3) m")
        infos: dict = {}
        for i in np.flatnonzero(mask):
            info = self._reset_one(int(i), seeds[i], None if targets is None else targets[i])
            infos = self._add_info(infos, info, int(i))
        return self._observations(), infos

    # ------------------------------------------------------------------ step

    def _observations(self) -> np.ndarray:
        return np.stack([self.task.observe(q, v, x) for q, v, x in zip(self._Q, self._V, self._targets)])

    def step(self, actions):
        task, N = self.task, self.num_envs
        P = task.pressures_batch(actions, N)
        rewards = np.zeros(N)
        terminated = np.zeros(N, dtype=bool)
        truncated = np.zeros(N, dtype=bool)
        obs = np.empty((N,) + self.single_observation_space.shape)
        infos: dict = {}
        resets = np.flatnonzero(self._autoreset)
        for i in resets:
            infos = self._add_info(infos, self._reset_one(int(i)), int(i))
            obs[i] = task.observe(self._Q[i], self._V[i], self._targets[i])
        run = np.flatnonzero(~np.isin(np.arange(N), resets))
        if run.size:
            batch = simulate_batch(task.chain, self._Q[run], self._V[run], (0.0, task.dt_control), pressure=P[run],
                                   workers=self.pool, **task.run_settings)
            for k, i in enumerate(run):
                if batch.nsamples[k]:  # reached the period's end; else the state stays the period's start
                    self._Q[i], self._V[i] = batch.q[k, -1], batch.v[k, -1]
                self._elapsed[i] += task.dt_control
                obs[i], rewards[i], terminated[i], truncated[i], info = task.outcome(
                    self._Q[i], self._V[i], self._targets[i], P[i], bool(batch.success[k]), str(batch.message[k]),
                    float(self._elapsed[i]))
                infos = self._add_info(infos, info, int(i))
        self._autoreset = terminated | truncated
        return obs, rewards, terminated, truncated, infos
