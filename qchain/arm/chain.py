"""An n-segment soft arm: segments stacked through non-inertial root frames.

The root frame of segment ``j + 1`` is the tip frame of segment ``j`` (docs/model.md
section 8; the paper's non-inertial root frames, section III-B), so the arm has
piecewise-constant (variable) curvature. :class:`Chain` is the model
(parameters, never changed by algorithms) and its user-facing methods; the recursive
passes live in :mod:`qchain.algorithms.recursive`, the world frames and kinematics in
:mod:`qchain.arm.kinematics` and the input checks and non-finite result errors in
:mod:`qchain.arm.checks` (base classes of :class:`Chain`).

Configuration layout (Pinocchio's conventions):

* ``base="fixed"``: ``q = (q_e1, ..., q_en)`` (nq = 3n), ``v = (qdot_e1, ...)`` (nv = 3n);
  the base sits at ``base_placement`` in the world.
* ``base="floating"``: ``q = (x, y, z, qx, qy, qz, qw, q_e...)`` (nq = 7 + 3n),
  ``v = (v_B, w_B, qdot_e...)`` (nv = 6 + 3n): the base's linear and angular velocity in
  its own frame -- the paper's quasi-velocities ``xi`` for the base, so the attitude has no
  singularity (docs/model.md section 7).
* ``base="prescribed"``: as fixed, with the base placement, body twist and body
  acceleration given functions of time (``base_motion(t) -> (X_WB, V_B, A_B)``).

Equation of motion, the paper's eq. (9) for a chain (docs/model.md section 6; every
generalised force in the segments' own coordinates)::

    M(q) a + C(q, v) v + g(q) + D v + dU_el/dq = B(q) p + tau

with ``nonlinear_effects = C v + g`` (plus the base-motion forcing for a prescribed
base). Pressures ``p`` (Pa) are ordered segment by segment, chambers 1..3.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import itertools

import numpy as np
import pinocchio as pin

from . import dynamics_derivatives as _derivs
from ..algorithms import planar as _planar
from ..algorithms import recursive
from ..algorithms.arrays import ChainArrays
from ..model.arc import SCRATCH, arc_nodes
from .checks import QUATERNION_TOLERANCE, ChainChecks, _finite  # noqa: F401 (QUATERNION_TOLERANCE re-exported)
from .contact import ChainContact, _plus_drag
from .energies import ChainEnergies
from .parameter_derivatives import ChainParameters
from .kinematics import ChainKinematics, Frames
from .dynamics_derivatives import _EMPTY, _ZERO6, ForwardDynamicsDerivatives, InverseDynamicsDerivatives
from .data import Data
from .payload import payload_matrix
from .tendons import ChainTendons, tendon_table
from ..checks.bounds import GRAVITY, POSITION, PSI, SEGMENT_COUNT, TIME
from ..checks.convert import as_bool, as_index, as_vector, describe_value
from ..errors import DomainError, NonFiniteError, SingularConfigurationError
from ..model.segment import PAPER_SINGULAR_ANGLE, Segment
from ..model.segment import _paper_jacobian as paper_jacobian, _paper_jacobian_dot as paper_jacobian_dot
from ..model.segment import _paper_to_curvature as paper_to_curvature
from ..model.spatial import _ad_matrix as ad_matrix, _force_cross_bar as force_cross_bar
from ..checks.frozen import KeepsReadOnly

__all__ = ["Chain", "Frames", "BASES"]

BASES = ("fixed", "floating", "prescribed")


@dataclass
class _State:
    """One evaluation's inputs, validated and in curvature coordinates."""

    X_WB: pin.SE3
    q_e: np.ndarray  # (n, 3) segment coordinates
    q_c: np.ndarray  # (n, 3) curvature coordinates
    J: np.ndarray | None  # (n, 3, 3) dq_c/dq_e, None if all segments use curvature coordinates
    v_e: np.ndarray | None = None  # (n, 3)
    v_c: np.ndarray | None = None  # (n, 3)
    V0: np.ndarray | None = None  # (6,) base body twist
    A_B: np.ndarray | None = None  # (6,) base body acceleration (prescribed)
    g_B: np.ndarray | None = None  # (3,) gravity in the base frame
    q: np.ndarray | None = None  # (nq,) the whole validated configuration
    v: np.ndarray | None = None  # (nv,) and velocity


def _check_placement(name: str, X) -> None:
    """``X`` must be a ``pinocchio.SE3`` with a finite rotation matrix (orthonormal, det 1,
    within 1e-9) and a translation within :data:`qchain.checks.bounds.POSITION`."""
    if not isinstance(X, pin.SE3):
        raise TypeError(f"{name} must be a pinocchio.SE3, got {describe_value(X)}")
    H = X.homogeneous
    if not np.all(np.isfinite(H)):
        raise ValueError(f"{name} must be finite, got a placement with non-finite entries")
    R = H[:3, :3]
    err = float(np.max(np.abs(R.T @ R - np.eye(3))))
    if not (err <= 1e-9 and np.linalg.det(R) > 0.0):
        raise ValueError(f"{name}.rotation must be a rotation matrix (R^T R = I within 1e-9, det R = 1), got "
                         f"|R^T R - I| = {err:.3g}, det R = {np.linalg.det(R):.6g}")
    POSITION.check_array(f"{name}.translation", H[:3, 3])


