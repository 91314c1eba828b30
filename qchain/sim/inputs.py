"""Input schedules: chamber pressures (or generalised forces) as functions of time.

Every schedule is a callable ``s(t) -> (m,)`` with a fixed size ``s.size``; a controller is
any callable ``(t, q, v) -> (m,)``. :func:`as_input` turns a constant, a schedule or a
controller into the ``(t, q, v) -> (m,)`` form the integrators use.
"""

from __future__ import annotations

import inspect
import math
import re
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from ..checks.bounds import ANGLE, FORCE, FREQUENCY, PRESSURE, TENSION, TIME, Range, check_time
from ..checks.convert import as_real_array, as_vector
from ..checks.frozen import KeepsReadOnly

__all__ = ["Schedule", "Constant", "Step", "Ramp", "Sine", "Table", "BUILT_IN", "as_input", "input_range", "FORCE", "SineMotion",
           "schedules_inside", "sine_value"]

_RANGES = {"pressure": PRESSURE, "tau": FORCE, "tension": TENSION}


def _vec(name, x, size=None) -> np.ndarray:
    """A read-only copy of ``x`` as a finite (size,) float array: a schedule owns its values
    (a later change of the caller's array cannot get around the checks made here)."""
    x = np.atleast_1d(as_real_array(name, x))
    if x.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array, got shape {x.shape}")
    return _frozen(as_vector(name, x, x.size if size is None else size))


def _frozen(x: np.ndarray) -> np.ndarray:
    x = np.array(x, dtype=np.float64)
    x.flags.writeable = False
    return x


def _copy(x):
    """What a user's callable gets: its own copy of a state array (its writes stay its own)."""
    return x.copy() if isinstance(x, np.ndarray) else x


def _spread(name, x, n) -> np.ndarray:
    """One number or ``n`` (as an ``(n,)`` array), else ``ValueError`` naming ``name``."""
    v = _vec(name, x)
    if v.size not in (1, n):
        raise ValueError(f"{name} must be one number or {n} (one an entry of amplitude), got {v.size}")
    return _frozen(np.broadcast_to(v, (n,)))


