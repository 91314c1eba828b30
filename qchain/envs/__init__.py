"""Gymnasium environments over the compiled engine (docs/envs.md).

``import qchain.envs`` registers ``qchain/SoftArmReach-v0``: a fixed-base soft arm whose
chamber pressures reach for a target (:class:`qchain.envs.reach.SoftArmReachEnv`), with a
vectorised form that steps N arms in one batch of compiled rollouts
(:class:`qchain.envs.vector.SoftArmReachVec`)::

    import gymnasium as gym
    import qchain.envs

    env = gym.make("qchain/SoftArmReach-v0")                      # the built-in 3-segment arm
    env = gym.make("qchain/SoftArmReach-v0", scene="arm.toml")    # another fixed-base arm
    envs = gym.make_vec("qchain/SoftArmReach-v0", num_envs=8, vectorization_mode="vector_entry_point")

Needs the optional ``gymnasium`` dependency (``pip install qchain[gym]``).
"""

from __future__ import annotations

try:
    import gymnasium
except ImportError as err:  # the optional extra: say which one
    raise ImportError("qchain.envs needs gymnasium: pip install 'qchain[gym]'") from err

from .. import lazy_exports

ENV_ID = "qchain/SoftArmReach-v0"

if ENV_ID not in gymnasium.registry:  # (a reload of this module registers nothing twice)
    gymnasium.register(
        id=ENV_ID,
        entry_point="qchain.envs.reach:SoftArmReachEnv",
        vector_entry_point="qchain.envs.vector:SoftArmReachVec",
    )

_EXPORTS = {"SoftArmReachEnv": "reach", "ReachTask": "task", "SoftArmReachVec": "vector"}
__all__ = ["ENV_ID", *_EXPORTS]
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
