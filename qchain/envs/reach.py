"""``qchain/SoftArmReach-v0``: a soft arm's chamber pressures reach for a target
(docs/envs.md), one arm a :class:`SoftArmReachEnv`."""

from __future__ import annotations

import gymnasium
import numpy as np

from ..sim.simulation import simulate
from .task import ReachTask


class SoftArmReachEnv(gymnasium.Env):
    """A fixed-base soft arm whose chamber pressures move its tip to a target.

    Each :meth:`step` holds the action's pressures for ``dt_control`` and integrates the arm
    over that period from its current state with the compiled engine
    (:func:`qchain.simulate`, the scene's method). Spaces, reward and termination:
    :class:`qchain.envs.task.ReachTask` and docs/envs.md.

    Parameters
    ----------
    scene : None, path or Scene
        The arm; None for the built-in three-segment arm.
    render_mode : None
        No rendering (a recording of the states is the way to look: docs/recording.md).
    **settings
        :class:`~qchain.envs.task.ReachTask`'s ``dt_control``, ``max_time``, ``p_min``,
        ``p_max``, ``tolerance``, ``effort_weight``, ``domain_penalty``.

    Observation ``[q (nq), v (nv), tip (3) m, target (3) m]`` (float64); action ``(3 n,)`` in
    ``[-1, 1]``, chamber pressure ``p_min + (a + 1) / 2 (p_max - p_min)`` Pa.
    ``reset(seed=s)`` draws the target from ``s`` (the same target for the same seed);
    ``reset(options={"target": (3,) m})`` sets it. ``info``: ``distance`` (m), ``elapsed``
    (s), ``pressure`` (3 n,) Pa, and ``domain_error`` (the run's message) when a step left the
    model's domain.
    """

    metadata = {"render_modes": []}

    def __init__(self, scene=None, render_mode=None, **settings):
        if render_mode is not None:
            raise ValueError(f"render_mode must be None (SoftArmReach-v0 does not render), got {render_mode!r}")
        self.render_mode = None
        self.task = ReachTask(scene, **settings)
        self.action_space = self.task.action_space
        self.observation_space = self.task.observation_space
        self._q, self._v = self.task.q_rest.copy(), self.task.v_rest.copy()
        self._target = self.task.tip(self._q)
        self._elapsed = 0.0

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        task = self.task
        target = None if options is None else options.get("target")
        self._target = task.draw_target(self.np_random) if target is None else task.check_target(target)
        self._q, self._v = task.q_rest.copy(), task.v_rest.copy()
        self._elapsed = 0.0
        obs = task.observe(self._q, self._v, self._target)
        return obs, {"distance": float(np.linalg.norm(obs[task.slices["tip"]] - self._target)), "elapsed": 0.0}

    def step(self, action):
        task = self.task
        p = task.pressures(action)
        tr = simulate(task.chain, self._q, self._v, (0.0, task.dt_control), pressure=p, **task.run_settings)
        if len(tr.t):  # reached the period's end (its one sample); else the state stays the period's start
            self._q, self._v = tr.q[-1].copy(), tr.v[-1].copy()
        self._elapsed += task.dt_control
        return task.outcome(self._q, self._v, self._target, p, tr.success, tr.message, self._elapsed)
