"""The controller base: a callable ``(t, q, v) -> p`` that plugs into
:func:`qchain.simulate`'s ``pressure=`` (or ``(t, q, v) -> T``, tendon tensions, into
``tension=``), its rate, its input bounds, and the record of its internal signals.

A controller of a fixed-base :class:`~qchain.arm.chain.Chain` computes a wanted generalised
force ``tau`` on the chain's free coordinates (``chain.active``; locked coordinates have no
dynamics), turns it into chamber pressures (or, given ``tension_max``, the tensions of the chain's
tendons) by bounded least squares (:mod:`qchain.control.allocation`) and records, at every call, the time, the pressures, the
force wanted and the force realised (``B p``), the allocation's residual and whether it
saturated, its CPU time, and the controller's own signals (references, errors, the storage
function where one is defined). :meth:`Controller.signals` returns them as ``(K, ...)``
arrays; :meth:`Controller.save` writes them to an ``.npz`` file beside a run's recording.

The controller is sampled at :attr:`Controller.rate` and its pressures held between
samples (zero-order hold): :meth:`Controller.run` passes the rate to :func:`qchain.simulate`
as ``controller_rate``, so the arm is integrated in compiled code between calls.
"""

from __future__ import annotations

import os
import time
from abc import ABC, abstractmethod

import numpy as np

from ..arm.chain import Chain
from ..checks.bounds import PRESSURE, SAMPLE_RATE, TENSION
from ..checks.convert import as_real, as_vector, describe_value
from ..sim.simulation import simulate
from .allocation import PENALTY_SCALE, allocate

__all__ = ["Controller", "gain"]


def gain(name: str, value, size: int) -> np.ndarray:
    """A positive gain: a number > 0 or a (size,) array of numbers > 0, as a (size,) array."""
    arr = np.asarray(value, dtype=float) if not isinstance(value, (bool, np.bool_, str)) else None
    if arr is None or arr.ndim == 0:
        x = as_real(name, value)
        arr = np.full(size, x)
    else:
        arr = as_vector(name, value, size)
    bad = np.flatnonzero(~(arr > 0))
    if bad.size:
        raise ValueError(f"{name}[{bad[0]}] must be a number > 0, got {arr[bad[0]]:g}")
    return arr


