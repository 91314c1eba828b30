"""qchain: quasi-Lagrangian dynamics of soft continuum arms (Olguin-Diaz et al.).

The names below are imported on first use (PEP 562), so that ``import qchain`` stays light
(no numpy, Pinocchio or numba): the recording's writer process imports
:mod:`qchain.recording` without loading Pinocchio or numba, and the ``qchain`` command
starts answering (``--version``, ``--help``, Ctrl-C) before the model's libraries load.
"""

__version__ = "0.1.0"

__all__ = ["Chain", "LagrangianChain", "Segment", "Scene", "SceneError", "load_scene", "QchainError", "DomainError",
           "SingularConfigurationError", "NonFiniteError", "Budget", "BudgetError", "simulate_batch",
           "BatchTrajectory", "sweep", "__version__"]

_LAZY = {"Chain": ".chain", "LagrangianChain": ".lagrangian", "Scene": ".scene", "SceneError": ".scene",
         "load_scene": ".scene", "Segment": ".segment", "BatchTrajectory": ".batch", "simulate_batch": ".batch",
         "sweep": ".sweeps", "QchainError": ".errors", "DomainError": ".errors",
         "SingularConfigurationError": ".errors", "NonFiniteError": ".errors", "Budget": ".budget",
         "BudgetError": ".budget"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    import importlib.util

    if not name.startswith("_") and name.isidentifier():
        try:
            found = importlib.util.find_spec(f"{__name__}.{name}") is not None
        except ImportError:
            found = False
        if found:
            return importlib.import_module(f"{__name__}.{name}")  # a submodule, as an eager import made it
    raise AttributeError(f"module 'qchain' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
