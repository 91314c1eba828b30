"""The reaching task shared by the single and the vectorised environment (docs/envs.md):
the arm, its spaces, the map from actions to pressures, the reward, the targets.

One :class:`ReachTask` holds everything that does not change during an episode, so that
:class:`qchain.envs.reach.SoftArmReachEnv` and :class:`qchain.envs.vector.SoftArmReachVec`
compute the same observation, reward and termination from the same state, and the same
targets from the same seeds.
"""

from __future__ import annotations

import os

import numpy as np
from gymnasium import spaces

from ..arm.statics import equilibrium
from ..checks import bounds as B
from ..checks.convert import as_real_array, as_vector, describe_value
from ..scene.reading import load_scene, parse_scene
from ..scene.scene import Scene
from ..sim.simulation import FIXED_STEP

#: The built-in arm (the arm of ``examples/scenes/tip_control.toml``): three inextensible
#: segments of 10 cm hanging from a fixed mount 0.5 m above the ground, 9 chambers.
DEFAULT_SCENE = """\
name = "soft arm reach"
description = "three inextensible segments hanging from a fixed mount; pressures chosen by an agent"
gravity = [0.0, 0.0, -9.81]

[model]
node_tolerance = 1e-8
max_bend = 1.5

[[segments]]
count = 3
length = 0.1
radius = 0.015
mass = 0.05
chamber_area = 4.5e-5
chamber_radius = 0.0085
youngs_modulus = 1e5
damping = 0.02
extensible = false

[base]
type = "fixed"
position = [0.0, 0.0, 0.5]
rpy = [3.141592653589793, 0.0, 0.0]

[simulation]
duration = 2.0
method = "rk4"
dt = 2e-3
"""

#: How many pressure sets :meth:`ReachTask.draw_target` tries before it gives up.
TARGET_TRIES = 20


def _scene(scene) -> Scene:
    """``scene``: None (the built-in arm), a path to a scene file, or a :class:`Scene`."""
    if scene is None:
        return parse_scene(DEFAULT_SCENE, "<SoftArmReach-v0>")
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, (str, os.PathLike)):
        return load_scene(scene)
    raise TypeError(f"scene must be None, a path to a scene file or a qchain.Scene, got {describe_value(scene)}")


