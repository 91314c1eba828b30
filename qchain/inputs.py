"""Input schedules: chamber pressures (or generalised forces) as functions of time.

Every schedule is a callable ``s(t) -> (m,)`` with a fixed size ``s.size``; a controller is
any callable ``(t, q, v) -> (m,)``. :func:`as_input` turns a constant, a schedule or a
controller into the ``(t, q, v) -> (m,)`` form the integrators use.
"""

from __future__ import annotations

import inspect
from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .bounds import FREQUENCY
from .errors import as_real, as_real_array, as_vector

__all__ = ["Schedule", "Constant", "Step", "Ramp", "Sine", "Table", "as_input"]


def _vec(name, x, size=None) -> np.ndarray:
    x = np.atleast_1d(as_real_array(name, x))
    if x.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array, got shape {x.shape}")
    return as_vector(name, x, x.size if size is None else size)


def _spread(name, x, n) -> np.ndarray:
    """One number or ``n`` (as an ``(n,)`` array), else ``ValueError`` naming ``name``."""
    v = _vec(name, x)
    if v.size not in (1, n):
        raise ValueError(f"{name} must be one number or {n} (one an entry of amplitude), got {v.size}")
    return np.broadcast_to(v, (n,)).copy()


class Schedule(ABC):
    """Base class of time schedules ``s(t) -> (size,)``."""

    size: int

    @abstractmethod
    def __call__(self, t: float) -> np.ndarray:
        """The value at time ``t`` (s), shape ``(size,)``."""


@dataclass(frozen=True)
class Constant(Schedule):
    """``value`` at all times."""

    value: np.ndarray

    def __post_init__(self):
        object.__setattr__(self, "value", _vec("value", self.value))

    @property
    def size(self) -> int:
        return self.value.size

    def __call__(self, t):
        return self.value.copy()


@dataclass(frozen=True)
class Step(Schedule):
    """``before`` for ``t < time``, ``after`` from ``time`` on."""

    time: float
    after: np.ndarray
    before: np.ndarray | None = None

    def __post_init__(self):
        a = _vec("after", self.after)
        object.__setattr__(self, "after", a)
        object.__setattr__(self, "before", np.zeros_like(a) if self.before is None else _vec("before", self.before, a.size))
        object.__setattr__(self, "time", as_real("time", self.time))

    @property
    def size(self) -> int:
        return self.after.size

    def __call__(self, t):
        return (self.after if t >= self.time else self.before).copy()


@dataclass(frozen=True)
class Ramp(Schedule):
    """``start`` until ``t0``, linear to ``end`` at ``t1``, ``end`` after."""

    t0: float
    t1: float
    end: np.ndarray
    start: np.ndarray | None = None

    def __post_init__(self):
        e = _vec("end", self.end)
        object.__setattr__(self, "end", e)
        object.__setattr__(self, "start", np.zeros_like(e) if self.start is None else _vec("start", self.start, e.size))
        object.__setattr__(self, "t0", as_real("t0", self.t0))
        object.__setattr__(self, "t1", as_real("t1", self.t1))
        if not self.t1 > self.t0:
            raise ValueError(f"ramp times must be finite with t1 > t0, got t0 = {self.t0}, t1 = {self.t1}")

    @property
    def size(self) -> int:
        return self.end.size

    def __call__(self, t):
        s = min(max((t - self.t0) / (self.t1 - self.t0), 0.0), 1.0)
        return self.start + s * (self.end - self.start)


@dataclass(frozen=True)
class Sine(Schedule):
    """``offset + amplitude * sin(2 pi frequency t + phase)``, element-wise (Hz, rad);
    ``0 <= frequency <= 1e4`` Hz (:data:`qchain.bounds.FREQUENCY`)."""

    amplitude: np.ndarray
    frequency: np.ndarray
    phase: np.ndarray | None = None
    offset: np.ndarray | None = None

    def __post_init__(self):
        a = _vec("amplitude", self.amplitude)
        n = a.size
        f = _spread("frequency", self.frequency, n)
        FREQUENCY.check_array("frequency", f)
        ph = np.zeros(n) if self.phase is None else _spread("phase", self.phase, n)
        off = np.zeros(n) if self.offset is None else _spread("offset", self.offset, n)
        for k, v in (("amplitude", a), ("frequency", f), ("phase", ph), ("offset", off)):
            object.__setattr__(self, k, v)

    @property
    def size(self) -> int:
        return self.amplitude.size

    def __call__(self, t):
        return self.offset + self.amplitude * np.sin(2.0 * np.pi * self.frequency * t + self.phase)


@dataclass(frozen=True)
class Table(Schedule):
    """Piecewise-linear interpolation of ``values`` (K, m) at strictly increasing ``times`` (K,);
    held constant outside the table."""

    times: np.ndarray
    values: np.ndarray

    def __post_init__(self):
        t = _vec("times", self.times)
        v = as_real_array("values", self.values)
        if v.ndim != 2 or v.shape[0] != t.size:
            raise ValueError(f"values must have shape ({t.size}, m) to match times, got {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ValueError("values has non-finite entries")
        d = np.diff(t)
        if np.any(d <= 0):
            k = int(np.flatnonzero(d <= 0)[0])
            raise ValueError(f"times must increase strictly: times[{k}] = {t[k]} >= times[{k + 1}] = {t[k + 1]}")
        object.__setattr__(self, "times", t)
        object.__setattr__(self, "values", v)

    @property
    def size(self) -> int:
        return self.values.shape[1]

    def __call__(self, t):
        i = int(np.searchsorted(self.times, t, side="right"))
        if i == 0:
            return self.values[0].copy()
        if i >= self.times.size:
            return self.values[-1].copy()
        t0, t1 = self.times[i - 1], self.times[i]
        s = (t - t0) / (t1 - t0)
        return (1 - s) * self.values[i - 1] + s * self.values[i]


def as_input(name: str, u, size: int) -> Callable[[float, np.ndarray, np.ndarray], np.ndarray]:
    """``(t, q, v) -> (size,)`` from ``None`` (zeros), a constant array, a :class:`Schedule` or a
    controller ``(t, q, v) -> (size,)``. Sizes are checked here, where the input enters; a
    controller's outputs are checked at every call (shape and finiteness)."""
    if u is None:
        z = np.zeros(size)
        return lambda t, q, v: z
    if isinstance(u, Schedule):
        if u.size != size:
            raise ValueError(f"{name} schedule gives {u.size} values, the model needs {size}")
        return lambda t, q, v: u(t)
    if callable(u):
        try:
            nargs = len(inspect.signature(u).parameters)
        except (TypeError, ValueError):
            nargs = 3
        if nargs == 1:
            return lambda t, q, v: as_vector(f"{name}(t)", u(t), size)
        return lambda t, q, v: as_vector(f"{name}(t, q, v)", u(t, q, v), size)
    c = as_vector(name, u, size)
    return lambda t, q, v: c
