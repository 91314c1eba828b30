"""Argument converters: input checked and converted where it enters.

Every check names the argument, the value it got and what it expected: booleans, strings,
``None`` and complex numbers are refused as numbers (``TypeError``), non-finite entries and
wrong shapes as values (``ValueError``). Ranges of physical quantities are declared in
:mod:`qchain.checks.bounds`; the exception classes are :mod:`qchain.errors`'s.
"""

from __future__ import annotations

import numbers

import numpy as np

__all__ = ["as_real", "as_real_array", "as_vector", "as_matrix", "describe_value", "as_batch", "as_bool", "as_index",
           "check_callable"]


def describe_value(value, limit: int = 60) -> str:
    """``"a str 'abc'"``: the type and a short rendering of ``value``, for messages."""
    if isinstance(value, (bool, np.bool_)):
        kind = "a boolean"
    elif value is None:
        return "None"
    elif isinstance(value, np.ndarray):
        kind = f"an array of dtype {value.dtype} and shape {value.shape}"
    else:
        tn = type(value).__name__
        kind = f"{'an' if tn[:1] in 'aeiou' else 'a'} {tn}"
    try:
        text = repr(value) if not isinstance(value, np.ndarray) or value.size <= 12 else \
            np.array2string(value.ravel()[:6], separator=", ")[:-1] + ", ...]"
    except Exception:  # noqa: BLE001 - a value whose repr fails is still described by its type
        text = "?"
    if len(text) > limit:
        text = text[: limit - 3] + "..."
    return f"{kind} {text}"


def _refuse(name: str, value, what: str):
    raise TypeError(f"{name} must be {what}, got {describe_value(value)}")


def _bool_inside(value, depth: int = 0) -> bool:
    """Whether a (nested) list or tuple holds a boolean: numpy would turn it into 1.0."""
    if depth > 32:
        return False
    for x in value:
        if isinstance(x, (bool, np.bool_)):
            return True
        if isinstance(x, (list, tuple)) and _bool_inside(x, depth + 1):
            return True
    return False


def as_real(name: str, value) -> float:
    """A real number as a ``float``: ``TypeError`` for booleans, strings, ``None``, complex
    numbers and other non-numbers, ``ValueError`` for NaN and infinities; both name ``name``."""
    if isinstance(value, (bool, np.bool_)):
        _refuse(name, value, "a real number (booleans are not numbers)")
    if isinstance(value, np.ndarray) and type(value) is not np.ndarray:
        value = _plain(name, value)
    if isinstance(value, np.ndarray) and value.shape == () and value.dtype.kind in "fiu":
        value = value[()]
    if isinstance(value, (complex, np.complexfloating)):
        _refuse(name, value, "a real number (complex numbers are refused, not cut to their real part)")
    if not isinstance(value, numbers.Real):
        _refuse(name, value, "a real number")
    try:
        x = float(value)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"{name} must be a real number representable as a float, got "
                         f"{describe_value(value)}") from None
    if not np.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x}")
    return x


def as_real_array(name: str, value) -> np.ndarray:
    """``value`` as a float array of real numbers (any shape), without numpy's silent
    conversions: booleans, strings, ``None``, complex numbers and objects are refused
    (``TypeError`` naming ``name``), ragged nestings too (``ValueError``). Finiteness is
    not checked here (:func:`as_vector` does). A numpy masked array with a masked entry is
    refused (its masked entries would be used silently), an unmasked one and any other
    ndarray subclass (``np.matrix``) become a plain ndarray: compiled code takes no subclass."""
    if isinstance(value, np.ndarray) and type(value) is not np.ndarray:
        value = _plain(name, value)
    if isinstance(value, np.ndarray):
        kind = value.dtype.kind
        if kind == "f":
            return value if value.dtype == np.float64 else value.astype(np.float64)
        if kind in "iu":
            return value.astype(np.float64)
    elif isinstance(value, (list, tuple)):
        if _bool_inside(value):
            _refuse(name, value, "an array of real numbers (booleans are not numbers)")
    elif isinstance(value, (bool, np.bool_, str, bytes)) or value is None:
        _refuse(name, value, "an array of real numbers")
    elif isinstance(value, numbers.Real) and not isinstance(value, (complex, np.complexfloating)):
        return np.asarray(_float(name, value))
    try:
        arr = np.asarray(value)
        if type(arr) is not np.ndarray:
            arr = _plain(name, arr)
    except (ValueError, TypeError):
        raise ValueError(f"{name} must be a rectangular array of real numbers, got {describe_value(value)} "
                         "(rows of different lengths?)") from None
    kind = arr.dtype.kind
    if kind in "iu":
        return arr.astype(np.float64)
    if kind == "f":
        return arr.astype(np.float64, copy=False)
    if kind == "b":
        _refuse(name, value, "an array of real numbers (booleans are not numbers)")
    if kind == "c":
        _refuse(name, value, "an array of real numbers (complex numbers are refused, not cut to their real part)")
    if kind == "O":  # numbers of other types (Fraction, Decimal), or something that is not a number
        flat = arr.ravel()
        for i, x in enumerate(flat):
            if isinstance(x, (bool, np.bool_, complex, np.complexfloating)) or not isinstance(x, numbers.Real):
                where = f"{name}[{i}]" if arr.ndim == 1 else f"{name} (entry {i} in row-major order)"
                _refuse(where, x, "a real number")
        return np.array([_float(name, x) for x in flat]).reshape(arr.shape)
    _refuse(name, value, "an array of real numbers")