class ReachTask:
    """A fixed-base arm reaching for a target with its chamber pressures.

    Parameters
    ----------
    scene : None, str, os.PathLike or Scene
        The arm (docs/scene-format.md): None for the built-in three-segment arm
        (:data:`DEFAULT_SCENE`). Its base must be fixed; obstacles and point loads are refused
        (the vectorised form's batch engine takes none). The scene's method, ``dt``, ``rtol``
        and ``atol`` integrate every control period; its pressures and duration are not used.
    dt_control : float, s
        Control period: each action's pressures are held this long (default 20 ms);
        :data:`qchain.checks.bounds.STEP`, and at least the scene's ``dt`` for a fixed-step method.
    max_time : float, s
        Episode length: ``truncated`` once this much simulated time has passed (default 2 s).
    p_min, p_max : float, Pa
        Gauge pressure of every chamber at action -1 and +1 (defaults 0 and 100 kPa), within
        :data:`qchain.checks.bounds.PRESSURE`, ``p_min < p_max``.
    tolerance : float, m
        ``terminated`` (success) once the tip is within this distance of the target (default 5 mm).
    effort_weight : float, m
        Weight of the pressure effort in the reward (default 1e-3 m; see :meth:`reward`).
    domain_penalty : float, m
        The reward of a step that leaves the model's domain (``-domain_penalty``, default 10).
    """

    def __init__(self, scene=None, *, dt_control: float = 0.02, max_time: float = 2.0, p_min: float = 0.0,
                 p_max: float = 1.0e5, tolerance: float = 5e-3, effort_weight: float = 1e-3,
                 domain_penalty: float = 10.0):
        sc = _scene(scene)
        self.dt_control = B.STEP.check("dt_control", dt_control)
        self.max_time = B.DURATION.check("max_time", max_time)
        self.p_min = B.PRESSURE.check("p_min", p_min)
        self.p_max = B.PRESSURE.check("p_max", p_max)
        if not self.p_max > self.p_min:
            raise ValueError(f"p_max must be > p_min = {self.p_min:g} Pa, got {self.p_max:g} Pa")
        self.tolerance = B.EXTENT.check("tolerance", tolerance)
        self.effort_weight = B.REWARD_WEIGHT.check("effort_weight", effort_weight)
        self.domain_penalty = B.PENALTY.check("domain_penalty", domain_penalty)
        if sc.base.type != "fixed":
            raise ValueError(f"scene: the reach environment needs a fixed base, got base type {sc.base.type!r}")
        if sc.environment is not None:
            raise ValueError("scene: the reach environment takes no obstacles or point loads "
                             "([[obstacles]], [[loads]]): its batch engine (qchain.simulate_batch) has no contact")
        if sc.tendons:
            raise ValueError("scene: the reach environment takes no tendons ([[tendons]]): its actions are chamber "
                             "pressures and its batch engine (qchain.simulate_batch) has no tensions")
        if sc.method in FIXED_STEP and self.dt_control < sc.dt:
            raise ValueError(f"dt_control must be >= the scene's step dt = {sc.dt:g} s, got {self.dt_control:g} s")
        self.scene = sc
        model = sc.build(controlled=True)  # pressures from outside: no planar reduction
        self.chain = ch = model.chain
        self.nu = ch.nu
        self.method = sc.method
        # the settings of every control period's run; the single and the vectorised
        # environment pass exactly these, so that their runs are the same runs
        self.run_settings = dict(method=sc.method, dt=sc.dt, rtol=sc.rtol, atol=sc.atol, max_step=sc.max_step,
                                 t_eval=np.array([self.dt_control]), energies=False, budget=sc.budget)
        self.base = ch.base_placement.translation.copy()
        rest = equilibrium(ch, np.full(self.nu, self.p_min))
        if not rest.success:
            raise ValueError(f"p_min = {self.p_min:g} Pa: the arm has no static shape under it ({rest.message})")
        self.q_rest = rest.q.copy()  # every episode starts at rest under p_min
        self.v_rest = np.zeros(ch.nv)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.nu,), dtype=np.float64)
        self._obs_bounds()

    # ------------------------------------------------------------------ spaces

    def _obs_bounds(self) -> None:
        """The observation ``[q (nq), v (nv), tip (3), target (3)]``: each segment's ``l`` in
        ``[0, inf)`` m (``l0`` where it is locked), ``ux, uy`` in ``[-1/r_s, 1/r_s]`` 1/m (the
        domain's ``|kappa| r_s < 1``; paper coordinates: ``psi`` in :data:`qchain.checks.bounds.PSI`,
        ``kappa`` in ``[0, 1/r_s]``), rates unbounded, tip and target within the arm's reach
        of the base (a cube of half-side the sum of the rest lengths; unbounded if a segment
        stretches)."""
        ch = self.chain
        lo_q, hi_q = [], []
        reach = 0.0
        for seg in ch.segments:
            k = 1.0 / seg.radius
            if seg.coords == "paper":
                lo_q += [0.0, B.PSI.low, 0.0]
                hi_q += [np.inf, B.PSI.high, k]
            else:
                lo_q += [0.0, -k, -k]
                hi_q += [np.inf, k, k]
            reach += seg.length if not seg.extensible else np.inf
        lo_q, hi_q = np.array(lo_q), np.array(hi_q)
        lo_x, hi_x = self.base - reach, self.base + reach
        inf = np.full(ch.nv, np.inf)
        self.obs_low = np.concatenate([lo_q, -inf, lo_x, lo_x])
        self.obs_high = np.concatenate([hi_q, inf, hi_x, hi_x])
        self.observation_space = spaces.Box(self.obs_low, self.obs_high, dtype=np.float64)
        nq, nv = ch.nq, ch.nv
        self.slices = dict(q=slice(0, nq), v=slice(nq, nq + nv), tip=slice(nq + nv, nq + nv + 3),
                           target=slice(nq + nv + 3, nq + nv + 6))

    # ------------------------------------------------------------------ maps

    def pressures(self, action) -> np.ndarray:
        """Chamber pressures ``p (3 n,)`` Pa of ``action (3 n,)``: ``p = p_min + (a + 1) / 2
        (p_max - p_min)``, ``a`` clipped to ``[-1, 1]`` (a policy's samples may leave the box);
        a non-finite entry raises ``ValueError`` naming it."""
        a = np.clip(as_vector("action", action, self.nu), -1.0, 1.0)
        return self.p_min + 0.5 * (a + 1.0) * (self.p_max - self.p_min)

    def pressures_batch(self, actions, num_envs: int) -> np.ndarray:
        """:meth:`pressures` of ``actions (num_envs, 3 n)``, row by row: ``(num_envs, 3 n)`` Pa."""
        A = as_real_array("actions", actions)
        if A.shape != (num_envs, self.nu):
            raise ValueError(f"actions must have shape ({num_envs}, {self.nu}), got {A.shape}")
        return np.stack([self.pressures(a) for a in A]) if num_envs else A

    def tip(self, q) -> np.ndarray:
        """World position of the tip (3,) m."""
        return self.chain.tip_placement(q).translation.copy()

    def observe(self, q, v, target) -> np.ndarray:
        """The observation ``[q, v, tip(q), target]`` (float64)."""
        return np.concatenate([q, v, self.tip(q), target])

    def reward(self, distance: float, p) -> float:
        """``-|tip - target| - effort_weight * mean(u^2)`` (m), ``u = (p - p_min) / (p_max -
        p_min)`` in ``[0, 1]`` the chambers' share of the pressure range."""
        u = (np.asarray(p) - self.p_min) / (self.p_max - self.p_min)
        return float(-distance - self.effort_weight * np.mean(u * u))

    def outcome(self, q, v, target, p, ok: bool, message: str, elapsed: float):
        """One control period's end, the same for both environments: ``(obs, reward,
        terminated, truncated, info)`` at the state ``(q, v)`` the run reached at the period's
        end; ``ok``: whether it got there (False: it left the model's domain or its state
        became non-finite: terminated, reward ``-domain_penalty``, ``info["domain_error"]``
        the run's message, and ``(q, v)`` the state at the period's start, the last one inside
        the domain on the control grid)."""
        obs = self.observe(q, v, target)
        d = float(np.linalg.norm(obs[self.slices["tip"]] - target))
        info = {"distance": d, "elapsed": elapsed, "pressure": np.array(p, dtype=float)}
        if not ok:
            info["domain_error"] = message
            return obs, -self.domain_penalty, True, False, info
        reached = d <= self.tolerance
        truncated = (not reached) and elapsed >= self.max_time * (1 - 1e-12)
        return obs, self.reward(d, p), reached, truncated, info

    # ------------------------------------------------------------------ targets

    def check_target(self, target) -> np.ndarray:
        """A target given in ``reset(options={"target": ...})``: (3,) m, world, within the
        observation's bounds."""
        x = as_vector("target", target, 3)
        lo, hi = self.obs_low[self.slices["target"]], self.obs_high[self.slices["target"]]
        for k in range(3):
            if not lo[k] <= x[k] <= hi[k]:
                raise ValueError(f"target[{k}] must be within [{lo[k]:g}, {hi[k]:g}] m (the arm's reach of its base), "
                                 f"got {x[k]:g} m")
        return x.copy()

    def draw_target(self, rng: np.random.Generator) -> np.ndarray:
        """A reachable target (3,) m: the tip of the static shape (:func:`qchain.equilibrium`)
        under pressures drawn uniformly in ``[p_min, p_max]`` from ``rng`` (so the same
        generator state gives the same target). Pressure sets without a static shape are
        drawn again, up to :data:`TARGET_TRIES` times."""
        for _ in range(TARGET_TRIES):
            p = rng.uniform(self.p_min, self.p_max, size=self.nu)
            eq = equilibrium(self.chain, p, q0=self.q_rest)
            if eq.success:
                return self.tip(eq.q)
        raise RuntimeError(f"no static shape under {TARGET_TRIES} pressure sets drawn in [{self.p_min:g}, "
                           f"{self.p_max:g}] Pa: lower p_max or pass options={{'target': ...}} to reset")
