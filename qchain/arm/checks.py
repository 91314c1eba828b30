"""Input checks of a :class:`qchain.arm.chain.Chain` and the errors of its non-finite results.

Every argument of a chain method is checked where it enters: real arrays of the right
shape (``TypeError`` for strings, booleans, complex numbers), finite, a floating base's
quaternion of unit norm (within :data:`QUATERNION_TOLERANCE`), segment configurations
inside the model and locked coordinates at their locked values (``ValueError`` or
:class:`~qchain.errors.DomainError` naming the entry and segment). A result that is not
finite raises :class:`~qchain.errors.NonFiniteError` naming the quantity, the segment whose
state overflows and the time (:func:`_finite`, :meth:`ChainChecks.nonfinite_error`).

:class:`ChainChecks` holds these checks as methods of :class:`~qchain.arm.chain.Chain`, which
inherits them; it reads the chain's layout (``n``, ``nq``, ``nv``, ``_qoff``, ...) and
has no state of its own.
"""

from __future__ import annotations

import functools
import threading

import numpy as np

from ..algorithms import recursive
from ..checks.bounds import POSITION, check_time
from ..checks.results import finite_result
from ..checks.convert import as_index, as_real_array, as_vector, describe_value
from ..errors import DomainError, NonFiniteError, QchainError
from .data import Data
from .dynamics_derivatives import _EMPTY, _ZERO6
from ..checks.text import show_vector
from ..model.segment import Segment
from ..model.spatial import _quaternion_to_rotation as quaternion_to_rotation
from ..model.segment import _paper_jacobian as paper_jacobian, _paper_to_curvature as paper_to_curvature

__all__ = ["ChainChecks", "QUATERNION_TOLERANCE"]

#: How far from 1 a floating base's quaternion norm may be (it is then normalised).
QUATERNION_TOLERANCE = 1e-6


def _finite(quantity: str, has_v: bool = False):
    """Decorator of a :class:`~qchain.arm.chain.Chain` method ``(self, q, [v,] ...)``: a result that
    is not finite raises :class:`~qchain.errors.NonFiniteError` naming the quantity, the segment
    whose state overflows and the time (:meth:`ChainChecks.nonfinite_error`) instead of being
    returned; so does a segment's own :class:`~qchain.errors.NonFiniteError` inside. The
    ``skip_checks=True`` fast path is not checked."""

    def error(self, method, quantity, q, args, kwargs):
        v = args[0] if has_v and args else kwargs.get("v")
        return self.nonfinite_error(method, quantity, q, v, kwargs.get("t"))

    def wrap(fn):
        checked = finite_result(quantity, error, inner=True)(fn)

        @functools.wraps(fn)
        def method(self, q, *args, **kwargs):
            if kwargs.get("skip_checks"):
                return fn(self, q, *args, **kwargs)
            if has_v and (args[0] if args else kwargs.get("v")) is None:  # None means "no velocities" inside
                raise TypeError(f"Chain.{fn.__name__}: v must be an array of real numbers of shape ({self.nv},), got None")
            return checked(self, q, *args, **kwargs)

        return method

    return wrap


