"""Error classes and the input checks that raise them where input enters."""

from __future__ import annotations

import numpy as np

__all__ = [
    "QchainError",
    "DomainError",
    "SingularConfigurationError",
    "as_vector",
    "as_matrix",
    "check_positive",
]


class QchainError(Exception):
    """Base class of every error qchain raises on purpose."""


class DomainError(QchainError, ValueError):
    """A configuration outside the model's domain (l <= 0, |kappa| r_s >= 1, ...)."""


class SingularConfigurationError(QchainError, ValueError):
    """The paper's (l, psi, kappa) coordinates are singular at this configuration.

    Also raised by :class:`qchain.LagrangianChain` at the attitude singularity of its
    roll-pitch-yaw base coordinates (``|pitch| -> pi/2``).
    """


def as_vector(name: str, value, size: int) -> np.ndarray:
    """Return ``value`` as a float array of shape ``(size,)``; raise ``ValueError`` naming
    ``name``, the expected and the actual shape, or the non-finite entries."""
    arr = np.asarray(value, dtype=float)
    if arr.shape != (size,):
        raise ValueError(f"{name} must have shape ({size},), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.isfinite(arr)).tolist()
        raise ValueError(f"{name} has non-finite entries at indices {bad}: {arr.tolist()}")
    return arr


def as_matrix(name: str, value, shape: tuple[int, int]) -> np.ndarray:
    """Like :func:`as_vector` for a matrix of the given shape."""
    arr = np.asarray(value, dtype=float)
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} has non-finite entries")
    return arr


def check_positive(name: str, value, unit: str, allow_zero: bool = False) -> float:
    """A finite real ``> 0`` (or ``>= 0`` with ``allow_zero``); ``ValueError`` naming the bound."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not np.isfinite(v):
        raise ValueError(f"{name} must be finite, got {v}")
    if allow_zero and v < 0.0:
        raise ValueError(f"{name} must be >= 0 {unit}, got {v} {unit}".replace("  ", " "))
    if not allow_zero and v <= 0.0:
        raise ValueError(f"{name} must be > 0 {unit}, got {v} {unit}".replace("  ", " "))
    return v