class Controller(ABC):
    """Base of the controllers of :mod:`qchain.control`: ``(t, q, v) -> p`` (3 n,) Pa, or
    ``(t, q, v) -> T`` (nt,) N for a tendon-driven arm (``tension_max``).

    Parameters
    ----------
    chain : Chain
        The controller's model of the arm; base ``"fixed"`` (the chambers cannot move a
        floating base, and a prescribed base's motion is not the controller's).
    rate : float, Hz
        The rate it runs at (> 0): :meth:`run` passes it as ``controller_rate``.
    p_max : float, Pa
        Largest chamber pressure, within :data:`qchain.checks.bounds.PRESSURE` (the model's
        domain; what a real chamber takes is the user's to state, e.g. 100 kPa for an
        elastomer actuator).
    p_min : float, Pa
        Smallest chamber pressure, default 0 (inflation only); as low as
        :data:`qchain.checks.bounds.VACUUM_GAUGE` (-101325 Pa, a vacuum) for chambers that
        take suction. ``p_min < p_max``.
    penalty : float, optional
        The least-input weight ``w`` of the allocation (units of ``B``, N m^2/Pa for a
        curvature coordinate; of ``B_T``, m, with tendons); default
        :data:`~qchain.control.allocation.PENALTY_SCALE` times the largest entry of ``B``
        (``B_T``) (free rows) at the neutral configuration.
    tension_max : float, N, optional
        Drive the chain's tendons instead of its chambers (docs/tendons.md): the wanted
        force is realised by tensions in ``[0, tension_max]`` (a tendon pulls; within
        :data:`qchain.checks.bounds.TENSION`) through ``B_T(q)`` (:meth:`qchain.Chain.tendon_matrix`),
        the chambers held at zero; ``p_max`` and ``p_min`` are then not given. The least-tension
        penalty picks the least co-contraction of antagonistic tendons.

    Attributes
    ----------
    chain, rate, p_min, p_max, penalty, tension_max
    input : str
        ``"pressure"`` or ``"tension"``: what the controller outputs, the keyword of
        :func:`qchain.simulate` it plugs into and the name of its signal.
    active : (k,) int
        Indices of the free velocity coordinates ``tau`` acts on.
    """

    def __init__(self, chain: Chain, *, rate: float, p_max: float | None = None, p_min: float = 0.0,
                 penalty: float | None = None, tension_max: float | None = None):
        if not isinstance(chain, Chain):
            raise TypeError(f"chain must be a qchain.Chain, got {describe_value(chain)}")
        if chain.base != "fixed":
            raise ValueError(f"chain must have base 'fixed' (the chambers cannot move a {chain.base} base), "
                             f"got base {chain.base!r}")
        self.chain = chain
        self.rate = SAMPLE_RATE.check("rate", rate)
        self.tension_max = None if tension_max is None else TENSION.check("tension_max", tension_max)
        if self.tension_max is not None:
            if not chain.nt:
                raise ValueError("tension_max is given but the chain has no tendons (Chain(..., tendons=[...]))")
            if p_max is not None or p_min != 0.0:
                raise ValueError("give either p_max (and p_min) for the chambers or tension_max for the tendons, "
                                 "not both: a controller drives one kind of actuator")
            if not self.tension_max > 0:
                raise ValueError(f"tension_max must be > 0 N, got {self.tension_max:g} N")
            self.input, self.p_min, self.p_max = "tension", 0.0, None
            self._bounds = (0.0, self.tension_max)
        else:
            if p_max is None:
                raise TypeError("p_max is required (the largest chamber pressure, Pa), or tension_max for a "
                                "tendon-driven arm")
            self.input = "pressure"
            self.p_min = PRESSURE.check("p_min", p_min)
            self.p_max = PRESSURE.check("p_max", p_max)
            if not self.p_min < self.p_max:
                raise ValueError(f"p_max must be > p_min = {self.p_min:g} Pa, got {self.p_max:g} Pa")
            self._bounds = (self.p_min, self.p_max)
        self.active = np.flatnonzero(chain.active)
        if penalty is None:
            penalty = PENALTY_SCALE * float(np.abs(self._input_matrix(chain.neutral())).max())
        elif not as_real("penalty", penalty) >= 0:
            raise ValueError(f"penalty must be a number >= 0, got {penalty:g}")
        self.penalty = float(penalty)
        self._ix = np.ix_(self.active, self.active)
        self._records: list[dict] = []

    # -- what a subclass writes
    @abstractmethod
    def torque(self, t: float, q: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, dict]:
        """``(tau, signals)``: the wanted force on the free coordinates (k,) and the
        controller's own signals at this call (name -> array or number)."""

    def _input_matrix(self, q: np.ndarray) -> np.ndarray:
        """``B(q)`` (k, 3 n) or ``B_T(q)`` (k, nt): the input matrix's free rows."""
        B = self.chain.tendon_matrix(q) if self.input == "tension" else self.chain.input_matrix(q)
        return B[self.active]

    # -- the callable simulate samples
    def __call__(self, t, q, v) -> np.ndarray:
        """The pressures (3 n,) Pa (the tensions (nt,) N with tendons) at time ``t`` (s) and
        state ``q`` (nq,), ``v`` (nv,)."""
        c0 = time.process_time()
        t = as_real("t", t)
        q = as_vector("q", q, self.chain.nq)
        v = as_vector("v", v, self.chain.nv)
        rec = {"t": t}
        rec.update(self._command(t, q, v))
        rec["compute_s"] = time.process_time() - c0
        self._records.append(rec)
        return rec[self._signal]

    @property
    def _signal(self) -> str:
        return "tension" if self.input == "tension" else "p"

    def _command(self, t: float, q: np.ndarray, v: np.ndarray) -> dict:
        """The call's signals, ``"p"`` the pressures (``"tension"`` the tensions) among them:
        :meth:`torque`, then the bounded allocation of ``tau`` (a controller that chooses
        pressures itself, such as :class:`~qchain.control.mpc.MPC`, overrides this)."""
        tau, own = self.torque(t, q, v)
        a = allocate(self._input_matrix(q), tau, *self._bounds, self.penalty)
        rec = {self._signal: a.p, "tau": tau, "tau_realised": a.realised, "residual": a.residual,
               "saturated": a.saturated, "at_upper": a.at_upper}
        rec.update(own)
        return rec

    # -- after a run
    def signals(self) -> dict[str, np.ndarray]:
        """Every call's signals as arrays, first axis the K calls in order: ``t`` (K,) s,
        ``p`` (K, 3 n) Pa (``tension`` (K, nt) N with tendons), ``tau`` and ``tau_realised``
        (K, k) (the free coordinates' generalised forces wanted and made), ``residual`` (K,)
        ``|B p - tau|``, ``saturated`` (K,) bool, ``at_upper`` (K,) inputs at their largest, ``compute_s`` (K,)
        the call's CPU time (s), and the controller's own (its docstring lists them)."""
        if not self._records:
            return {}
        return {k: np.array([r[k] for r in self._records]) for k in self._records[0]}

    def save(self, path: str | os.PathLike) -> None:
        """Write :meth:`signals` to ``path`` (``numpy.savez``, one array per name)."""
        np.savez(path, **self.signals())

    def reset(self) -> None:
        """Forget the recorded signals (before another run)."""
        self._records.clear()

    def run(self, q0, v0, duration: float, *, plant: Chain | None = None, t0: float = 0.0, **simulate_kwargs):
        """Run the closed loop for ``duration`` s from ``(q0, v0)`` at ``t0``: a
        :class:`qchain.sim.trajectory.Trajectory`.

        ``plant`` is the arm the pressures act on (default the controller's own model; a
        different chain of the same layout shows a model mismatch). The controller's signals
        are reset first. Other keywords go to :func:`qchain.simulate` (``method``, ``dt``,
        ``t_eval``, ...); ``controller_rate`` is :attr:`rate`.
        """
        plant = self.chain if plant is None else plant
        if not isinstance(plant, Chain):
            raise TypeError(f"plant must be a qchain.Chain, got {describe_value(plant)}")
        if (plant.nq != self.chain.nq or plant.nu != self.chain.nu or plant.nt != self.chain.nt
                or not np.array_equal(plant.active, self.chain.active)):
            raise ValueError(f"plant must have the controller's layout (nq = {self.chain.nq}, nu = {self.chain.nu}, "
                             f"nt = {self.chain.nt}, the same free coordinates), got nq = {plant.nq}, nu = {plant.nu}, "
                             f"nt = {plant.nt}")
        if "controller_rate" in simulate_kwargs or self.input in simulate_kwargs:
            raise TypeError(f"run sets {self.input} (the controller) and controller_rate (its rate) itself")
        t0 = as_real("t0", t0)
        self.reset()
        return simulate(plant, q0, v0, (t0, t0 + as_real("duration", duration)), controller_rate=self.rate,
                        **{self.input: self}, **simulate_kwargs)