class Chain(KeepsReadOnly, ChainKinematics, ChainEnergies, ChainContact, ChainParameters, ChainTendons, ChainChecks):
    """A soft arm of ``n`` segments.

    Parameters
    ----------
    segments : sequence of Segment
        From the base to the tip; they may differ in every parameter and coordinate choice.
    base : {"fixed", "floating", "prescribed"}
    gravity : (3,) m/s^2
        World gravity, each component within +-1e4 m/s^2 (:data:`qchain.checks.bounds.GRAVITY`).
    base_placement : pinocchio.SE3, optional
        World placement ``X_WB`` of a fixed base (default identity).
    base_motion : callable, optional
        For ``base="prescribed"``: ``t -> (X_WB, V_B, A_B)`` with ``X_WB`` a ``pinocchio.SE3``,
        ``V_B`` (6,) the base's body twist and ``A_B`` (6,) its derivative (base frame,
        ``[linear; angular]``, m/s, rad/s, m/s^2, rad/s^2).
    planar : bool
        Hold ``uy = 0`` in every segment (curvature coordinates only): the arm moves in the
        base's x-z plane. Exact for scenes symmetric about that plane.
    payload : pinocchio.Inertia, optional
        A rigid body fixed at the tip frame (root ``n``): ``Inertia(mass, lever, inertia)``,
        mass (kg, >= 0), centre of mass ``lever`` (3,) m in the tip frame, rotational inertia
        (3, 3) kg m^2 about it, tip-frame axes (symmetric, positive semi-definite). It enters
        every dynamics pass, gravity included, and the energies and momentum
        (:mod:`qchain.arm.payload`). With ``planar=True`` it must be symmetric about the x-z
        plane. None (default): no payload.
    tendons : sequence of Tendon, optional
        Tendons beside the chambers (:class:`qchain.Tendon`, :class:`ChainTendons`; docs/tendons.md).

    Locked coordinates (``planar``, and ``l`` of segments with ``extensible=False``) keep
    their place in ``q`` and ``v`` so layouts do not change: ``q`` must hold the locked
    value (``l0``, or 0 for ``uy``), ``v`` zero there, and :meth:`forward_dynamics` returns
    zero acceleration there (an ideal constraint). ``active`` marks the free velocity
    coordinates.

    Inputs of every method (``q``, ``v``, ``a``, ``p``, ``tau``) are real arrays of the right
    shape (``TypeError`` for strings, booleans, complex numbers), finite and inside the
    model's domain (``ValueError`` or :class:`~qchain.errors.DomainError` naming the entry
    and segment); a result that is not finite raises :class:`~qchain.errors.NonFiniteError`
    naming the quantity, the segment whose state overflows and the time.

    Attributes
    ----------
    n, nq, nv, nu, nt : int
        Segments, configuration size, velocity size, pressure inputs (3 n), tendons (``tendons``).
    active : (nv,) bool
        Free (not locked) velocity coordinates; ``nv_active`` of them.
    """

    def __init__(
        self,
        segments: Sequence[Segment],
        base: str = "fixed",
        gravity=(0.0, 0.0, -9.81),
        base_placement: pin.SE3 | None = None,
        base_motion: Callable | None = None,
        planar: bool = False,
        payload: pin.Inertia | None = None,
        tendons: Sequence = (),
    ):
        if (isinstance(segments, (Segment, str, bytes, set, frozenset, dict)) or isinstance(segments, np.ndarray)
                and segments.ndim != 1 or not isinstance(segments, Sequence) and not hasattr(segments, "__iter__")):
            # (a set or a dict has no order: the segments' order from base to tip would be arbitrary)
            raise TypeError(f"segments must be a sequence (list or tuple, or a 1-d array) of qchain.Segment, got "
                            f"{describe_value(segments)}")
        try:
            segs = tuple(itertools.islice(segments, int(SEGMENT_COUNT.high) + 1))  # (an endless iterable ends)
        except TypeError as e:  # an object whose __iter__ refuses
            raise TypeError(f"segments must be a sequence of qchain.Segment, got {describe_value(segments)} ({e})"
                            ) from None
        if len(segs) == 0:
            raise ValueError("segments must hold at least one Segment, got none")
        if len(segs) > SEGMENT_COUNT.high:
            raise ValueError(f"segments must hold at most {SEGMENT_COUNT.high:g} Segments (qchain.checks.bounds.SEGMENT_COUNT), "
                             "got more")
        for j, s in enumerate(segs):
            if not isinstance(s, Segment):
                raise TypeError(f"segments[{j}] must be a qchain.Segment, got {type(s).__name__}")
        if not isinstance(base, str) or base not in BASES:
            raise ValueError(f"base must be one of {BASES}, got {base!r}")
        if base == "prescribed" and not callable(base_motion):
            raise ValueError("base='prescribed' needs base_motion, a callable t -> (X_WB, V_B, A_B)")
        if base != "prescribed" and base_motion is not None:
            raise ValueError(f"base_motion is only used with base='prescribed', got base={base!r}")
        if base_placement is not None and base != "fixed":
            raise ValueError(f"base_placement is only used with base='fixed', got base={base!r}")
        if base_placement is not None and not isinstance(base_placement, pin.SE3):
            raise TypeError(f"base_placement must be a pinocchio.SE3, got {type(base_placement).__name__}")
        if base_placement is not None:
            _check_placement("base_placement", base_placement)
        self.segments = segs
        self.base = base
        self._gravity = np.array(GRAVITY.check_array("gravity", as_vector("gravity", gravity, 3)))  # its own copy
        self._gravity.flags.writeable = False  # the passes use it (and its base-frame image) as given here
        self._X_WB0 = pin.SE3.Identity() if base_placement is None else pin.SE3(base_placement)
        self.base_motion = base_motion
        n = len(segs)
        self.n = n
        self.nu = 3 * n
        self.tendons, self._tendon_rows, self._tendon_nodes, self._tendon_weights = tendon_table(tendons, segs)
        self.nt = len(self.tendons)
        self.floating = base == "floating"
        self._qoff = 7 if self.floating else 0
        self._voff = 6 if self.floating else 0
        self.nq = self._qoff + 3 * n
        self.nv = self._voff + 3 * n
        # flat per-segment arrays for the compiled passes
        counts = np.array([s.node_count for s in segs])
        self._offs = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self._alpha = np.concatenate([s.alpha_nodes for s in segs])
        self._w = np.concatenate([s.alpha_weights for s in segs])
        for name, attr in (("_mass", "mass"), ("_radius", "radius"), ("_l0", "length"), ("_EI", "bending_stiffness"),
                           ("_EA", "axial_stiffness"), ("_beta", "damping"), ("_A_ch", "chamber_area"),
                           ("_r_ch", "chamber_radius")):
            setattr(self, name, np.array([getattr(s, attr) for s in segs], dtype=float))
        self._paper_act = np.array([s.actuation == "paper" for s in segs])
        self._paper = np.array([s.coords == "paper" for s in segs])
        self._any_paper = bool(self._paper.any())
        # the paper's literal linear law (stiffness_matrix, damping_matrix): constant matrices in
        # the segment's coordinates. In curvature coordinates the compiled passes carry them
        # (ChainArrays.K, .D); a paper-coordinate segment's are evaluated by the Segment
        self._literal = np.array([s.stiffness_matrix is not None or s.damping_matrix is not None for s in segs])
        self._linear = self._literal & self._paper
        self._has_linear = bool(self._linear.any())
        laws = [s._law_c() for s in segs]  # (D, K_e, q_e0, linear) in curvature coordinates
        self._D, self._K, self._q_rest = (np.array([law[i] for law in laws]) for i in range(3))
        self._linear_law = np.array([law[3] for law in laws])
        self._drag = np.array([[s.drag_linear, s.drag_quadratic] for s in segs], dtype=float)  # (n, 2)
        self._has_drag = bool(self._drag.any())
        if self._has_drag and self._any_paper:
            j = int(np.flatnonzero(self._paper)[0])
            raise ValueError(f"segments[{j}] has coords='paper': a chain with drag (drag_linear, drag_quadratic) "
                             "needs every segment in curvature coordinates")
        if not isinstance(planar, (bool, np.bool_)):
            raise TypeError(f"planar must be True or False, got {describe_value(planar)}")
        if planar and self._any_paper:
            j = int(np.flatnonzero(self._paper)[0])
            raise ValueError(f"planar=True needs curvature coordinates; segments[{j}] has coords='paper'")
        self.planar = bool(planar)
        # the checked payload and its spatial inertia (6, 6) at the tip origin (zeros: none)
        self._payload_inertia, self._payload = payload_matrix(payload, self.planar)
        self._payload.flags.writeable = False
        self._has_payload = self._payload_inertia is not None
        self._planar_kernel = self.planar and base == "fixed"  # forward dynamics on qchain.algorithms.planar
        # curvature coordinates and the material law: what the one-call compiled paths serve
        # (recursive.forward_dynamics, aba_derivatives.forward_dynamics_derivatives)
        self._curvature = not (self._any_paper or self._has_linear)
        self._fused = self._curvature and not self._planar_kernel
        self._p_zero = np.zeros((n, 3))  # p = None on the unchecked path (writable: one array type for the kernels)
        self._p_flat = self._p_zero.reshape(-1)
        self._own_data: dict[int, Data] = {}  # the workspaces of calls without data= (_workspace)
        self._locked = np.zeros((n, 3), dtype=bool)
        self._locked[:, 0] = [not s.extensible for s in segs]
        self._locked[:, 2] = self.planar
        self._lock_values = np.zeros((n, 3))
        self._lock_values[:, 0] = self._l0
        self._any_locked = bool(self._locked.any())
        # the same arrays as one structure (kernel_arrays), and as the plain tuple of its fields
        # that the Python-side calls pass (numba types a plain tuple of arrays in C, a
        # NamedTuple field by field in Python: a microsecond a call; the passes name it again)
        self._named_arrays = ChainArrays(alpha=self._alpha, w=self._w, offs=self._offs, mass=self._mass,
                                   radius=self._radius, l0=self._l0, EI=self._EI, EA=self._EA, beta=self._beta,
                                   A_ch=self._A_ch, r_ch=self._r_ch, paper_act=self._paper_act, locked=self._locked,
                                   payload=self._payload, D=self._D, K=self._K, q_rest=self._q_rest,
                                   linear_law=self._linear_law, drag=self._drag)
        self._arrays = tuple(self._named_arrays)
        self.active = np.ones(self.nv, dtype=bool)
        self.active[self._voff :] = ~self._locked.ravel()
        self.active.flags.writeable = False
        self.nv_active = int(self.active.sum())
        self._g_B = self._X_WB0.rotation.T @ self.gravity
        self._R_WB = self._X_WB0.rotation[None].copy()  # (1, 3, 3), for recursive.frames
        self._p_WB = self._X_WB0.translation[None].copy()  # (1, 3)
        if self.floating:
            self._ff = pin.Model()
            self._ff.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")

    # ------------------------------------------------------------------ layout

    @property
    def base_placement(self) -> pin.SE3:
        """World placement ``X_WB`` of a fixed base (a copy: the chain's passes keep
        quantities made from it, so it is set once, at construction)."""
        return pin.SE3(self._X_WB0)

    @property
    def payload(self) -> pin.Inertia | None:
        """The tip payload (a new ``pinocchio.Inertia``, tip frame), or None; read-only (the
        passes keep its spatial inertia: make a new Chain for another payload)."""
        return pin.Inertia(self._payload_inertia) if self._has_payload else None

    def kernel_arrays(self) -> ChainArrays | None:
        """The flat per-node and per-segment arrays the compiled passes take, as one named
        structure (:class:`qchain.algorithms.arrays.ChainArrays`; the chain's own arrays, not
        copies: never write them), or None where compiled code
        cannot evaluate the chain's segment forces (paper coordinates in some segment, evaluated
        in Python through the coordinate map; the linear law in curvature coordinates is
        compiled).

        ``N`` nodes over all segments, ``n`` segments: ``alpha (N,)`` the nodes' arc
        parameters in [0, 1], ``w (N,)`` their quadrature weights, ``offs (n + 1,) int64``
        segment ``j``'s nodes ``offs[j]:offs[j + 1]``; ``mass`` (kg), ``radius`` (m), ``l0``
        rest length (m), ``EI`` (N m^2), ``EA`` (N), ``beta`` damping (s), ``A_ch`` chamber
        area (m^2), ``r_ch`` chamber radius (m), all ``(n,)``; ``paper_act (n,) bool`` the
        paper's actuation law; ``locked (n, 3) bool`` coordinates held still; ``payload
        (6, 6)`` the tip payload's spatial inertia (zeros: none); ``D (n, 3, 3)`` each
        segment's constant dissipation matrix, ``K (n, 3, 3)``, ``q_rest (n, 3)`` and
        ``linear_law (n,) bool`` the linear elastic law (``stiffness_matrix``) where it is given."""
        if self._any_paper:
            return None
        return self._named_arrays

    def q_slice(self, j: int) -> slice:
        """Indices of segment ``j``'s ``q_e`` in ``q`` (``0 <= j < n``)."""
        if type(j) is not int or not 0 <= j < self.n:
            j = as_index("j", j, self.n)
        return slice(self._qoff + 3 * j, self._qoff + 3 * j + 3)

    def v_slice(self, j: int) -> slice:
        """Indices of segment ``j``'s ``qdot_e`` in ``v`` (``0 <= j < n``)."""
        if type(j) is not int or not 0 <= j < self.n:
            j = as_index("j", j, self.n)
        return slice(self._voff + 3 * j, self._voff + 3 * j + 3)

    def neutral(self) -> np.ndarray:
        """The straight rest configuration (nq,), base at the origin for a floating base."""
        q = np.zeros(self.nq)
        if self.floating:
            q[6] = 1.0
        for j, s in enumerate(self.segments):
            q[self.q_slice(j)] = s.neutral()
        return q

    def __getstate__(self):
        state = super().__getstate__()
        state["_own_data"] = {}  # the calls' own workspaces stay with this process's threads
        return state

    def __repr__(self) -> str:
        return f"Chain(n={self.n}, base={self.base!r}, nq={self.nq}, nv={self.nv})"

    # ------------------------------------------------------------------ inputs

    def base_state(self, t: float = 0.0):
        """``(X_WB, V_B, A_B)`` of a prescribed base at time ``t`` (validated)."""
        if self.base != "prescribed":
            raise ValueError(f"base_state is for base='prescribed', this chain has base={self.base!r}")
        t = self._time(t)
        out = self.base_motion(t)
        if not (isinstance(out, tuple) and len(out) == 3):
            raise TypeError(f"base_motion(t) must return (X_WB: pinocchio.SE3, V_B: (6,), A_B: (6,)), got "
                            f"{describe_value(out)} at t = {t:g} s")
        X, V, A = out
        _check_placement(f"base_motion({t:g})[0] (X_WB)", X)
        return X, as_vector("base_motion(t)[1] (V_B)", V, 6), as_vector("base_motion(t)[2] (A_B)", A, 6)

    def _state(self, q, v=None, t: float = 0.0, nonsingular: bool = False, extra=()) -> _State:
        """Validate and convert ``q`` (and ``v``); ``extra`` (name, array) pairs are checked
        for non-finite entries too."""
        q = self._q(q)
        if type(t) is not float or not -1e12 <= t <= 1e12:
            t = self._time(t)
        q_e = q[self._qoff :].reshape(self.n, 3)
        if v is not None:
            v = self._vec("v", v, self.nv)
            self._check_domain(q_e, ("q", q), ("v", v), *extra)
        else:
            self._check_domain(q_e, ("q", q), *extra)
        A_B = None
        if self.base == "fixed":
            X = self._X_WB0
            V0 = np.zeros(6)
        elif self.base == "floating":
            X = pin.XYZQUATToSE3(q[:7])
            V0 = None
        else:
            X, V0, A_B = self.base_state(t)
        J = None
        q_c = q_e
        if self._any_paper:
            q_c = q_e.copy()
            J = np.broadcast_to(np.eye(3), (self.n, 3, 3)).copy()
            for j in np.flatnonzero(self._paper):
                sl = self.q_slice(j)
                if not PSI.contains(q_e[j, 1]):  # qchain.checks.bounds.PSI
                    raise DomainError(f"segment {j} (q[{sl.start}:{sl.stop}]): bending plane angle psi = "
                                      f"{q_e[j, 1]:.6g} rad must be {PSI.text()} (qchain.checks.bounds.PSI)")
                if nonsingular and q_e[j, 2] * q_e[j, 0] < PAPER_SINGULAR_ANGLE:
                    raise SingularConfigurationError(
                        f"segment {j} (q[{sl.start}:{sl.stop}]): bending angle kappa*l = {q_e[j, 2] * q_e[j, 0]:.3e} rad "
                        f"is below {PAPER_SINGULAR_ANGLE:g} rad, where the paper's (l, psi, kappa) coordinates are "
                        "singular; use coords='curvature' for this segment"
                    )
                q_c[j] = paper_to_curvature(q_e[j])
                J[j] = paper_jacobian(q_e[j])
        st = _State(X_WB=X, q_e=q_e, q_c=np.ascontiguousarray(q_c), J=J, A_B=A_B, q=q, v=v)
        st.g_B = self._g_B if self.base == "fixed" else X.rotation.T @ self.gravity
        if v is not None:
            st.v_e = v[self._voff :].reshape(self.n, 3)
            st.v_c = st.v_e if J is None else np.einsum("nij,nj->ni", J, st.v_e)
            st.V0 = v[:6].copy() if self.floating else V0
        else:
            st.V0 = np.zeros(6) if self.floating else V0
        return st

    def _acc_c(self, st: _State, a_e: np.ndarray) -> np.ndarray:
        """Segment accelerations in curvature coordinates: ``J a_e + Jdot v_e``."""
        if st.J is None:
            return np.ascontiguousarray(a_e)
        a_c = np.einsum("nij,nj->ni", st.J, a_e)
        for j in np.flatnonzero(self._paper):
            a_c[j] += paper_jacobian_dot(st.q_e[j], st.v_e[j]) @ st.v_e[j]
        return a_c

    def _force_e(self, st: _State, tau_c: np.ndarray) -> np.ndarray:
        """Generalised forces from curvature to segment coordinates: ``J^T tau_c``."""
        return tau_c if st.J is None else np.einsum("nji,nj->ni", st.J, tau_c)

    def _lift(self, st: _State) -> np.ndarray | None:
        """``T = blockdiag(I_base, J_1, ..., J_n)`` (nv, nv), or None if the identity."""
        if st.J is None:
            return None
        T = np.eye(self.nv)
        for j in range(self.n):
            T[self.v_slice(j), self.v_slice(j)] = st.J[j]
        return T

    # ------------------------------------------------------------------ Lie group

    def integrate(self, q, v, dt: float = 1.0) -> np.ndarray:
        """``q (+) v dt`` on the configuration manifold (Pinocchio's free-flyer exp for the base;
        docs/model.md section 7)."""
        q = as_vector("q", self._q(q), self.nq)
        v = as_vector("v", v, self.nv)
        dt = TIME.check("dt", dt)
        out = q.copy()
        with np.errstate(all="ignore"):
            if self.floating:
                out[:7] = pin.integrate(self._ff, q[:7], v[:6] * dt)
            out[self._qoff :] += v[self._voff :] * dt
        if not np.all(np.isfinite(out)):
            k = int(np.flatnonzero(~np.isfinite(out))[0])
            raise NonFiniteError(f"Chain.integrate: q (+) v dt is not finite (first at q[{k}], "
                                 f"{self.coordinate_name(k, velocity=False)}) for dt = {dt:g} s: v dt overflows")
        return out

    def difference(self, q0, q1) -> np.ndarray:
        """The ``v`` (nv,) with ``integrate(q0, v, 1) == q1``."""
        q0 = as_vector("q0", self._q(q0, "q0"), self.nq)
        q1 = as_vector("q1", self._q(q1, "q1"), self.nq)
        out = np.empty(self.nv)
        with np.errstate(all="ignore"):
            if self.floating:
                out[:6] = pin.difference(self._ff, q0[:7], q1[:7])
            out[self._voff :] = q1[self._qoff :] - q0[self._qoff :]
        if not np.all(np.isfinite(out)):
            k = int(np.flatnonzero(~np.isfinite(out))[0])
            raise NonFiniteError(f"Chain.difference: q1 - q0 is not finite (first at v[{k}], "
                                 f"{self.coordinate_name(k)}): the difference overflows")
        return out

    # ------------------------------------------------------------------ dynamics

    def _A0(self, st: _State, a_base=None) -> np.ndarray:
        """Apparent base acceleration ``a_B - (g_B, 0)`` (6,)."""
        A0 = np.zeros(6)
        if a_base is not None:
            A0 += a_base
        elif st.A_B is not None:
            A0 += st.A_B
        A0[:3] -= st.g_B
        return A0

    @property
    def gravity(self) -> np.ndarray:
        """Gravity (3,) m/s^2, world frame; read-only (the passes keep its base-frame image:
        make a new Chain for another gravity)."""
        return self._gravity

    @gravity.setter
    def gravity(self, value) -> None:
        raise AttributeError("Chain.gravity is read-only (the passes keep its base-frame image): make a new Chain "
                             "with gravity=...")

    def create_data(self) -> Data:
        """A per-evaluation workspace for this chain (Pinocchio's ``model.createData()``): pass it
        as ``data=`` to the dynamics methods so a loop of calls allocates no arrays."""
        return Data(self.n, self.nv)


    def _aba(self, q_c, v_c, f_c, V0, A0, F0, qdd_c, A0_out, data: Data | None) -> bool:
        """The articulated-body pass: :func:`qchain.algorithms.planar.planar_aba` for a planar chain on a
        fixed base (the same accelerations at 2-D cost), :func:`qchain.algorithms.recursive.aba` else."""
        data = self._workspace(data)
        if self._planar_kernel:
            pw = data.planar_workspace()
            A0_out[:] = A0
            return _planar.planar_aba(self._arrays, q_c, v_c, f_c, A0, qdd_c, tuple(pw), pw.pscratch)
        return recursive.aba(self._arrays, q_c, v_c, f_c, V0, A0, self.floating, F0, qdd_c, A0_out,
                             *self._ws_sc(data))

    def _ws_sc(self, data: Data | None) -> tuple:
        """``(workspace, scratch)`` arguments of the compiled passes, the workspace as the plain
        tuple of its fields (as ``_arrays``: the pass names it again)."""
        ws = self._workspace(data).aba_workspace()
        return tuple(ws), ws.scratch

    @_finite("mass matrix")
    def mass_matrix(self, q, data: Data | None = None) -> np.ndarray:
        """``M(q)`` (nv, nv) by composite-body assembly (:func:`qchain.algorithms.recursive.crba`):
        ``sum_j A_j^T M_xi_j A_j`` of the segments' eq. (6) blocks (docs/model.md section 8)."""
        st = self._state(q, nonsingular=True)
        data = self._data(data)
        H = np.empty((self.nv, self.nv)) if data is None else data.M
        recursive.crba(self._arrays, st.q_c, self.floating, H, *self._ws_sc(data))
        T = self._lift(st)
        return H if T is None else T.T @ H @ T

    def _rnea(self, st: _State, a_e: np.ndarray, a_base=None) -> np.ndarray:
        tau_c = np.empty((self.n, 3))
        F0 = np.empty(6)
        recursive.rnea(
            self._arrays, st.q_c, np.ascontiguousarray(st.v_c),
            self._acc_c(st, a_e), st.V0, self._A0(st, a_base), tau_c, F0, *self._ws_sc(None),
        )
        tau = self._force_e(st, tau_c).ravel()
        return np.concatenate([F0, tau]) if self.floating else tau

    @_finite("generalised force M a + C v + g", has_v=True)
    def inverse_dynamics(self, q, v, a, t: float = 0.0, env=None) -> np.ndarray:
        """``M a + C v + g`` (nv,) by recursive Newton-Euler over the slices (Pinocchio's ``rnea``;
        docs/model.md sections 4 and 8): the inertial and gravity terms of eq. (9).

        No elastic, damping or pressure terms. For a floating base the first six entries
        are the wrench on the base (base frame). For a prescribed base the base's own
        motion at time ``t`` is included. With ``env`` (a :class:`qchain.contact.Environment`)
        its generalised force is subtracted: what the arm's own forces must supply.
        """
        st = self._state(q, v, t=t, nonsingular=True)
        a = as_vector("a", a, self.nv)
        out = self._rnea(st, a[self._voff :].reshape(self.n, 3), a[:6] if self.floating else None)
        if env is not None:
            out = out - self.environment_force(q, v, env, t)
        return out

    def nonlinear_effects(self, q, v, t: float = 0.0) -> np.ndarray:
        """``C(q, v) v + g(q)`` (nv,) ``== inverse_dynamics(q, v, 0)`` (Pinocchio's ``nle``)."""
        return self.inverse_dynamics(q, v, np.zeros(self.nv), t=t)

    @_finite("generalised gravity")
    def generalized_gravity(self, q, t: float = 0.0) -> np.ndarray:
        """``g(q)`` (nv,): gravity alone (a prescribed base held still at its placement at ``t``);
        the ``g_xi`` of eq. (9) (docs/model.md section 9)."""
        st = self._state(q, np.zeros(self.nv), t=t, nonsingular=True)
        st.V0 = np.zeros(6)
        st.A_B = None
        return self._rnea(st, np.zeros((self.n, 3)), np.zeros(6) if self.floating else None)

    @_finite("elastic force")
    def elastic_force(self, q) -> np.ndarray:
        """``dU_el/dq`` (nv,), zero on the base (docs/model.md section 9)."""
        st = self._state(q)
        out = np.zeros(self.nv)
        for j, s in enumerate(self.segments):
            out[self.v_slice(j)] = s.elastic_force(st.q_e[j])
        return out

    def _segment_blocks(self, q, block) -> np.ndarray:
        """Block-diagonal (nv, nv) of ``block(j, segment, q_e)`` (3, 3), zero on the base."""
        st = self._state(q)
        out = np.zeros((self.nv, self.nv))
        for j, s in enumerate(self.segments):
            sl = self.v_slice(j)
            out[sl, sl] = block(j, s, st.q_e[j])
        return out

    @_finite("elastic stiffness")
    def elastic_stiffness(self, q) -> np.ndarray:
        """``d^2 U_el / dq^2`` (nv, nv), exact, block-diagonal, zero on the base."""
        return self._segment_blocks(q, lambda j, s, qe: s.elastic_stiffness(qe))

    @_finite("dissipation matrix")
    def dissipation_matrix(self, q) -> np.ndarray:
        """``D`` (nv, nv), block-diagonal, zero on the base (docs/model.md section 9)."""
        return self._segment_blocks(q, lambda j, s, qe: s.dissipation_matrix(qe))

    @_finite("pressure stiffness")
    def pressure_stiffness(self, q, p) -> np.ndarray:
        """``d(B(q) p)/dq`` (nv, nv), exact for both actuation models, zero on the base."""
        p3 = self._p(p)
        return self._segment_blocks(q, lambda j, s, qe: s.pressure_stiffness(qe, p3[j]))

    @_finite("damping force", has_v=True)
    def damping_force(self, q, v) -> np.ndarray:
        """``D v`` (nv,), zero on the base."""
        st = self._state(q, v)
        out = np.zeros(self.nv)
        for j, s in enumerate(self.segments):
            out[self.v_slice(j)] = s.damping_force(st.q_e[j], st.v_e[j])
        return out

    @_finite("input matrix")
    def input_matrix(self, q) -> np.ndarray:
        """``B(q)`` (nv, 3 n): block-diagonal, pressures act only on their own segment's ``q_e``,
        never as a net force on the base (the paper's eq. (8); docs/model.md section 5)."""
        st = self._state(q)
        B = np.zeros((self.nv, self.nu))
        for j, s in enumerate(self.segments):
            B[self.v_slice(j), 3 * j : 3 * j + 3] = s.input_matrix(st.q_e[j])
        return B

    @_finite("internal forces", has_v=True)
    def internal_forces(self, q, v, p=None) -> np.ndarray:
        """``B p - D v - dU_el/dq`` (nv,), the segments' own generalised forces, zero on the base
        (docs/model.md sections 5 and 9)."""
        st = self._state(q, v)
        f = self._internal_e(st, self._p(p))
        out = np.zeros(self.nv)
        out[self._voff :] = f.ravel()
        return out

    def _internal_e(self, st: _State, p: np.ndarray) -> np.ndarray:
        """Internal forces in segment coordinates (n, 3)."""
        f_c = np.empty((self.n, 3))
        recursive.internal_forces(
            self._arrays, st.q_c, np.ascontiguousarray(st.v_c), p, f_c, np.empty(SCRATCH),
        )
        f = self._force_e(st, f_c)
        if self._has_linear:
            f = f.copy()
            for j in np.flatnonzero(self._linear):
                s = self.segments[j]
                f[j] = s.input_matrix(st.q_e[j]) @ p[j] - s.damping_force(st.q_e[j], st.v_e[j]) - s.elastic_force(st.q_e[j])
        return f

    def forward_dynamics(self, q, v, p=None, tau=None, t: float = 0.0, data: Data | None = None,
                         skip_checks: bool = False, env=None, tension=None) -> np.ndarray:
        """Accelerations ``a`` (nv,) of ``M a + C v + g + D v + dU_el/dq = B p + tau``.

        The paper's eq. (9) for the chain (docs/model.md section 6), solved by the
        articulated-body recursion on the segment blocks (:func:`qchain.algorithms.recursive.aba`;
        docs/model.md section 8), O(n); locked coordinates get zero acceleration. ``p`` (3 n,)
        Pa, default zero; ``tau`` (nv,) external generalised forces (for a floating base,
        ``tau[:6]`` is a wrench on the base in the base frame). ``data`` (:meth:`create_data`)
        is the workspace the pass writes in. ``skip_checks=True``
        is the unchecked fast path (:meth:`forward_dynamics_derivatives`): it returns
        ``data.a``, overwritten by the next call with that ``data``. ``env`` (a
        :class:`qchain.contact.Environment`) adds its contact forces and loads to ``tau``
        (:meth:`environment_force`). ``tension`` (nt,) N adds ``B_T(q) T`` (:meth:`tendon_force`).
        """
        data = self._data(data)
        tau = tau if tension is None else self._with_tendons(q, tau, tension)
        if env is not None:
            te = self.environment_force(q, v, env, t)
            tau = te if tau is None else self._vec("tau", tau, self.nv) + te
        if as_bool("skip_checks", skip_checks):
            return self._forward_dynamics_unchecked(q, v, p, tau, t, data)
        st, p3, tau = self._dynamics_inputs(q, v, p, tau, t)
        if self._has_drag:
            tau = self._with_drag(tau, st.q_c, st.v_c, st.V0)
        return self._forward_dynamics(st, p3, tau, t, data)

    def _dynamics_inputs(self, q, v, p, tau, t):
        """Validated ``(state, p (n, 3), tau)`` of a forward-dynamics call, locks checked."""
        p3, tau, extra = self._pt(p, tau)
        st = self._state(q, v, t=t, nonsingular=True, extra=extra)
        if self._any_locked:
            self._check_locks(st.q_e, st.v_e)
        return st, p3, tau

    def _forward_dynamics_unchecked(self, q, v, p, tau, t, data):
        if self._has_drag:
            tau = self._drag_unchecked(q, v, t, tau)
        if self._fused and data is not None:  # a singular articulated block is not reported here
            V0, A_B, g_B = self._unchecked_base(q, v, p, t, data)
            recursive.forward_dynamics(self._arrays, self.floating, q, v, self._p_flat if p is None else p,
                                       _EMPTY if tau is None else tau, V0, _ZERO6 if A_B is None else A_B, g_B,
                                       data.f, data.a, tuple(data.aba_workspace()), data.scratch)
            return data.a
        q_c, v_c, p3, V0, A_B, g_B = self._unchecked_inputs(q, v, p, t, data)  # the planar kernel
        f = data.f
        recursive.internal_forces(self._arrays, q_c, v_c, p3, f, data.scratch)
        F0 = _ZERO6
        if tau is not None:
            f += tau[self._voff :].reshape(self.n, 3)
            if self.floating:
                F0 = tau[:6]
        A0 = data.A0
        A0[:] = 0.0 if A_B is None else A_B
        A0[:3] -= g_B
        a = data.a
        self._aba(q_c, v_c, f, V0, A0, F0, a[self._voff :].reshape(self.n, 3), a[:6] if self.floating else A0, data)
        if self.floating:
            a[:3] += g_B
        return a

    def _forward_dynamics(self, st: _State, p3: np.ndarray, tau: np.ndarray | None, t: float,
                          data: Data | None = None) -> np.ndarray:
        """:meth:`forward_dynamics` on a validated state."""
        a = np.empty(self.nv)
        if self._fused:  # what the path below computes, in one compiled call
            d = self._workspace(data)
            status = recursive.forward_dynamics(self._arrays, self.floating, st.q, st.v, p3.reshape(-1),
                                                _EMPTY if tau is None else tau, st.V0,
                                                _ZERO6 if st.A_B is None else st.A_B, st.g_B, d.f, a,
                                                tuple(d.aba_workspace()), d.scratch)
            ok, finite = status != 1, status == 0
        else:
            f = self._internal_e(st, p3)
            F0 = np.zeros(6)
            if tau is not None:
                f = f + tau[self._voff :].reshape(self.n, 3)
                if self.floating:
                    F0 = tau[:6].copy()
            f_c = f if st.J is None else np.linalg.solve(np.swapaxes(st.J, 1, 2), f[..., None])[..., 0]
            qdd_c = np.empty((self.n, 3))
            A0 = np.empty(6)
            ok = self._aba(st.q_c, np.ascontiguousarray(st.v_c), np.ascontiguousarray(f_c), st.V0, self._A0(st), F0,
                           qdd_c, A0, data)
        if not ok:
            culprit = self._overflowing_segment(st.q_e, st.v_e)
            if culprit:
                raise NonFiniteError(f"Chain.forward_dynamics: the acceleration is not finite at t = {t:.6g} s: "
                                     f"{culprit}")
            raise self.indefinite_error("forward_dynamics", st.q_e, t)
        if not self._fused:
            if self.floating:
                a[:6] = A0
                a[:3] += st.g_B
            if st.J is None:
                a[self._voff :] = qdd_c.ravel()
            else:
                a_e = np.empty((self.n, 3))
                for j in range(self.n):
                    rhs = qdd_c[j]
                    if self._paper[j]:
                        rhs = rhs - paper_jacobian_dot(st.q_e[j], st.v_e[j]) @ st.v_e[j]
                    a_e[j] = np.linalg.solve(st.J[j], rhs)
                a[self._voff :] = a_e.ravel()
            finite = np.all(np.isfinite(a))
        if not finite:
            q_full = np.concatenate([np.zeros(self._qoff), st.q_e.ravel()])
            v_full = np.concatenate([np.zeros(self._voff), st.v_e.ravel()])
            raise self.nonfinite_error("forward_dynamics", "acceleration", q_full, v_full, t, result=a)
        return a

    # ------------------------------------------------------------------ derivatives

    @_finite("inverse dynamics derivatives", has_v=True)
    def inverse_dynamics_derivatives(self, q, v, a, t: float = 0.0,
                                     data: Data | None = None) -> InverseDynamicsDerivatives:
        """Exact derivatives of :meth:`inverse_dynamics` (Pinocchio's ``computeRNEADerivatives``).

        Returns ``tau`` (nv,), ``dtau_dq``, ``dtau_dv`` and ``dtau_da`` (``= M``), each (nv, nv);
        the q-derivative is taken along :meth:`integrate` (a floating base's tangent space).
        Compiled analytic passes over the segments and their slices
        (:mod:`qchain.algorithms.rnea_derivatives`), no finite differences. With ``data``
        (:meth:`create_data`) the pass writes in it and, in curvature coordinates, the
        returned matrices are its arrays (overwritten by the next call).
        """
        a = self._vec("a", a, self.nv)
        st = self._state(q, v, t=t, nonsingular=True, extra=(("a", a),))
        return _derivs.inverse_dynamics_derivatives(self, st, a, self._data(data))

    @_finite("forward dynamics derivatives", has_v=True)
    def forward_dynamics_derivatives(self, q, v, p=None, tau=None, t: float = 0.0, data: Data | None = None,
                                     skip_checks: bool = False, env=None) -> ForwardDynamicsDerivatives:
        """Exact derivatives of :meth:`forward_dynamics` (Pinocchio's ``computeABADerivatives``).

        Returns ``a`` (nv,), ``da_dq``, ``da_dv`` (nv, nv) (q along :meth:`integrate`),
        ``da_dp`` (nv, 3 n) (1/Pa) and ``da_dtau`` (nv, nv) ``= M^-1``, of the whole equation of
        motion (elastic, damping and pressure terms included). Locked coordinates have zero
        rows and columns (:mod:`qchain.arm.dynamics_derivatives`).

        ``data`` (:meth:`create_data`): the workspace the passes write in; where the chain is
        in curvature coordinates the result's arrays are its arrays
        (overwritten by the next call with it). ``skip_checks=True`` is the unchecked fast path
        of integrators and batches (MuJoCo's ``skip_checks``): the inputs are taken as valid
        -- shapes, finiteness, the model's domain, a unit quaternion, locked values are not
        checked -- and the result is not checked for non-finite entries. It needs ``data``
        and a chain in curvature coordinates. ``env`` (a
        :class:`qchain.contact.Environment`) adds its forces and their exact derivatives
        (:meth:`environment_force_derivatives`): ``da/dq += M^-1 d tau_env/dq``, likewise ``v``.
        """
        data = self._data(data)
        if env is not None:
            te, dq, dv = self.environment_terms(q, v, env, t)
            out = self.forward_dynamics_derivatives(q, v, p, te if tau is None else self._vec("tau", tau, self.nv) + te,
                                                    t, data, skip_checks)
            return out._replace(da_dq=out.da_dq + out.da_dtau @ dq, da_dv=out.da_dv + out.da_dtau @ dv)
        if as_bool("skip_checks", skip_checks):
            return self._forward_dynamics_derivatives_unchecked(q, v, p, tau, t, data)
        st, p3, tau = self._dynamics_inputs(q, v, p, tau, t)
        if not self._has_drag:
            return _derivs.forward_dynamics_derivatives(self, st, p3, tau, t, data)
        tau, dq, dv = self._with_drag(tau, st.q_c, st.v_c, st.V0, True)
        return _plus_drag(_derivs.forward_dynamics_derivatives(self, st, p3, tau, t, data), dq, dv)

    def _forward_dynamics_derivatives_unchecked(self, q, v, p, tau, t, data):
        V0, A_B, g_B = self._unchecked_base(q, v, p, t, data)
        dq = dv = None
        if self._has_drag:
            tau, dq, dv = self._drag_unchecked(q, v, t, tau, True)
        p = self._p_flat if p is None else (p if p.ndim == 1 else p.reshape(-1))
        out = _derivs.compiled_forward_dynamics_derivatives(self, q, v, p, tau, V0, A_B, g_B, t, data, check=False)
        return out if dq is None else _plus_drag(out, dq, dv)

    @_finite("mass matrix derivative")
    def mass_matrix_derivative(self, q, data: Data | None = None) -> np.ndarray:
        """``dM[:, :, k] = dM/dq_k`` (nv, nv, nv) along :meth:`integrate`, exact."""
        return _derivs.mass_matrix_derivative(self, self._state(q, nonsingular=True), self._data(data))

    @_finite("Coriolis matrix", has_v=True)
    def coriolis_matrix(self, q, v) -> np.ndarray:
        """``C(q, v)`` (nv, nv) with ``C v = nonlinear_effects - g`` and ``dM/dt - 2C`` skew
        (the tip payload's terms included).

        ``C = sum_j A_j^T (C_xi_j A_j + M_xi_j Adot_j)`` with ``xi_j = A_j v``, from the
        segments' own ``C_xi`` (fixed and floating bases; a prescribed base adds a forcing
        that is not of the form ``C v``). docs/model.md sections 4 and 8; it is not the
        Christoffel matrix of the Lagrangian form (docs/model.md section 7), with which it
        shares ``C v`` and the skew property.
        """
        if self.base == "prescribed":
            raise ValueError("coriolis_matrix is defined for base='fixed' or 'floating' (a prescribed base "
                             "adds a time-dependent forcing, included in nonlinear_effects)")
        st = self._state(q, v, nonsingular=True)
        v = as_vector("v", v, self.nv)
        Ad, S = self._tip_maps(st)
        nodes = arc_nodes(np.ones(self.n), st.q_c, st.v_c)
        Vmap = np.zeros((6, self.nv))  # root twist of segment j per unit v
        Vdot = np.zeros((6, self.nv))  # its time derivative
        if self.floating:
            Vmap[:, :6] = np.eye(6)
        C = np.zeros((self.nv, self.nv))
        for j, s in enumerate(self.segments):
            sl = self.v_slice(j)
            A = np.zeros((9, self.nv))
            A[:6] = Vmap
            A[6:, sl] = np.eye(3)
            Adot = np.zeros((9, self.nv))
            Adot[:6] = Vdot
            xi = A @ v
            C += A.T @ (s.coriolis_matrix(st.q_e[j], xi) @ A + s.mass_matrix(st.q_e[j]) @ Adot)
            Sdot = nodes.Sdot[j]
            if self._paper[j]:
                Sdot = Sdot @ st.J[j] + nodes.S[j] @ paper_jacobian_dot(st.q_e[j], st.v_e[j])
            Ad_dot = -ad_matrix(S[j] @ st.v_e[j]) @ Ad[j]
            Vdot = Ad_dot @ Vmap + Ad[j] @ Vdot
            Vdot[:, sl] += Sdot
            Vmap = Ad[j] @ Vmap
            Vmap[:, sl] += S[j]
        if self._has_payload:  # a rigid body with twist V = Vmap v: C_b(V) = (V x* I + I ad(V) + bar(I V)) / 2, skew
            I = self._payload
            V = Vmap @ v
            C_b = 0.5 * (-ad_matrix(V).T @ I + I @ ad_matrix(V) + force_cross_bar(I @ V))
            C += Vmap.T @ (I @ Vdot + C_b @ Vmap)
        return C