def _plain(name: str, value) -> np.ndarray:
    """A plain ndarray holding the data of an ndarray subclass; ``ValueError`` naming ``name``
    for a masked array with any masked entry."""
    if isinstance(value, np.ma.MaskedArray):
        mask = np.ma.getmaskarray(value)
        if mask.any():
            bad = np.flatnonzero(mask.ravel()).tolist()
            raise ValueError(f"{name} has masked entries at flat indices {bad[:10]} (a masked array must have "
                             f"no masked entry: fill them, e.g. with .filled(), or pass a plain array), got "
                             f"{describe_value(value)}")
        value = np.ma.getdata(value)
    return np.asarray(value).view(np.ndarray) if isinstance(value, np.ndarray) else np.asarray(value)


def _float(name: str, x) -> float:
    """``float(x)``; an integer too large for a float is a ``ValueError`` naming ``name``."""
    try:
        return float(x)
    except OverflowError:
        raise ValueError(f"{name} must hold real numbers representable as floats (|x| <= 1.8e308), got "
                         f"{describe_value(x)}") from None


def as_vector(name: str, value, size: int) -> np.ndarray:
    """Return ``value`` as a float array of shape ``(size,)``; raise ``TypeError`` for
    entries that are not real numbers and ``ValueError`` naming ``name``, the expected and
    the actual shape, or the non-finite entries."""
    arr = as_real_array(name, value)
    if arr.shape != (size,):
        raise ValueError(f"{name} must have shape ({size},), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.isfinite(arr)).tolist()
        raise ValueError(f"{name} has non-finite entries at indices {bad[:10]}: {describe_value(arr)}")
    return arr


def as_matrix(name: str, value, shape: tuple[int, int]) -> np.ndarray:
    """Like :func:`as_vector` for a matrix of the given shape."""
    arr = as_real_array(name, value)
    if arr.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} has non-finite entries")
    return arr


def as_batch(name: str, value, last: int) -> np.ndarray:
    """``value`` as a finite float array of shape ``(..., last)`` (a batch of vectors of
    ``last`` entries): ``TypeError`` for entries that are not real numbers, ``ValueError``
    naming ``name`` for another shape or non-finite entries."""
    arr = as_real_array(name, value)
    if arr.ndim == 0 or arr.shape[-1] != last:
        raise ValueError(f"{name} must have shape ({last},) or (..., {last}), got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        bad = np.flatnonzero(~np.isfinite(arr.ravel())).tolist()
        raise ValueError(f"{name} has non-finite entries at flat indices {bad[:10]}: {describe_value(arr)}")
    return arr


def as_bool(name: str, value) -> bool:
    """``True`` or ``False`` (Python or numpy booleans); ``TypeError`` naming ``name`` for
    anything else (``"no"``, ``0.5`` and ``None`` are not booleans, whatever their truth)."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise TypeError(f"{name} must be True or False, got {describe_value(value)}")


def as_index(name: str, value, size: int) -> int:
    """An integer ``0 <= value < size`` (Python or numpy integers, not booleans); ``TypeError``
    or ``ValueError`` naming ``name``, the value and the bound."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise TypeError(f"{name} must be an integer >= 0 and < {size}, got {describe_value(value)}")
    i = int(value)
    if not 0 <= i < size:
        raise ValueError(f"{name} must be an integer >= 0 and < {size}, got {i}")
    return i


def check_callable(name: str, value, optional: bool = True):
    """``value`` if it is callable (or None with ``optional``); ``TypeError`` naming ``name``."""
    if value is None and optional:
        return None
    if not callable(value):
        raise TypeError(f"{name} must be {'None or ' if optional else ''}a callable, got {describe_value(value)}")
    return value
