"""qchain: quasi-Lagrangian dynamics of soft continuum arms (Olguin-Diaz et al.).

The names below are imported on first use (PEP 562), so that ``import qchain`` stays light:
the recording's writer process imports :mod:`qchain.recording` without loading Pinocchio or
numba.
"""

from .errors import DomainError, QchainError, SingularConfigurationError

__version__ = "0.1.0"

__all__ = ["Chain", "LagrangianChain", "Segment", "Scene", "SceneError", "load_scene", "QchainError", "DomainError", "SingularConfigurationError", "simulate_batch", "BatchTrajectory", "sweep", "__version__"]

_LAZY = {"Chain": ".chain", "LagrangianChain": ".lagrangian", "Scene": ".scene", "SceneError": ".scene", "load_scene": ".scene", "Segment": ".segment", "BatchTrajectory": ".batch", "simulate_batch": ".batch", "sweep": ".sweeps"}


def __getattr__(name: str):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(_LAZY[name], __name__), name)
        globals()[name] = value
        return value
    import importlib.util

    if not name.startswith("_") and importlib.util.find_spec(f"{__name__}.{name}") is not None:
        return importlib.import_module(f"{__name__}.{name}")  # a submodule, as an eager import made it
    raise AttributeError(f"module 'qchain' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
