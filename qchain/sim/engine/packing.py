"""How a chain and its inputs are packed into the model a compiled pass reads
(:class:`qchain.sim.engine.system.EngineModel`: :func:`pack`, :func:`with_inputs`), or why they
cannot be (:func:`python_reason`). Python, apart from the passes of
:mod:`qchain.sim.engine.system`; each chain's model is packed once and kept.
"""

from __future__ import annotations

import weakref

import numpy as np

from ...algorithms.layout import kernel_layout
from ...contact.environment import Environment
from . import schedules
from .system import FIXED, FLOATING, PRESCRIBED, EngineModel

__all__ = ["pack", "with_inputs", "python_reason"]


def pack(chain, pressure, tau, env=None, tension=None) -> EngineModel | None:
    """The :class:`~qchain.sim.engine.system.EngineModel` of ``chain`` with compiled ``pressure``
    and ``tau`` inputs, or None where the compiled engine cannot serve it (:func:`python_reason`
    says why). A ``planar`` chain whose base stays in its x-z plane runs on
    :func:`qchain.algorithms.planar.planar_aba_moving` (2-D cost, the same accelerations).
    Without ``env`` the chain's model is packed at its first call and kept (:data:`_CHAIN_MODELS`):
    later calls make only their inputs' arrays."""
    from ...arm.chain import Chain

    if not isinstance(chain, Chain):
        raise TypeError(f"chain must be a qchain.Chain, got {type(chain).__name__}")
    arrays = chain.kernel_arrays()
    if arrays is None:
        return None
    if env is not None:
        m = _packed_model(chain, arrays, env)
    else:
        m = _CHAIN_MODELS.get(chain, _UNPACKED)
        if m is _UNPACKED:  # (two threads may both pack it: the same model)
            m = _CHAIN_MODELS[chain] = _packed_model(chain, arrays, None)
    return None if m is None else with_inputs(m, chain, pressure, tau, tension)


#: each chain's model without an environment and with zero inputs, packed at its first run (a
#: chain never changes after it is made, and the passes never write a model's arrays); a run's
#: own inputs replace its input arrays. None: the compiled engine cannot serve the chain's base
#: motion.
_CHAIN_MODELS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_UNPACKED = object()


def python_reason(chain, pressure, tau, tension=None) -> str | None:
    """Why :func:`pack` returns None for ``chain`` with these inputs (the run then goes to the
    Python backend), in words naming the segment or the input; None where it does not."""
    if chain.kernel_arrays() is None:
        j = int(np.flatnonzero(chain._paper)[0])
        return (f"segments[{j}] has coords='paper' (the compiled passes work in curvature coordinates; use "
                "coords='curvature')")
    for name, u, size in (("pressure", pressure, chain.nu), ("tau", tau, chain.nv), ("tension", tension, chain.nt)):
        if schedules.pack_input(u, size, name) is not None:
            continue
        if name == "tension":
            return ("tension is a Python callable (a tension controller, evaluated at every stage; a schedule of "
                    "qchain.sim.inputs runs on the compiled engine)")
        return (f"{name} is a Python callable (a controller evaluated at every stage; give controller_rate= "
                "to hold it between instants on the compiled engine, or a schedule of qchain.sim.inputs)")
    if chain.base == "prescribed" and schedules.pack_base_motion(chain.base_motion) is None:
        return "base_motion is a Python callable (the compiled engine takes a qchain.sim.inputs.SineMotion)"
    return None


def with_inputs(m: EngineModel, chain, pressure, tau, tension=None) -> EngineModel | None:
    """``m`` (:func:`pack` of ``chain``, the model shared) with the compiled ``pressure`` and
    ``tau`` inputs instead of its own (new arrays: a held controller's output is written into
    them), or None where compiled code cannot evaluate them: :func:`pack` of ``chain`` with
    those inputs, without packing the chain again."""
    p = schedules.pack_input(pressure, chain.nu, "pressure")
    f = schedules.pack_input(tau, chain.nv, "tau")
    tn = schedules.pack_input(tension, chain.nt, "tension")
    if p is None or f is None or tn is None:
        return None
    return m._replace(p_ints=p[0], p_params=p[1], tau_ints=f[0], tau_params=f[1], tn_ints=tn[0], tn_params=tn[1])


def _packed_model(chain, arrays, env) -> EngineModel | None:
    """The model of ``chain`` (its kernel ``arrays``, the environment ``env`` or none) with zero
    inputs, or None where its base motion is a Python callable."""
    base = {"fixed": FIXED, "floating": FLOATING, "prescribed": PRESCRIBED}[chain.base]
    planar_kernel = chain.planar and base != FLOATING
    if base == PRESCRIBED:
        bm = schedules.pack_base_motion(chain.base_motion)
        if bm is None:
            return None
        axis = bm[1][:3]
        in_plane = axis[1] == 0.0 if bm[0][0] == schedules.TRANSLATION else axis[0] == axis[2] == 0.0
        planar_kernel = planar_kernel and in_plane
    else:
        bm = (np.zeros(1, dtype=np.int64), np.zeros(1))
    X = chain.base_placement
    env = (env or Environment()).packed()
    p, f, tn = (schedules.pack_input(None, size, name) for name, size in
                (("pressure", chain.nu), ("tau", chain.nv), ("tension", chain.nt)))
    return EngineModel(arrays=arrays, idx=np.flatnonzero(chain.active).astype(np.int64), base=base,
                       planar_kernel=int(planar_kernel), nq=chain.nq, nv=chain.nv,
                       g_W=np.array(chain.gravity, dtype=float), R_WB0=np.array(X.rotation),
                       p_WB0=np.array(X.translation), bm_ints=bm[0], bm_params=bm[1], p_ints=p[0], p_params=p[1],
                       tau_ints=f[0], tau_params=f[1], layout=kernel_layout(chain.n, chain.nv), env=env,
                       tendon_rows=np.array(chain._tendon_rows), tendon_nodes=np.array(chain._tendon_nodes),
                       tendon_weights=np.array(chain._tendon_weights), tn_ints=tn[0], tn_params=tn[1])
