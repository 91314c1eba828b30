"""Results that must be finite: a method whose result overflows raises a
:class:`~qchain.errors.NonFiniteError` naming what overflowed and where, instead of handing
NaN or inf on. :func:`finite_result` is the one decorator for it (:class:`qchain.Segment`'s
and :class:`qchain.Chain`'s methods); :func:`all_finite` the one test of a result."""

from __future__ import annotations

import functools
import math

import numpy as np

from ..errors import NonFiniteError

__all__ = ["all_finite", "finite_result"]


def all_finite(x) -> bool:
    """Whether a result is finite: an array, a number, a placement (anything with a
    ``homogeneous`` matrix, as ``pinocchio.SE3``), or a tuple or list of them. Anything else
    (None, a string) counts as finite."""
    if isinstance(x, np.ndarray):
        return bool(np.isfinite(x).all())
    if isinstance(x, float):
        return math.isfinite(x)
    if isinstance(x, (tuple, list)):
        return all(all_finite(y) for y in x)
    h = getattr(x, "homogeneous", None)
    return True if h is None else bool(np.isfinite(h).all())


def finite_result(quantity: str, error, *, inner: bool = False):
    """Decorator of a method ``(self, first, *args, **kwargs)``: a result that is not finite
    raises ``error(self, method_name, quantity, first, args, kwargs)`` (an exception) instead
    of being returned.

    Parameters
    ----------
    quantity : str
        What the method returns, as a message names it ("mass matrix M_xi").
    error : callable
        Makes the exception; it knows the owner's parameters and how to find the culprit.
    inner : bool
        Also turn a :class:`~qchain.errors.NonFiniteError` raised inside the method (by a
        part it calls) into this method's ``error``.
    """

    def wrap(fn):
        @functools.wraps(fn)
        def method(self, first, *args, **kwargs):
            try:
                out = fn(self, first, *args, **kwargs)
            except NonFiniteError:
                if not inner:
                    raise
                raise error(self, fn.__name__, quantity, first, args, kwargs) from None
            if not all_finite(out):
                raise error(self, fn.__name__, quantity, first, args, kwargs)
            return out

        return method

    return wrap
