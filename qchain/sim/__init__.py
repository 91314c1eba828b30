"""Time integration: :func:`simulate` (the compiled engine, :mod:`qchain.sim.engine`, or
scipy's steppers), input schedules (:mod:`qchain.sim.inputs`), the run budget
(:mod:`qchain.sim.budget`) and the :class:`Trajectory` a run returns.

Names are imported on first use: :mod:`qchain.recording` reads trajectories without loading
the engine."""

from .. import lazy_exports

_EXPORTS = {
    "simulate": "simulation", "Event": "simulation", "METHODS": "simulation", "FIXED_STEP": "simulation",
    "COMPILED": "simulation", "DEFAULT_METHOD": "simulation",
    "Trajectory": "trajectory", "Budget": "budget", "BudgetError": "budget", "Cost": "budget",
    "Schedule": "inputs", "Constant": "inputs", "Step": "inputs", "Ramp": "inputs", "Sine": "inputs",
    "Table": "inputs", "SineMotion": "inputs", "as_input": "inputs",
    "compile_all": "engine.compile",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
