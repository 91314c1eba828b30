"""What a scene's run costs, reckoned from its values before any model is built (the
:class:`qchain.sim.budget.Cost` the budget is checked against): shared by the reader, which
refuses a scene over budget, and :meth:`qchain.scene.Scene.cost`."""

from __future__ import annotations

import math

from ..sim.budget import run_cost
from ..sim.simulation import FIXED_STEP
from .parts import BaseSpec

__all__ = ["_cost", "_frequency"]


def _frequency(pspec: dict, base: BaseSpec | None) -> float:
    """The fastest sine input's or base motion's frequency (Hz) whose amplitude is not zero."""
    f = 0.0
    if pspec.get("type") == "sine":
        live = pspec["frequency"][pspec["amplitude"] != 0]
        f = float(live.max()) if live.size else 0.0
    if base is not None and base.motion is not None and base.motion.amplitude != 0:
        f = max(f, base.motion.frequency)
    return f


def _samples(duration: float, rate: float) -> float:
    """How many output samples :meth:`Scene.sample_times` gives (without making them): the
    grid ``k / rate`` from 0 up to ``duration``, its last point replaced by ``duration``
    where it falls within 1e-9 of it, else ``duration`` added."""
    last = math.floor(duration * rate * (1 + 1e-12))
    on_end = last / rate >= duration - 1e-9 * max(1.0, duration)
    return float(last + 1 if on_end else last + 2)


def _cost(n, base_type, method, dt, max_step, duration, rate, frequency, stable_step=None):
    """The :class:`qchain.sim.budget.Cost` of a run of ``n`` segments from the scene's values
    (``stable_step``: an explicit method's stability limit, s, known once the model is built)."""
    floating = base_type == "floating"
    nq, nv = (7 if floating else 0) + 3 * n, (6 if floating else 0) + 3 * n
    return run_cost(duration=duration, method=method, fixed_step=method in FIXED_STEP, dt=dt, max_step=max_step,
                    frequency=frequency, samples=_samples(duration, rate),
                    samples_why=f"duration {duration:g} s x sample_rate {rate:g} Hz", nq=nq, nv=nv, nu=3 * n,
                    stable_step=stable_step)
