"""World frames and kinematics of a :class:`qchain.arm.chain.Chain`.

The world placements of the segment roots and the tip, the backbone points along each
segment's axis (one configuration or a batch of them, in one compiled
:func:`qchain.algorithms.recursive.frames` call: :class:`Frames`), the tip Jacobian and the tip twist
and the segments' root twists.

:class:`ChainKinematics` holds them as methods of :class:`~qchain.arm.chain.Chain`, which
inherits them; it reads the chain's model arrays and validated states
(:meth:`~qchain.arm.chain.Chain._state`) and has no state of its own.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import pinocchio as pin

from ..algorithms import recursive
from ..model.arc import arc_nodes
from .checks import QUATERNION_TOLERANCE, _finite
from ..checks.convert import as_bool, as_real_array, describe_value
from ..errors import NonFiniteError, QchainError
from ..model.spatial import _quaternion_to_rotation as quaternion_to_rotation

if TYPE_CHECKING:
    from .chain import _State

__all__ = ["ChainKinematics", "Frames"]

_NO_POINTS = np.empty(0)  # recursive.frames without backbone points
_NO_POINTS.flags.writeable = False


class Frames(NamedTuple):
    """World frames of ``K`` configurations (:meth:`ChainKinematics.frames_batch`): index ``j < n``
    is the root of segment ``j``, index ``n`` the tip.

    Attributes
    ----------
    rotation : (K, n + 1, 3, 3)
    translation : (K, n + 1, 3), m
    quaternion : (K, n + 1, 4)
        The rotations as unit quaternions ``(x, y, z, w)``, ``w >= 0``.
    backbone : (K, n, P, 3), m
        World points along each segment's axis, ``alpha`` from 0 to 1
        (``backbone[k, j, -1] == translation[k, j + 1]``).
    """

    rotation: np.ndarray
    translation: np.ndarray
    quaternion: np.ndarray
    backbone: np.ndarray


_ALPHAS: dict[int, np.ndarray] = {}


def _backbone_alpha(points_per_segment: int) -> np.ndarray:
    """``P`` evenly spaced slice coordinates from 0 to 1 (read-only, cached)."""
    # checked before the cache is asked: an unhashable value, or 20.0 after a call with 20
    if not (isinstance(points_per_segment, (int, np.integer)) and not isinstance(points_per_segment, (bool, np.bool_))
            and 2 <= points_per_segment <= 10_000):
        raise ValueError(f"points_per_segment must be an int >= 2 and <= 10000, got {describe_value(points_per_segment)}")
    alpha = _ALPHAS.get(int(points_per_segment))
    if alpha is None:
        alpha = np.linspace(0.0, 1.0, int(points_per_segment))
        alpha.flags.writeable = False
        _ALPHAS[int(points_per_segment)] = alpha
    return alpha


class ChainKinematics:
    """World frames and kinematics of :class:`~qchain.arm.chain.Chain` (its base class; see the
    module docstring)."""

    @_finite("world placements")
    def placements(self, q, t: float = 0.0) -> list[pin.SE3]:
        """World placements of every segment root and of the tip: ``n + 1`` ``pinocchio.SE3``."""
        f = self._state_frames(self._state(q, t=t), _NO_POINTS)
        return [pin.SE3(f.rotation[0, k], f.translation[0, k]) for k in range(self.n + 1)]

    def tip_placement(self, q, t: float = 0.0) -> pin.SE3:
        """World placement of the tip frame."""
        return self.placements(q, t)[-1]

    def backbone(self, q, points_per_segment: int = 20, t: float = 0.0) -> np.ndarray:
        """World points along each segment's axis (m), shape ``(n, P, 3)``, ``alpha`` from 0 to 1."""
        return self.frames(q, points_per_segment, t)[1]

    @_finite("frames and backbone")
    def frames(self, q, points_per_segment: int = 20, t: float = 0.0) -> tuple[list[pin.SE3], np.ndarray]:
        """:meth:`placements` and :meth:`backbone` in one pass (:meth:`frames_batch` does many
        configurations at once)."""
        f = self._state_frames(self._state(q, t=t), _backbone_alpha(points_per_segment))
        return [pin.SE3(f.rotation[0, k], f.translation[0, k]) for k in range(self.n + 1)], f.backbone[0]

    def frames_batch(self, Q, points_per_segment: int = 20, t=0.0, *, skip_checks: bool = False,
                     out: Frames | None = None) -> Frames:
        """World frames and backbones of ``K`` configurations in one compiled call: what a
        batch of logged step records needs, at a few microseconds a configuration.

        Parameters
        ----------
        Q : (K, nq)
            Configurations, validated as ``q`` is everywhere (an error names the row).
        points_per_segment : int
            Backbone points a segment, ``alpha`` from 0 to 1 (>= 2).
        t : float or (K,), s
            Times (they matter for a prescribed base only).
        skip_checks : bool
            Trust ``Q``: a float64 (K, nq) array of valid configurations (the states of a
            run, which the engine checked at every step). No validation of ``Q`` and no
            check of the results: for a caller that records a run's samples.
        out : Frames, optional
            Arrays to write the frames into, of at least ``K`` rows (their first ``K`` rows
            are returned); with ``skip_checks`` only. They are checked (float64, C-contiguous,
            writeable, the shapes above): the compiled pass writes into them.

        Returns
        -------
        Frames
            ``rotation`` (K, n + 1, 3, 3), ``translation`` (K, n + 1, 3) m and ``quaternion``
            (K, n + 1, 4) of the roots of segments ``0..n-1`` and of the tip (index ``n``) in
            the world; ``backbone`` (K, n, P, 3) m.
        """
        alpha = _backbone_alpha(points_per_segment)
        if as_bool("skip_checks", skip_checks):
            if not (isinstance(Q, np.ndarray) and Q.dtype == np.float64):  # a list, or big-endian: one conversion
                Q = np.asarray(Q, dtype=np.float64)
            if out is not None:
                self._check_out(out, Q.shape[0], alpha.shape[0])
            return self._frames(np.ascontiguousarray(Q[:, self._qoff :]).reshape(Q.shape[0], self.n, 3),
                                *self._base_frames(Q, t), alpha, out=out)
        if out is not None:
            raise ValueError("frames_batch: out is for skip_checks=True only")
        Q = as_real_array("Q", Q)
        if Q.ndim != 2 or Q.shape[1] != self.nq:
            raise ValueError(f"Q must have shape (K, nq) = (K, {self.nq}), got {Q.shape}")
        K = Q.shape[0]
        times = self._times(t, K)  # checked also where a fixed base does not use it
        if self.base == "prescribed":
            t = times
        q_e = Q[:, self._qoff :].reshape(K, self.n, 3)
        bad = recursive.first_invalid(Q.ravel(), q_e.reshape(K * self.n, 3), self._radius, self._paper)
        if bad == -2:
            bad = int(np.flatnonzero(~np.isfinite(Q).all(axis=1))[0])
        elif bad >= 0:
            bad //= self.n
        if self.floating:
            norm = np.linalg.norm(Q[:, 3:7], axis=1)
            off = np.flatnonzero(~(np.abs(norm - 1.0) <= QUATERNION_TOLERANCE))
            if off.size and (bad < 0 or off[0] < bad):
                bad = int(off[0])
        if bad >= 0:
            t_bad = float(np.broadcast_to(t, (K,))[bad])
            try:
                self._state(Q[bad], t=t_bad)
            except (ValueError, QchainError) as err:
                raise type(err)(f"Q[{bad}]: {err}") from None
        with np.errstate(all="ignore"):
            f = self._frames(q_e, *self._base_frames(Q, t), alpha)
        bad = ~(np.isfinite(f.translation).all(axis=(1, 2)) & np.isfinite(f.backbone).all(axis=(1, 2, 3)))
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise NonFiniteError(f"Q[{k}]: " + str(self.nonfinite_error("frames_batch", "frames", Q[k])))
        return f

    def _times(self, t, K: int) -> np.ndarray:
        """``t`` a time or ``K`` times (s), each within :data:`qchain.checks.bounds.TIME`."""
        ts = as_real_array("t", t)
        if ts.shape not in ((), (K,)):
            raise ValueError(f"t must be one time or ({K},) times, one a configuration, got shape {ts.shape}")
        for k, tk in enumerate(np.ravel(ts)):
            self._time(float(tk) if np.isfinite(tk) else tk, "t" if ts.ndim == 0 else f"t[{k}]")
        return ts

    def _check_out(self, out, K: int, P: int) -> None:
        """``out`` must be four float64, C-contiguous, writeable arrays of the shapes of
        :class:`Frames` with at least ``K`` rows (the compiled pass writes into them)."""
        shapes = ((self.n + 1, 3, 3), (self.n + 1, 3), (self.n + 1, 4), (self.n, P, 3))
        if not (isinstance(out, tuple) and len(out) == 4):
            raise TypeError(f"out must be a Frames (four arrays), got {describe_value(out)}")
        for name, a, tail in zip(Frames._fields, out, shapes):
            if not (type(a) is np.ndarray and a.dtype == np.float64 and a.flags.c_contiguous and a.flags.writeable
                    and a.ndim == 1 + len(tail) and a.shape[1:] == tail and a.shape[0] >= K):
                got = describe_value(a) if not isinstance(a, np.ndarray) else f"{a.dtype} {a.shape}"
                raise ValueError(f"out.{name} must be a writeable C-contiguous float64 array of shape (>= {K}, "
                                 f"{', '.join(map(str, tail))}), got {got}")

    def _state_frames(self, st: _State, alpha: np.ndarray) -> Frames:
        """The :class:`Frames` (K = 1) of one validated state, backbone points at ``alpha``."""
        return self._frames(st.q_e[None], st.X_WB.rotation[None], st.X_WB.translation[None], alpha)

    def _base_frames(self, Q: np.ndarray, t) -> tuple[np.ndarray, np.ndarray]:
        """Base rotations (K, 3, 3) or (1, 3, 3) and origins (K, 3) or (1, 3) (m) of the
        configurations ``Q`` (K, nq) at times ``t`` (s)."""
        if self.base == "fixed":
            return self._R_WB, self._p_WB
        if self.floating:
            return quaternion_to_rotation(Q[:, 3:7]), Q[:, :3]
        X = [self.base_state(tk)[0] for tk in np.broadcast_to(np.asarray(t, dtype=float), (Q.shape[0],))]
        return np.array([x.rotation for x in X]), np.array([x.translation for x in X])

    def _frames(self, q_e: np.ndarray, R0: np.ndarray, o0: np.ndarray, alpha: np.ndarray,
                out: Frames | None = None) -> Frames:
        """The one :func:`recursive.frames` call: ``q_e`` (K, n, 3) segment coordinates, base
        rotations (K, 3, 3) and origins (K, 3); into the first ``K`` rows of ``out`` if given."""
        K = q_e.shape[0]
        if out is None:
            f = Frames(np.empty((K, self.n + 1, 3, 3)), np.empty((K, self.n + 1, 3)), np.empty((K, self.n + 1, 4)),
                       np.empty((K, self.n, alpha.shape[0], 3)))
        else:
            f = Frames(*(a[:K] for a in out))
        recursive.frames(np.ascontiguousarray(q_e), self._paper, np.ascontiguousarray(R0), np.ascontiguousarray(o0),
                         alpha, *f)
        return f

    def _tip_maps(self, st: _State):
        """Per-segment tip maps in segment coordinates: ``Ad_j`` (n, 6, 6), ``S_j`` (n, 6, 3)."""
        n = arc_nodes(np.ones(self.n), st.q_c)
        S = n.S if st.J is None else n.S @ st.J
        return n.Ad_inv, S

    @_finite("tip Jacobian")
    def tip_jacobian(self, q, reference: str = "local", t: float = 0.0) -> np.ndarray:
        """Tip frame Jacobian (6, nv): ``V_tip = J v`` (+ the base's own motion if prescribed).

        ``reference``: ``"local"`` (tip frame, Pinocchio LOCAL), ``"local_world_aligned"``
        (tip origin, world axes) or ``"world"`` (spatial twist at the world origin).
        """
        st = self._state(q, t=t)
        Ad, S = self._tip_maps(st)
        Jt = np.zeros((6, self.nv))
        if self.floating:
            Jt[:, :6] = np.eye(6)
        for j in range(self.n):
            Jt = Ad[j] @ Jt
            Jt[:, self.v_slice(j)] += S[j]
        return self._express(Jt, self.placements(q, t)[-1], reference)

    def points(self, q, where, t: float = 0.0) -> np.ndarray:
        """World positions (m, 3), m, of the backbone points ``where`` = ``[(segment, alpha),
        ...]`` (0-based segment, ``alpha`` in [0, 1] along it; segment ``-1`` is the last)."""
        segs, alphas = self._where(where)
        st = self._state(q, t=t)
        grid = np.unique(alphas)
        f = self._state_frames(st, grid)
        return f.backbone[0, segs, np.searchsorted(grid, alphas)]

    @_finite("point Jacobian")
    def point_jacobian(self, q, segment: int, alpha: float, t: float = 0.0) -> np.ndarray:
        """``d(point)/dq`` (3, nv): the linear rows, in world axes, of the exact frame Jacobian
        of the slice at ``alpha`` in [0, 1] of ``segment`` (segment ``-1`` the last), along
        ``integrate(q, dq)``: the root maps of the segments before it, then the slice's own map
        at ``alpha`` (:meth:`tip_jacobian`'s construction, stopped there)."""
        (seg,), (a,) = self._where([(segment, alpha)])
        st = self._state(q, t=t)
        alphas = np.ones(self.n)
        alphas[seg] = a
        nodes = arc_nodes(alphas, st.q_c)
        S = nodes.S if st.J is None else nodes.S @ st.J
        Jt = np.zeros((6, self.nv))
        if self.floating:
            Jt[:, :6] = np.eye(6)
        for j in range(seg + 1):
            Jt = nodes.Ad_inv[j] @ Jt
            Jt[:, self.v_slice(j)] += S[j]
        R = self.placements(q, t)[seg].rotation @ nodes.R[seg]
        return R @ Jt[:3]

    def _where(self, where) -> tuple[np.ndarray, np.ndarray]:
        """Checked ``(segment, alpha)`` pairs as arrays (segment made >= 0)."""
        segs, alphas = [], []
        for i, item in enumerate(where):
            try:
                seg, a = item
            except (TypeError, ValueError):
                raise ValueError(f"where[{i}] must be a (segment, alpha) pair, got {item!r}") from None
            if isinstance(seg, bool) or not isinstance(seg, (int, np.integer)) or not -self.n <= seg < self.n:
                raise ValueError(f"where[{i}]: segment must be an int in [-{self.n}, {self.n - 1}], got {seg!r}")
            a = float(a)
            if not 0.0 <= a <= 1.0:
                raise ValueError(f"where[{i}]: alpha must be in [0, 1], got {a!r}")
            segs.append(int(seg) % self.n)
            alphas.append(a)
        return np.array(segs, dtype=np.int64), np.array(alphas)

    @staticmethod
    def _express(J_local: np.ndarray, X: pin.SE3, reference: str) -> np.ndarray:
        """Tip-frame (LOCAL) Jacobian columns (6, k) re-expressed in ``reference`` at the tip
        placement ``X`` (see :meth:`tip_jacobian`)."""
        if reference == "local":
            return J_local
        if reference == "world":
            return X.action @ J_local
        if reference == "local_world_aligned":
            return np.concatenate([X.rotation @ J_local[:3], X.rotation @ J_local[3:]])
        raise ValueError(f"reference must be 'local', 'local_world_aligned' or 'world', got {reference!r}")

    @_finite("tip twist", has_v=True)
    def tip_velocity(self, q, v, reference: str = "local", t: float = 0.0) -> np.ndarray:
        """Tip twist (6,) ``[linear; angular]`` in ``reference`` (see :meth:`tip_jacobian`)."""
        V = self._root_twists(self._state(q, v, t=t))
        return self._express(V[-1][:, None], self.placements(q, t)[-1], reference)[:, 0]

    def _root_twists(self, st: _State) -> np.ndarray:
        """Body twists (n + 1, 6) of the segment roots and (last) of the tip
        (:func:`qchain.algorithms.recursive.tip_maps`)."""
        T = np.empty((self.n, 6, 9))
        c = np.empty((self.n, 6))
        V = np.empty((self.n + 1, 6))
        recursive.tip_maps(st.q_c, np.ascontiguousarray(st.v_c), st.V0, T, c, V)
        return V