class Schedule(KeepsReadOnly, ABC):
    """Base class of time schedules ``s(t) -> (size,)``."""

    size: int

    @abstractmethod
    def __call__(self, t: float) -> np.ndarray:
        """The value at time ``t`` (s), shape ``(size,)``."""

    def extent(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The smallest and the largest value each entry takes over all times, two
        ``(size,)`` arrays; None where that is not known (the base class: a subclass's
        values are then checked at every call)."""
        return None


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

    def extent(self):
        return self.value, self.value


@dataclass(frozen=True)
class Step(Schedule):
    """``before`` for ``t < time``, ``after`` from ``time`` on."""

    time: float
    after: np.ndarray
    before: np.ndarray | None = None

    def __post_init__(self):
        a = _vec("after", self.after)
        object.__setattr__(self, "after", a)
        object.__setattr__(self, "before", _frozen(np.zeros_like(a)) if self.before is None else
                           _vec("before", self.before, a.size))
        object.__setattr__(self, "time", TIME.check("time", self.time))

    @property
    def size(self) -> int:
        return self.after.size

    def __call__(self, t):
        return (self.after if check_time(t) >= self.time else self.before).copy()

    def extent(self):
        return np.minimum(self.before, self.after), np.maximum(self.before, self.after)


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
        object.__setattr__(self, "start", _frozen(np.zeros_like(e)) if self.start is None else
                           _vec("start", self.start, e.size))
        object.__setattr__(self, "t0", TIME.check("t0", self.t0))
        object.__setattr__(self, "t1", TIME.check("t1", self.t1))
        if not self.t1 > self.t0:
            raise ValueError(f"ramp times must be finite with t1 > t0, got t0 = {self.t0}, t1 = {self.t1}")

    @property
    def size(self) -> int:
        return self.end.size

    def __call__(self, t):
        s = min(max((check_time(t) - self.t0) / (self.t1 - self.t0), 0.0), 1.0)
        return self.start + s * (self.end - self.start)

    def extent(self):
        return np.minimum(self.start, self.end), np.maximum(self.start, self.end)


def sine_value(offset, amplitude, frequency, phase, t: float) -> np.ndarray:
    """``offset + amplitude sin(2 pi frequency t + phase)``, element-wise (arrays of one shape,
    Hz, rad, ``t`` in s): :class:`Sine`'s value, and a batch's at once
    (:func:`qchain.sim.engine.schedules.values_at`), by the same operations in the same order."""
    return offset + amplitude * np.sin(2.0 * np.pi * frequency * t + phase)


@dataclass(frozen=True)
class Sine(Schedule):
    """``offset + amplitude * sin(2 pi frequency t + phase)``, element-wise (Hz, rad);
    ``0 <= frequency <= 1e4`` Hz (:data:`qchain.checks.bounds.FREQUENCY`)."""

    amplitude: np.ndarray
    frequency: np.ndarray
    phase: np.ndarray | None = None
    offset: np.ndarray | None = None

    def __post_init__(self):
        a = _vec("amplitude", self.amplitude)
        n = a.size
        f = _spread("frequency", self.frequency, n)
        FREQUENCY.check_array("frequency", f)
        ph = _frozen(np.zeros(n)) if self.phase is None else _spread("phase", self.phase, n)
        ANGLE.check_array("phase", ph)
        off = _frozen(np.zeros(n)) if self.offset is None else _spread("offset", self.offset, n)
        for k, v in (("amplitude", a), ("frequency", f), ("phase", ph), ("offset", off)):
            object.__setattr__(self, k, v)

    @property
    def size(self) -> int:
        return self.amplitude.size

    def __call__(self, t):
        return sine_value(self.offset, self.amplitude, self.frequency, self.phase, check_time(t))

    def extent(self):
        """``offset -+ |amplitude|`` (a sine of frequency 0 is the constant
        ``offset + amplitude sin(phase)``)."""
        swing = np.abs(self.amplitude)
        if min(self.frequency.tolist()) > 0.0:  # (every entry swings: the common case, fewer array passes)
            return self.offset - swing, self.offset + swing
        swing = np.where(self.frequency > 0.0, swing, 0.0)
        mid = np.where(self.frequency > 0.0, self.offset, self.offset + self.amplitude * np.sin(self.phase))
        return mid - swing, mid + swing


@dataclass(frozen=True)
class Table(Schedule):
    """Piecewise-linear interpolation of ``values`` (K, m) at strictly increasing ``times`` (K,);
    held constant outside the table."""

    times: np.ndarray
    values: np.ndarray

    def __post_init__(self):
        t = TIME.check_array("times", _vec("times", self.times))
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
        object.__setattr__(self, "values", _frozen(v))

    @property
    def size(self) -> int:
        return self.values.shape[1]

    def __call__(self, t):
        i = int(np.searchsorted(self.times, check_time(t), side="right"))
        if i == 0:
            return self.values[0].copy()
        if i >= self.times.size:
            return self.values[-1].copy()
        t0, t1 = self.times[i - 1], self.times[i]
        s = (t - t0) / (t1 - t0)
        return (1 - s) * self.values[i - 1] + s * self.values[i]

    def extent(self):
        return self.values.min(axis=0), self.values.max(axis=0)


#: qchain's own schedules: frozen, their arrays read-only (runs may share one), their values
#: bounded by :meth:`Schedule.extent`
BUILT_IN = (Constant, Step, Ramp, Sine, Table)


def input_range(name: str) -> Range | None:
    """The declared range of the input called ``name`` (``"pressure"``, ``"tau"``, also
    as ``"pressure[3]"`` for a batch's rollout 3): :data:`qchain.checks.bounds.PRESSURE`,
    :data:`FORCE`, or None for a name without one."""
    return _RANGES.get(re.split(r"[\[(]", str(name), maxsplit=1)[0])


def _extent(u: Schedule) -> tuple[np.ndarray, np.ndarray] | None:
    """``u.extent()`` where it describes ``u``'s values: not for a subclass that changes
    ``__call__`` and keeps its parent's ``extent``."""
    owner = next(cls for cls in type(u).__mro__ if "extent" in vars(cls))
    if type(u).__call__ is not owner.__call__:
        return None
    return u.extent()


def _check_extent(name: str, rng: Range, u: Schedule, ext: tuple[np.ndarray, np.ndarray]) -> None:
    """``ValueError`` naming ``name``, the entry, the value and the bound if the schedule
    ``u``, whose values stay within ``ext = _extent(u)``, goes outside ``rng`` at any time."""
    if _inside(rng, ext[0]) and _inside(rng, ext[1]):
        return  # (the common case, in plain floats: a batch checks a schedule a rollout)
    unit = f" {rng.unit}" if rng.unit else ""
    for values in ext:
        bad = rng.outside(values)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise ValueError(f"{name}[{k}] must stay {rng.text()}, but the {type(u).__name__} schedule given as "
                             f"{name} reaches {rng.shown(values[k])}{unit}")


def _inside(rng: Range, arr: np.ndarray) -> bool:
    """Whether every entry of the 1-D array ``arr`` is a number inside the closed range ``rng``
    (NaN is not): in plain floats for the few entries of an input, by numpy for a batch's. False
    for an open range (the caller then checks with numpy)."""
    if rng.low_open or rng.high_open:
        return False
    lo = -math.inf if rng.low is None else rng.low
    hi = math.inf if rng.high is None else rng.high
    if arr.size > 32:
        return bool(np.all((lo <= arr) & (arr <= hi)))
    return all(lo <= x <= hi for x in arr.tolist())


def schedules_inside(name: str, us: Sequence, size: int) -> bool:
    """Whether every entry of ``us`` is one of qchain's own schedules (:data:`BUILT_IN`, exact
    types) of ``size`` values whose extent lies inside :func:`input_range` of ``name``: what
    :func:`as_input` checks of each, for a batch's B schedules at once. False otherwise,
    without saying why: the caller then checks each with :func:`as_input`, whose error names
    the entry, the value and the bound."""
    if not us or not all(type(u) in BUILT_IN and u.size == size for u in us):
        return False
    rng = input_range(name)
    return rng is None or _inside(rng, np.concatenate([x for u in us for x in u.extent()]))


def _range_check(rng: Range, label: str) -> Callable[[np.ndarray], np.ndarray]:
    """A function that returns a finite ``(m,)`` array whose entries are inside ``rng`` and
    raises ``Range.check_array``'s ``ValueError`` otherwise; cheap for the few entries of
    an input (it runs at every call of a controller)."""

    def check(arr: np.ndarray) -> np.ndarray:
        if arr.size and _inside(rng, arr):
            return arr
        return rng.check_array(label, arr)

    return check


def _arity(name: str, u) -> int:
    """1 for a schedule-like callable ``u(t)``, 3 for a controller ``u(t, q, v)``; a
    ``TypeError`` naming ``name`` for a callable that takes neither."""
    try:
        sig = inspect.signature(u)
    except (TypeError, ValueError):  # a builtin without a signature: taken as a controller
        return 3
    for n in (3, 1):
        try:
            sig.bind(*range(n))
        except TypeError:
            continue
        if n == 3 and len(sig.parameters) == 1 and not any(
                p.kind is p.VAR_POSITIONAL for p in sig.parameters.values()):
            continue
        return n
    raise TypeError(f"{name} must be a controller (t, q, v) -> array or a function of time t -> array, got a "
                    f"callable {getattr(u, '__qualname__', type(u).__name__)}{sig} that takes neither")


def _checked(label: str, call: Callable, size: int, rng: Range | None) -> Callable:
    """``(t, q, v) -> call(t, q, v)`` checked at every call as a finite ``(size,)`` array
    (inside ``rng``), errors naming ``label``."""
    if rng is None:
        return lambda t, q, v: as_vector(label, call(t, q, v), size)
    check = _range_check(rng, label)
    return lambda t, q, v: check(as_vector(label, call(t, q, v), size))


def as_input(name: str, u, size: int, bound: Range | None | str = "auto"
             ) -> Callable[[float, np.ndarray, np.ndarray], np.ndarray]:
    """``(t, q, v) -> (size,)`` from ``None`` (zeros), a constant array, a :class:`Schedule` or a
    controller ``(t, q, v) -> (size,)`` (or ``(t) -> (size,)``).

    Checked here, where the input enters (docs/simulation.md): a schedule's values over all
    times (:meth:`Schedule.extent`), a controller's outputs at every call.

    Parameters
    ----------
    name : str
        The argument's name in messages (``"pressure"``, ``"tau"``, ``"pressure[3]"``).
    u : None, array_like, Schedule or callable
    size : int
        How many values the model needs.
    bound : Range, None or "auto"
        The range every value must be in; ``"auto"`` takes :func:`input_range` of
        ``name``, None checks no range.

    Raises
    ------
    TypeError
        Entries that are not real numbers (booleans, strings, complex numbers), naming ``name``.
    ValueError
        A wrong size or shape, non-finite entries, or values outside ``bound``, naming
        ``name``, the entry, the value and the bound.
    """
    rng = input_range(name) if isinstance(bound, str) and bound == "auto" else bound
    if rng is not None and not isinstance(rng, Range):
        raise TypeError(f"bound must be a qchain.checks.bounds.Range, None or 'auto', got {type(rng).__name__}")
    if u is None:
        z = _frozen(np.zeros(size))
        return lambda t, q, v: z
    if isinstance(u, Schedule):
        # a schedule of the user's may declare no size: it is then a function of time whose
        # values (shape, finiteness, range) are checked as they come, like any u(t)
        usize = getattr(u, "size", None)
        if usize is not None:
            if isinstance(usize, (bool, np.bool_)) or not isinstance(usize, (int, np.integer)):
                raise TypeError(f"{name} schedule {type(u).__qualname__} has size {usize!r}, not an integer")
            if usize != size:
                raise ValueError(f"{name} schedule gives {usize} values, the model needs {size}")
        ext = None if usize is None else _extent(u)
        if ext is None:  # a schedule of the user's: its values are checked as they come
            return _checked(f"{name}(t)", lambda t, q, v: u(t), size, rng)
        if rng is not None:
            _check_extent(name, rng, u, ext)
        return lambda t, q, v: u(t)
    if callable(u):
        if _arity(name, u) == 1:
            return _checked(f"{name}(t)", lambda t, q, v: u(t), size, rng)
        # the controller gets copies of the state: its writes stay its own
        return _checked(f"{name}(t, q, v)", lambda t, q, v: u(t, _copy(q), _copy(v)), size, rng)
    c = _frozen(as_vector(name, u, size))
    if rng is not None:
        rng.check_array(name, c)
    return lambda t, q, v: c


@dataclass(frozen=True, eq=False)
class SineMotion:
    """A mount swinging sinusoidally: ``X_WB(t) = X_0 * M(s(t))``, ``s = a sin(2 pi f t + phase)``.

    ``kind = "translation"``: ``M(s) = (I, s axis)``, a shift along ``axis`` (mount frame);
    ``kind = "rotation"``: ``M(s) = (exp3(s axis), 0)``, a turn about ``axis`` through the
    mount origin. Velocities and accelerations are exact: ``V_B = s' (axis, 0)`` or
    ``s' (0, axis)`` in the base frame, ``A_B = dV_B/dt`` likewise with ``s''``.

    Calling it at ``t`` returns ``(X_WB: pinocchio.SE3, V_B (6,), A_B (6,))``, the form
    :class:`qchain.Chain` takes as ``base_motion``.
    """

    kind: str
    axis: np.ndarray
    amplitude: float
    frequency: float
    phase: float
    mount: pin.SE3

    def offset(self, t: float) -> tuple[float, float, float]:
        """``(s, s', s'')`` at ``t``: m or rad, per s, per s^2."""
        w = 2.0 * math.pi * self.frequency
        arg = w * t + self.phase
        return (self.amplitude * math.sin(arg), self.amplitude * w * math.cos(arg),
                -self.amplitude * w * w * math.sin(arg))

    def placement_at(self, s: float) -> pin.SE3:
        """``X_0 * M(s)``."""
        if self.kind == "translation":
            return self.mount * pin.SE3(np.eye(3), s * self.axis)
        return self.mount * pin.SE3(pin.exp3(s * self.axis), np.zeros(3))

    def peak_acceleration(self) -> float:
        """``max |s''| = |a| (2 pi f)^2``."""
        return abs(self.amplitude) * (2.0 * math.pi * self.frequency) ** 2

    def __call__(self, t: float):
        s, sd, sdd = self.offset(float(t))
        V = np.zeros(6)
        A = np.zeros(6)
        k = 0 if self.kind == "translation" else 3
        V[k : k + 3] = sd * self.axis
        A[k : k + 3] = sdd * self.axis
        return self.placement_at(s), V, A
