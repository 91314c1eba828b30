"""Many runs at once, as a library (no command line here: that is :mod:`qchain.cli.sweep`):
:func:`simulate_batch` rolls one chain out from many starts and inputs
(:mod:`qchain.batch.rollouts`); :func:`sweep` runs a scene over axes of its values
(:mod:`qchain.batch.sweep_spec` declares a sweep, :mod:`qchain.batch.sweeps` runs it); both on
the engines of :mod:`qchain.batch.workers` (this process, a local pool, a Dask cluster)."""

from .. import lazy_exports

_EXPORTS = {
    "simulate_batch": "rollouts", "BatchTrajectory": "rollouts", "RolloutError": "rollouts",
    "sweep": "sweeps", "run_sweep": "sweeps", "SweepResult": "sweeps", "summary_metrics": "sweeps",
    "SweepSpec": "sweep_spec", "Axis": "sweep_spec", "SweepError": "sweep_spec", "load_sweep": "sweep_spec",
    "LocalPool": "workers", "DaskEngine": "workers",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