class ChainChecks:
    """Input checks and non-finite result errors of :class:`~qchain.arm.chain.Chain` (its base
    class; see the module docstring)."""

    def coordinate_name(self, i: int, velocity: bool = True) -> str:
        """Who owns entry ``i`` of ``v`` (or of ``q`` with ``velocity=False``), in words:
        ``"segment 1, uy"``, ``"base, angular velocity z"``."""
        off = self._voff if velocity else self._qoff
        i = as_index("i", i, self.nv if velocity else self.nq)
        if i < off:
            names = (("linear velocity x", "linear velocity y", "linear velocity z", "angular velocity x",
                      "angular velocity y", "angular velocity z") if velocity else
                     ("position x", "position y", "position z", "quaternion x", "quaternion y", "quaternion z",
                      "quaternion w"))
            return f"base, {names[i]}"
        j, k = divmod(i - off, 3)
        return f"segment {j}, {('l', 'psi', 'kappa')[k] if self._paper[j] else ('l', 'ux', 'uy')[k]}"

    def _check_locks(self, q_e: np.ndarray, v_e: np.ndarray | None) -> None:
        """Raise for a locked coordinate of ``q_e`` (n, 3) off its locked value, or of ``v_e``
        not zero, naming its index in ``q`` or ``v``."""
        bad = self._locked & (np.abs(q_e - self._lock_values) > 1e-12 * np.maximum(1.0, np.abs(self._lock_values)))
        if bad.any():
            j, i = map(int, np.argwhere(bad)[0])
            raise ValueError(
                f"q[{self._qoff + 3 * j + i}] (segment {j}, {'l' if i == 0 else 'uy'}) is locked at "
                f"{self._lock_values[j, i]:.9g}, got {q_e[j, i]:.9g}"
            )
        if v_e is not None:
            bad = self._locked & (v_e != 0.0)
            if bad.any():
                j, i = map(int, np.argwhere(bad)[0])
                raise ValueError(f"v[{self._voff + 3 * j + i}] (segment {j}) is locked and must be 0, got {v_e[j, i]:.9g}")

    def _overflowing_segment(self, q_e: np.ndarray, v_e: np.ndarray | None) -> str | None:
        """The first segment whose own mass matrix, kinetic or elastic energy is not finite
        at ``q_e`` (n, 3) (and ``v_e``), in words, or None."""
        with np.errstate(all="ignore"):
            for j, s in enumerate(self.segments):
                q_c = paper_to_curvature(q_e[j]) if self._paper[j] else q_e[j]
                M = s._mass_c(np.ascontiguousarray(q_c, dtype=float))
                J = paper_jacobian(q_e[j]) if self._paper[j] else np.eye(3)
                T = 0.0 if v_e is None else _quadratic_form(M[6:, 6:], J, v_e[j])
                U = Segment.elastic_energy.__wrapped__(s, q_e[j])
                what = [w for w, ok in (("mass matrix", np.all(np.isfinite(M))),
                                        (f"kinetic energy {T:.3g} J", np.isfinite(T) or not np.all(np.isfinite(M))),
                                        (f"elastic energy {U:.3g} J", np.isfinite(U))) if not ok]
                if what:
                    sl, vs = self.q_slice(j), self.v_slice(j)
                    rates = "" if v_e is None else f", v[{vs.start}:{vs.stop}] = {show_vector(v_e[j])}"
                    return (f"segment {j} (q[{sl.start}:{sl.stop}] = {show_vector(q_e[j])}{rates}) overflows double "
                            f"precision: its {' and '.join(what)}")
        return None

    def nonfinite_error(self, method: str, quantity: str, q, v=None, t=None, result=None) -> NonFiniteError:
        """The :class:`~qchain.errors.NonFiniteError` of a ``method`` whose ``quantity`` came
        out non-finite at ``(q, v)`` (and time ``t``): it names the first segment whose own
        mass matrix, kinetic or elastic energy overflows there, or else the first
        non-finite entry of ``result`` (a vector over ``v``)."""
        try:
            at = f" at t = {float(t):.6g} s" if t is not None else ""
        except (TypeError, ValueError):
            at = f" at t = {t!r}"
        try:
            q = np.asarray(q, dtype=float)
            q_e = q[self._qoff :].reshape(self.n, 3)
            v_e = None if v is None else np.asarray(v, dtype=float)[self._voff :].reshape(self.n, 3)
        except (TypeError, ValueError):
            return NonFiniteError(f"Chain.{method}: the {quantity} is not finite{at}")
        culprit = self._overflowing_segment(q_e, v_e)
        if culprit:
            return NonFiniteError(f"Chain.{method}: the {quantity} is not finite{at}: {culprit}")
        where = ""
        if isinstance(result, np.ndarray) and result.shape == (self.nv,):
            bad = np.flatnonzero(~np.isfinite(result))
            if bad.size:
                where = f": first at entry {int(bad[0])} ({self.coordinate_name(int(bad[0]))})"
        return NonFiniteError(f"Chain.{method}: the {quantity} is not finite{at}{where}")

    def _data(self, data, name: str = "data"):
        """``data`` if it is None or a :class:`~qchain.arm.data.Data` made for this chain's sizes
        (``chain.create_data()``); ``TypeError``/``ValueError`` naming ``data`` otherwise (the
        compiled passes would write outside another chain's arrays). Cheap: the unchecked
        ``skip_checks`` path runs it too."""
        if data is None:
            return None
        if not isinstance(data, Data):
            raise TypeError(f"{name} must be None or chain.create_data(), got {describe_value(data)}")
        if data.n != self.n or data.nv != self.nv:
            raise ValueError(f"{name} is a workspace for n = {data.n} segments and nv = {data.nv} velocities; this "
                             f"chain has n = {self.n}, nv = {self.nv}: make it with this chain's create_data()")
        return data

    def _time(self, t, name: str = "t") -> float:
        """A time ``t`` (s): a real number within :data:`qchain.checks.bounds.TIME`."""
        return check_time(t, name)

    def indefinite_error(self, method: str, q_e: np.ndarray, t=None) -> QchainError:
        """The error of a ``method`` whose articulated-body pass met an inertia block that is
        not positive definite at the segment coordinates ``q_e`` (n, 3): it names the first
        segment whose own mass matrix ``M_xi`` is singular there (a length so small, or so
        large, that the inertia loses rank in double precision) and its entries of ``q``."""
        at = "" if t is None else f" at t = {float(t):.6g} s"
        with np.errstate(all="ignore"):
            for j, s in enumerate(self.segments):
                q_c = paper_to_curvature(q_e[j]) if self._paper[j] else np.asarray(q_e[j], dtype=float)
                M = s._mass_c(np.ascontiguousarray(q_c))
                try:
                    np.linalg.cholesky(M)
                    ok = np.all(np.isfinite(M))
                except np.linalg.LinAlgError:
                    ok = False
                if not ok:
                    sl = self.q_slice(j)
                    return QchainError(
                        f"Chain.{method}: an articulated inertia block is not positive definite{at}: segment {j} "
                        f"(q[{sl.start}:{sl.stop}] = {show_vector(q_e[j])}) has a singular mass matrix M_xi in double "
                        f"precision (length l = {float(q_e[j][0]):.3g} m against rest length {s.length:g} m)")
        return QchainError(f"Chain.{method}: an articulated inertia block is not positive definite{at} "
                           f"(q = {np.array2string(np.ravel(q_e), precision=6)})")

    def _workspace(self, data: Data | None) -> Data:
        """``data``, or for a call without one this thread's own workspace, made on its first
        call and kept (a fresh one each call cost a tenth of a checked forward dynamics at ten
        segments); one per thread, as a ``Data`` serves one evaluation at a time. What the
        methods return is never a workspace array when no ``data`` is given."""
        if data is not None:
            return data
        key = threading.get_ident()
        own = self._own_data.get(key)
        if own is None:
            if len(self._own_data) >= 64:  # threads come and go: start afresh (a call in progress holds its own)
                self._own_data.clear()
            own = self._own_data[key] = Data(self.n, self.nv)
        return own

    def _unchecked_inputs(self, q, v, p, t, data):
        """``(q_c, v_c, p (n, 3), V0, A_B, g_B)`` of the ``skip_checks`` fast path, which serves
        chains in curvature coordinates and needs a ``data``."""
        if data is None or self._any_paper or self._has_linear:
            raise ValueError("skip_checks=True needs data=chain.create_data() and a chain in curvature coordinates "
                             "(no segment with coords='paper')")
        n = self.n
        q_c = q[self._qoff :].reshape(n, 3)
        v_c = v[self._voff :].reshape(n, 3)
        p3 = self._p_zero if p is None else p.reshape(n, 3)
        A_B = None
        if self.base == "fixed":
            V0, g_B = _ZERO6, self._g_B
        elif self.floating:
            V0 = v[:6]
            g_B = quaternion_to_rotation(q[3:7]).T @ self.gravity
        else:
            X, V0, A_B = self.base_motion(float(t))
            g_B = X.rotation.T @ self.gravity
        return q_c, v_c, p3, V0, A_B, g_B

    def _unchecked_base(self, q, v, p, t, data):
        """``(V0, A_B, g_B)`` of the ``skip_checks`` path's one compiled call: a fixed base's
        without work, else :meth:`_unchecked_inputs`' (which refuses what the path does not serve)."""
        if self.base == "fixed" and data is not None and self._curvature:
            return _ZERO6, None, self._g_B
        return self._unchecked_inputs(q, v, p, t, data)[3:]

    def _vec(self, name: str, x, size: int) -> np.ndarray:
        """Fast shape check; finiteness is checked with the domain
        (:meth:`~qchain.arm.chain.Chain._state`). A float array passes straight; anything else is
        converted by :func:`qchain.checks.convert.as_real_array`, which refuses booleans, strings and
        complex numbers by name."""
        if not (type(x) is np.ndarray and x.dtype == np.float64):
            x = as_real_array(name, x)
        if x.shape != (size,):
            as_vector(name, x, size)  # raises with the expected and actual shape
        if not (x.flags.c_contiguous and x.flags.writeable):
            # the compiled passes are compiled for writeable contiguous float64 arrays: a
            # read-only or strided one would compile them again (seconds), so it is copied
            x = np.array(x, dtype=np.float64)
        return x

    def _q(self, q, name="q") -> np.ndarray:
        """Shape-checked ``q`` (nq,), a floating base's quaternion normalised (within
        :data:`QUATERNION_TOLERANCE` of unit norm, else a ``ValueError``) and its position
        within :data:`qchain.checks.bounds.POSITION`."""
        q = self._vec(name, q, self.nq)
        if self.floating:
            if not np.abs(q[:3]).max() <= 1e6:  # qchain.checks.bounds.POSITION (NaN is named by the finiteness check)
                as_vector(name, q, self.nq)
                POSITION.check_array(f"{name}[0:3] (base position)", q[:3])
            norm = np.sqrt(q[3] * q[3] + q[4] * q[4] + q[5] * q[5] + q[6] * q[6])
            if not abs(norm - 1.0) <= QUATERNION_TOLERANCE:
                as_vector(name, q, self.nq)  # non-finite entries are named first
                raise ValueError(
                    f"{name}[3:7] quaternion (qx, qy, qz, qw) has norm {norm:.9g}; it must be within "
                    f"{QUATERNION_TOLERANCE:g} of 1"
                )
            if norm != 1.0:
                q = q.copy()
                q[3:7] /= norm
        return q

    def _check_domain(self, q_e: np.ndarray, *checked: tuple[str, np.ndarray]) -> None:
        """Raise for non-finite entries of the ``checked`` (name, array) pairs, or a segment
        configuration outside the model (naming the segment and its indices in q)."""
        xs = [x for _, x in checked] + [_EMPTY] * (4 - len(checked))  # at most q, v, p, tau: one call
        j = recursive.first_invalid_of(*xs, q_e, self._radius, self._paper)
        if j <= -2:
            name, x = checked[-2 - j]
            as_vector(name, x, x.shape[0])  # raises, naming the entry
        if j >= 0:
            sl = self.q_slice(j)
            try:
                self.segments[j].check_configuration(q_e[j], name=f"segment {j} (q[{sl.start}:{sl.stop}])")
            except DomainError as err:
                raise DomainError(str(err)) from None
            raise DomainError(f"segment {j} (q[{sl.start}:{sl.stop}]) is outside the model: {q_e[j]}")

    def _p(self, p) -> np.ndarray:
        """Pressures ``p`` (3 n,) Pa as (n, 3), zero for None."""
        return np.zeros((self.n, 3)) if p is None else as_vector("p", p, self.nu).reshape(self.n, 3)

    def _pt(self, p, tau):
        """Shape-checked ``p`` (n, 3) and ``tau`` (nv,) or None, and their (name, array) pairs
        for the finiteness check of :meth:`~qchain.arm.chain.Chain._state`."""
        extra = []
        if p is None:
            p3 = np.zeros((self.n, 3))
        else:
            pv = self._vec("p", p, self.nu)
            extra.append(("p", pv))
            p3 = pv.reshape(self.n, 3)
        if tau is not None:
            tau = self._vec("tau", tau, self.nv)
            extra.append(("tau", tau))
        return p3, tau, extra


def _quadratic_form(M: np.ndarray, J: np.ndarray, v: np.ndarray) -> float:
    """``1/2 (J v)^T M (J v)`` for a positive-definite ``M``, computed on ``v`` scaled to unit
    size: a ``v`` whose square overflows gives +inf, not the nan of inf - inf that the plain
    products' order of summation may give."""
    s = float(np.max(np.abs(v))) if v.size else 0.0
    if s == 0.0 or not np.isfinite(s):
        w = J @ v
        return 0.5 * float(w @ M @ w)
    w = J @ (v / s)
    return 0.5 * float(w @ M @ w) * s * s
