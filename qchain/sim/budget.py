"""What a run may cost, checked before it starts: steps, output samples, memory, segments.

A run whose cost would exceed its :class:`Budget` is refused before the first step, with
a message naming the budget, what exceeded it and how to raise it; the costs, lower bounds
known before a run, are listed in docs/simulation.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..checks.bounds import Range
from ..errors import BudgetError
from .inputs import Sine

__all__ = ["Budget", "BudgetError", "Cost", "DEFAULT", "RANGES", "run_cost", "input_frequency"]

#: What each bound of a :class:`Budget` may be set to.
RANGES = {
    "max_steps": Range(1, 10**15, integer=True),
    "max_samples": Range(1, 10**12, integer=True),
    "max_memory": Range(0.0, 2.0**60, "bytes", low_open=True),
    "max_segments": Range(1, 10**6, integer=True),
}


@dataclass(frozen=True)
class Budget:
    """Upper bounds on what one run may cost (docs/simulation.md).

    Parameters
    ----------
    max_steps : int
        Steps of the integrator (a lower bound of them, known before the run).
    max_samples : int
        Output samples.
    max_memory : float
        Bytes of output arrays and solver matrices (an estimate).
    max_segments : int
        Segments of a scene (``count`` expanded).
    """

    max_steps: int = 10_000_000
    max_samples: int = 1_000_000
    max_memory: float = 2.0 * 2**30
    max_segments: int = 1000

    def __post_init__(self):
        for name, rng in RANGES.items():
            object.__setattr__(self, name, rng.check(f"Budget.{name}", getattr(self, name)))

    def problems(self, cost: "Cost") -> list[tuple[str, str, str]]:
        """``(budget key, expected, found)`` for each bound ``cost`` exceeds."""
        out = []
        if cost.steps > self.max_steps:
            out.append(("max_steps", f"at most {self.max_steps} steps", f"{cost.steps:.3g} steps ({cost.steps_why})"))
        if cost.samples > self.max_samples:
            out.append(("max_samples", f"at most {self.max_samples} output samples",
                        f"{cost.samples:.3g} samples ({cost.samples_why})"))
        if cost.memory > self.max_memory:
            out.append(("max_memory", f"at most {_bytes(self.max_memory)} of output arrays and solver matrices",
                        f"about {_bytes(cost.memory)} ({cost.memory_why})"))
        return out

    def check(self, cost: "Cost", how: str = "pass budget=qchain.sim.budget.Budget(...) to allow more") -> None:
        """Raise :class:`BudgetError` if ``cost`` exceeds the budget; ``how`` says how to raise it."""
        bad = self.problems(cost)
        if bad:
            lines = [f"budget.{k}: expected {e}, found {f}" for k, e, f in bad]
            raise BudgetError("the run would exceed its budget, refused before it starts: " + "; ".join(lines)
                              + f" ({how})", cost)


DEFAULT = Budget()


def as_budget(budget) -> Budget:
    """``budget``, or :data:`DEFAULT` for None; ``TypeError`` naming it for anything else."""
    if budget is None:
        return DEFAULT
    if not isinstance(budget, Budget):
        from ..checks.convert import describe_value

        raise TypeError(f"budget must be a qchain.sim.budget.Budget, got {describe_value(budget)}")
    return budget


def _bytes(x: float) -> str:
    for unit, scale in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20), ("KiB", 2**10)):
        if x >= scale:
            return f"{x / scale:.3g} {unit}"
    return f"{x:.3g} B"


@dataclass(frozen=True)
class Cost:
    """What a run costs (lower bounds and estimates) and why, in words."""

    steps: float
    steps_why: str
    samples: float
    samples_why: str
    memory: float
    memory_why: str
    matrix_memory: float = 0.0  #: the solver matrices' part of ``memory`` (the rest is the samples')


def run_cost(*, duration: float, method: str, fixed_step: bool, dt: float | None, max_step: float,
             frequency: float, samples: float, samples_why: str, nq: int, nv: int, nu: int,
             stable_step: float | None = None, controller_rate: float | None = None) -> Cost:
    """The :class:`Cost` of a run of ``duration`` s (docs/simulation.md).

    ``samples`` is the number of output samples (``math.nan``: one a step, for a run
    without output times); ``frequency`` the fastest input's (Hz, 0 for none);
    ``stable_step`` an explicit adaptive method's stability limit of the step at the start
    (s; None where unknown or the method is implicit); ``controller_rate`` (Hz) a held
    controller's: a step ends at each of its instants.
    """
    if fixed_step:
        steps = duration / dt
        why = f"duration {duration:g} s / dt {dt:g} s"
    else:
        steps, why = 0.0, ""
        if math.isfinite(max_step):
            steps, why = duration / max_step, f"duration {duration:g} s / max_step {max_step:g} s"
        if 2.0 * frequency * duration > steps:
            steps = 2.0 * frequency * duration
            why = (f"2 steps a period of the fastest input, {frequency:g} Hz, over {duration:g} s: {method} must "
                   "follow it")
        stable_steps = None if stable_step is None else (duration / stable_step if stable_step > 0 else math.inf)
        if stable_steps is not None and stable_steps > steps:
            steps = stable_steps
            why = (f"duration {duration:g} s / {method}'s stability limit of the step at the start, about "
                   f"{stable_step:.3g} s: the model is stiff for an explicit method, use method 'radau5'")
    if controller_rate is not None and duration * controller_rate > steps:
        steps = duration * controller_rate
        why = (f"duration {duration:g} s x controller_rate {controller_rate:g} Hz: a step ends at every controller "
               "instant")
    if math.isnan(samples):
        samples, samples_why = steps + 1.0, "one a step"
    per_sample = 8.0 * (3 + nq + nv + nu)
    matrices = 8.0 * 12 * nv * nv
    memory = samples * per_sample + matrices
    memory_why = f"{samples:.3g} samples x {per_sample:.0f} B + solver matrices {_bytes(matrices)} (nv = {nv})"
    return Cost(steps=steps, steps_why=why or "no bound known before the run", samples=samples,
                samples_why=samples_why, memory=memory, memory_why=memory_why, matrix_memory=matrices)


def input_frequency(*inputs) -> float:
    """The largest frequency (Hz) of the sine schedules and sine base motions among ``inputs``
    (others count 0)."""
    f = 0.0
    for u in inputs:
        freq = getattr(u, "frequency", None)
        if freq is None:
            continue
        if type(u) is Sine:  # frozen, its arrays checked finite and of one size: plain floats (a batch has one a rollout)
            f = max(f, max((x for x, a in zip(freq.tolist(), u.amplitude.tolist()) if a != 0.0), default=0.0))
            continue
        try:
            a = np.asarray(freq, dtype=float)
            amp = np.broadcast_to(np.asarray(getattr(u, "amplitude", 1.0), dtype=float), a.shape)
            live = a[(amp != 0) & np.isfinite(a)]
            if live.size:
                f = max(f, float(np.max(live)))
        except (TypeError, ValueError):
            continue
    return f
