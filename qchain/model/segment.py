"""One soft pneumatic segment: the paper's per-segment blocks M_xi, C_xi, B.

The model (Olguin-Diaz, Trejo-Ramos, Parra-Vega and Navarro-Alarcon, "the paper"), its
coordinates ``q_e`` (3,) (``coords="curvature"`` ``(l, ux, uy)``, ``coords="paper"``
``(l, psi, kappa)``), quasi-velocities ``xi = (v, w, qdot_e)`` (9,), equation of motion
(eq. (9)) and density field: docs/model.md, sections 1 to 6 and 9, and docs/segment.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from ..checks import bounds as B
from .arc import SCRATCH, arc_nodes, strain_twist
from ..checks.convert import as_matrix, as_real, as_real_array, as_vector
from ..errors import DomainError, NonFiniteError, SingularConfigurationError
from .slices import (
    CHAMBER_ANGLES, domain_violation, elastic_gradient_c, elastic_hessian_c, input_matrix_c, pressure_jacobian_c,
    rest_damping_c, segment_mass, segment_newton_euler)
from .spatial import _ad_matrix as ad_matrix, _disk_inertia as disk_inertia, _force_cross_bar as force_cross_bar
from ..checks.frozen import KeepsReadOnly
from ..checks.arguments import checked
from ..checks.results import finite_result
from ..checks.text import show_vector

__all__ = [
    "Segment",
    "nodes_for_tolerance",
    "CHAMBER_ANGLES",
    "DEFAULT_NODES",
    "PAPER_SINGULAR_ANGLE",
    "paper_to_curvature",
    "curvature_to_paper",
    "paper_jacobian",
    "paper_jacobian_dot",
    "paper_jacobian_derivative",
    "paper_bias_derivative",
    "paper_velocity_to_curvature",
    "curvature_velocity_to_paper",
]

#: Default Gauss-Legendre node count along a segment. ``tests/test_segment.py`` checks
#: that it gives M_xi to 1e-10 relative (in the Frobenius norm) against a 40-node
#: reference for bending angles up to 2 rad.
DEFAULT_NODES = 6

#: In paper coordinates, bending angles ``kappa * l`` below this (rad) raise
#: :class:`SingularConfigurationError`: the psi column of M_xi scales with kappa, so its
#: condition number grows like ``1 / (kappa l)^2`` and exceeds 1e12 here.
PAPER_SINGULAR_ANGLE = 1e-6

COORDS = ("curvature", "paper")
ACTUATIONS = ("volume", "paper")


def _nonfinite(self, method: str, quantity: str, q_e, args, kwargs) -> NonFiniteError:
    """The error of a :class:`Segment` method whose result is not finite (:func:`_finite`)."""
    more = "".join(f", {show_vector(a, 9)}" for a in args)
    return NonFiniteError(
        f"Segment.{method}: the {quantity} is not finite at q_e = {show_vector(q_e, 9)}{more} "
        f"(segment of length {self.length:g} m, radius {self.radius:g} m, mass {self.mass:g} kg): "
        "the configuration's or rates' magnitudes overflow double precision"
    )


def _finite(quantity: str):
    """Decorator of a :class:`Segment` method ``(self, q_e, ...)``: a result that is not
    finite raises :class:`~qchain.errors.NonFiniteError` naming the quantity, the method
    and its arguments instead of being returned."""
    return finite_result(quantity, _nonfinite)


# ---------------------------------------------------------------------------------------
# coordinate conversions (module level: they know no segment parameters)


def _paper_to_curvature(q_p: np.ndarray) -> np.ndarray:
    """``(l, psi, kappa) -> (l, ux, uy) = (l, kappa cos psi, kappa sin psi)`` (docs/model.md section 1).

    Like every coordinate map of this module, it takes finite real (3,) arrays
    (``TypeError``/``ValueError`` naming the argument otherwise)."""
    l, psi, kappa = q_p
    return np.array([l, kappa * np.cos(psi), kappa * np.sin(psi)])


def _curvature_to_paper(q_c: np.ndarray) -> np.ndarray:
    """``(l, ux, uy) -> (l, psi, kappa)`` with ``psi = atan2(uy, ux)`` in (-pi, pi].

    At ``ux = uy = 0`` the azimuth is undefined; ``psi = 0`` is returned.
    """
    l, ux, uy = q_c
    return np.array([l, np.arctan2(uy, ux), np.hypot(ux, uy)])


def _paper_jacobian(q_p: np.ndarray) -> np.ndarray:
    """``J = d(l, ux, uy) / d(l, psi, kappa)``, shape (3, 3); ``det J = -kappa``, which is why
    the paper's coordinates are singular at ``kappa = 0`` (docs/model.md section 1)."""
    _, psi, kappa = q_p
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[1.0, 0.0, 0.0], [0.0, -kappa * s, c], [0.0, kappa * c, s]])


def _paper_jacobian_dot(q_p: np.ndarray, qd_p: np.ndarray) -> np.ndarray:
    """Time derivative of :func:`paper_jacobian` along ``qd_p``, shape (3, 3)."""
    _, psi, kappa = q_p
    _, psid, kappad = qd_p
    c, s = np.cos(psi), np.sin(psi)
    return np.array(
        [
            [0.0, 0.0, 0.0],
            [0.0, -kappad * s - kappa * c * psid, -s * psid],
            [0.0, kappad * c - kappa * s * psid, c * psid],
        ]
    )


def _paper_jacobian_derivative(q_p: np.ndarray) -> np.ndarray:
    """``dJ[c] = d paper_jacobian / d q_p[c]`` (3, 3, 3), ``c`` over ``(l, psi, kappa)``."""
    _, psi, kappa = q_p
    c, s = np.cos(psi), np.sin(psi)
    dJ = np.zeros((3, 3, 3))
    dJ[1, 1:, 1:] = [[-kappa * c, -s], [-kappa * s, c]]
    dJ[2, 1:, 1] = [-s, c]
    return dJ


def _paper_bias_derivative(q_p: np.ndarray, qd_p: np.ndarray) -> np.ndarray:
    """``d(Jdot qd_p)/d q_p`` (3, 3) at fixed ``qd_p``: the configuration derivative of the
    velocity-product term of ``qdd_c = J qdd_p + Jdot qd_p``."""
    _, psi, kappa = q_p
    _, psid, kappad = qd_p
    c, s = np.cos(psi), np.sin(psi)
    out = np.zeros((3, 3))
    out[1, 1] = -2.0 * c * psid * kappad + kappa * s * psid * psid
    out[2, 1] = -2.0 * s * psid * kappad - kappa * c * psid * psid
    out[1, 2] = -c * psid * psid
    out[2, 2] = -s * psid * psid
    return out


def _paper_velocity_to_curvature(q_p: np.ndarray, qd_p: np.ndarray) -> np.ndarray:
    """``(ldot, psidot, kappadot) -> (ldot, uxdot, uydot) = J qd_p``."""
    return _paper_jacobian(q_p) @ qd_p


def _q3(name: str, x) -> np.ndarray:
    """A finite real (3,) array named ``name`` in errors."""
    return as_vector(name, x, 3)


# the checked entry points: finite real (3,) arrays, TypeError/ValueError naming the argument
paper_to_curvature = checked(_paper_to_curvature, q_p=_q3)
curvature_to_paper = checked(_curvature_to_paper, q_c=_q3)
paper_jacobian = checked(_paper_jacobian, q_p=_q3)
paper_jacobian_dot = checked(_paper_jacobian_dot, q_p=_q3, qd_p=_q3)
paper_jacobian_derivative = checked(_paper_jacobian_derivative, q_p=_q3)
paper_bias_derivative = checked(_paper_bias_derivative, q_p=_q3, qd_p=_q3)
paper_velocity_to_curvature = checked(_paper_velocity_to_curvature, q_p=_q3, qd_p=_q3)


def curvature_velocity_to_paper(q_c, qd_c) -> np.ndarray:
    """Inverse of :func:`paper_velocity_to_curvature`; needs ``kappa > 0``.

    Raises
    ------
    SingularConfigurationError
        where ``kappa`` is zero, or so small that ``kappa^2`` underflows (``psidot`` is
        undefined there).
    """
    (_, ux, uy), (ldot, uxd, uyd) = _q3("q_c", q_c), _q3("qd_c", qd_c)
    k2 = ux * ux + uy * uy
    if not k2 > 0.0:  # kappa = 0, or so small that kappa^2 underflows
        raise SingularConfigurationError(
            "curvature_velocity_to_paper: kappa = 0, psidot is undefined in the paper's "
            "(l, psi, kappa) coordinates; use coords='curvature'"
        )
    out = np.array([ldot, (ux * uyd - uy * uxd) / k2, (ux * uxd + uy * uyd) / np.sqrt(k2)])
    if not np.all(np.isfinite(out)):
        raise NonFiniteError(f"curvature_velocity_to_paper: the paper rates overflow at q_c = {show_vector(q_c, 9)}, "
                             f"qd_c = {show_vector(qd_c, 9)}")
    return out


def _paper_hessian_term(q_p: np.ndarray, grad_c: np.ndarray) -> np.ndarray:
    """``sum_i grad_c[i] d^2 q_c[i] / dq_p^2``: the chain-rule term of a Hessian."""
    _, psi, kappa = q_p
    c, s = np.cos(psi), np.sin(psi)
    gx, gy = grad_c[1], grad_c[2]
    H = np.zeros((3, 3))
    H[1, 1] = -kappa * (gx * c + gy * s)
    H[1, 2] = H[2, 1] = -gx * s + gy * c
    return H


# ---------------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True, eq=False)
class Segment(KeepsReadOnly):
    """A constant-curvature, extensible soft segment with three pressure chambers.

    Parameters
    ----------
    length : float
        Rest length ``l0`` (m), ``1e-5 <= l0 <= 100`` (:data:`qchain.checks.bounds.LENGTH`).
    radius : float
        Outer radius ``r_s`` (m), ``1e-6 <= r_s <= 10`` (:data:`qchain.checks.bounds.RADIUS`).
    mass : float
        Mass ``m`` (kg), ``1e-9 <= m <= 1e6`` (:data:`qchain.checks.bounds.MASS`), spread uniformly
        over every cross-section (the paper's density, eq. (5); docs/model.md section 3).
    chamber_area : float
        Cross-section area ``A_ch`` of each chamber (m^2), ``> 0``.
    chamber_radius : float
        Distance ``r_ch`` of the chamber centres from the axis (m), ``> 0``; the chamber must fit:
        ``r_ch + sqrt(A_ch / pi) <= r_s``.
    youngs_modulus : float
        ``E`` (Pa), ``1 <= E <= 1e12`` (:data:`qchain.checks.bounds.YOUNGS_MODULUS`);
        ``EI = E pi r_s^4 / 4``, ``EA = E pi r_s^2``.
    damping : float, optional
        Stiffness-proportional damping ``beta`` (s), ``0 <= beta <= 100``: ``D = beta K(q0)``,
        ``K(q0)`` the elastic stiffness at rest in curvature coordinates, mapped to ``coords``
        (docs/model.md section 9).
    coords : {"curvature", "paper"}
        Deformation coordinates ``q_e``; see docs/model.md section 1.
    actuation : {"volume", "paper"}
        Input matrix model: chamber-volume virtual work (default) or the paper's
        tip-plate forces (eq. (8); docs/model.md section 5).
    nodes : int, optional
        Gauss-Legendre nodes along the segment, ``1 <= nodes <= 100``
        (:data:`qchain.checks.bounds.NODES`); ``None`` gives :data:`DEFAULT_NODES`.
    stiffness_matrix : (3, 3) array, optional
        The paper's literal linear elasticity ``K_e`` in the segment's coordinates
        (``-K_e (q - q_0) - D qdot``, the text before eq. (4); docs/model.md section 9):
        ``U_el = 1/2 (q_e - rest_q_e)^T K_e (q_e - rest_q_e)`` replaces the material law.
    damping_matrix : (3, 3) array, optional
        The paper's literal ``D`` in the segment's coordinates, replacing ``beta K(q0)``:
        constant, symmetric, positive semi-definite (N s/m on ``l``, N m^3 s on the curvatures
        ``ux``, ``uy``, N m s between: ``D qdot`` is a generalised force, N on ``l`` and N m^2 on a
        curvature): e.g. a strain-rate law with its own axial and bending coefficients.
    drag_linear : float, optional
        ``c_1`` (N s/m^2), ``0 <= c_1 <= 1e4`` (:data:`qchain.checks.bounds.DRAG_LINEAR`), and
    drag_quadratic : float, optional
        ``c_2`` (kg/m^2), ``0 <= c_2 <= 1e5`` (:data:`qchain.checks.bounds.DRAG_QUADRATIC`), of
        the drag of a still medium on the backbone: a force per unit length
        ``f(s) = -(c_1 + c_2 |v(s)|) v(s)`` against each backbone point's velocity ``v(s)``
        (world frame, the base's motion included), isotropic; its generalised force
        ``-int_0^l J(s)^T (c_1 + c_2 |v|) v ds`` acts on this segment's and every parent's
        coordinates (docs/model.md section 9). Curvature coordinates only.
    rest_q_e : (3,) array, optional
        ``q_e0`` of the linear law; default the straight rest pose ``(l0, 0, 0)``.
    extensible : bool
        ``False`` holds the length at ``l0`` in a :class:`~qchain.Chain` (an ideal
        constraint): the stiffest, axial mode is dropped so integrators can take larger
        steps. The segment's own blocks keep all three coordinates.

    Every number is a real (a ``bool``, a string or a complex number raises ``TypeError``)
    inside the range above (else ``ValueError`` naming the parameter, the value and the
    bound). Every method validates ``q_e`` (shape, finiteness, the model's domain) and
    raises :class:`~qchain.errors.NonFiniteError` rather than return a result that is not
    finite (a configuration whose magnitudes overflow, ``q_e = (1e300, 0, 0)``).
    """

    length: float
    radius: float
    mass: float
    chamber_area: float
    chamber_radius: float
    youngs_modulus: float
    damping: float = 0.0
    coords: str = "curvature"
    actuation: str = "volume"
    nodes: int | None = None
    stiffness_matrix: np.ndarray | None = None
    damping_matrix: np.ndarray | None = None
    drag_linear: float = 0.0
    drag_quadratic: float = 0.0
    rest_q_e: np.ndarray | None = None
    extensible: bool = True
    # derived (set in __post_init__)
    node_count: int = field(init=False)
    bending_stiffness: float = field(init=False)
    axial_stiffness: float = field(init=False)
    alpha_nodes: np.ndarray = field(init=False, repr=False)
    alpha_weights: np.ndarray = field(init=False, repr=False)
    disk_inertia: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        s = object.__setattr__
        for name, rng in (("length", B.LENGTH), ("radius", B.RADIUS), ("mass", B.MASS),
                          ("chamber_area", B.CHAMBER_AREA), ("chamber_radius", B.CHAMBER_RADIUS),
                          ("youngs_modulus", B.YOUNGS_MODULUS), ("damping", B.DAMPING),
                          ("drag_linear", B.DRAG_LINEAR), ("drag_quadratic", B.DRAG_QUADRATIC)):
            s(self, name, rng.check(name, getattr(self, name)))
        outer = self.chamber_radius + np.sqrt(self.chamber_area / np.pi)
        if outer > self.radius:
            raise ValueError(
                f"chambers do not fit: chamber_radius + sqrt(chamber_area/pi) = {outer:.6g} m "
                f"must be <= radius = {self.radius:.6g} m"
            )
        if not isinstance(self.extensible, (bool, np.bool_)):
            raise TypeError(f"extensible must be True or False, got {self.extensible!r}")
        if not isinstance(self.coords, str) or self.coords not in COORDS:
            raise ValueError(f"coords must be one of {COORDS}, got {self.coords!r}")
        if self.coords != "curvature" and (self.drag_linear or self.drag_quadratic):
            raise ValueError(f"drag_linear = {self.drag_linear:g}, drag_quadratic = {self.drag_quadratic:g} need "
                             f"coords='curvature' (the drag pass works in curvature coordinates), got {self.coords!r}")
        if not isinstance(self.actuation, str) or self.actuation not in ACTUATIONS:
            raise ValueError(f"actuation must be one of {ACTUATIONS}, got {self.actuation!r}")
        n = DEFAULT_NODES if self.nodes is None else B.NODES.check("nodes", self.nodes)
        s(self, "node_count", int(n))
        for name in ("stiffness_matrix", "damping_matrix"):
            if getattr(self, name) is None:
                continue
            X = np.array(as_matrix(name, getattr(self, name), (3, 3)))  # a copy of its own
            if not np.allclose(X, X.T, rtol=1e-12, atol=0.0):
                raise ValueError(f"{name} must be symmetric")
            if name == "damping_matrix" and np.linalg.eigvalsh(X).min() < -1e-12 * max(1.0, np.abs(X).max()):
                raise ValueError("damping_matrix must be positive semi-definite")
            s(self, name, X)
        if self.rest_q_e is not None:  # a configuration of this segment: inside its domain
            s(self, "rest_q_e", self.check_configuration(self.rest_q_e, name="rest_q_e"))
        s(self, "bending_stiffness", self.youngs_modulus * np.pi * self.radius**4 / 4.0)
        s(self, "axial_stiffness", self.youngs_modulus * np.pi * self.radius**2)
        x, w = np.polynomial.legendre.leggauss(self.node_count)
        s(self, "alpha_nodes", 0.5 * (x + 1.0))
        s(self, "alpha_weights", 0.5 * w)
        s(self, "disk_inertia", disk_inertia(self.mass, self.radius))
        for name in ("alpha_nodes", "alpha_weights", "disk_inertia", "stiffness_matrix", "damping_matrix", "rest_q_e"):
            if getattr(self, name) is None:
                continue
            getattr(self, name).flags.writeable = False

    # ----------------------------------------------------------------- configurations

    def neutral(self) -> np.ndarray:
        """The straight rest pose ``(l0, 0, 0)`` in the segment's coordinates (3,)."""
        return np.array([self.length, 0.0, 0.0])

    def check_configuration(self, q_e, name: str = "q_e") -> np.ndarray:
        """Validate ``q_e`` (shape, finiteness, model domain); return it as an array.

        Raises
        ------
        ValueError
            wrong shape or non-finite entries.
        DomainError
            ``l <= 0``; ``|kappa| r_s >= 1`` (the inner fibre length vanishes and the
            density field diverges); ``kappa < 0`` in paper coordinates (docs/model.md
            sections 1 and 3).
        """
        q = np.array(as_vector(name, q_e, 3))  # the caller's array is never returned (nor kept)
        code = domain_violation(q[0], q[1], q[2], self.radius, self.coords == "paper")
        if code == 1:
            raise DomainError(f"{name}: length l = {q[0]:.6g} m must be > 0")
        if code == 2:
            raise DomainError(f"{name}: curvature kappa = {q[2]:.6g} 1/m must be >= 0 in paper coordinates")
        if code == 0 and self.coords == "paper" and not B.PSI.contains(q[1]):
            raise DomainError(f"{name}: bending plane angle psi = {q[1]:.6g} rad must be {B.PSI.text()} "
                              "(qchain.checks.bounds.PSI)")
        if code == 3:
            kappa = q[2] if self.coords == "paper" else float(np.hypot(q[1], q[2]))
            raise DomainError(
                f"{name}: |kappa| r_s = {abs(kappa) * self.radius:.6g} must be < 1 "
                f"(kappa = {kappa:.6g} 1/m, radius = {self.radius:.6g} m): the inner fibre length vanishes"
            )
        return q

    def to_curvature(self, q_e) -> np.ndarray:
        """The configuration in curvature coordinates ``(l, ux, uy)`` (3,)."""
        return self._curvature(q_e)[0]

    def from_curvature(self, q_c) -> np.ndarray:
        """A curvature-coordinate configuration in the segment's coordinates (3,)."""
        q = as_vector("q_c", q_c, 3)
        return _curvature_to_paper(q) if self.coords == "paper" else q.copy()

    def coordinate_jacobian(self, q_e) -> np.ndarray:
        """``d q_c / d q_e`` (3, 3): identity in curvature coordinates, :func:`paper_jacobian` else."""
        return self._curvature(q_e)[1]

    def _curvature(self, q_e, nonsingular: bool = False):
        """``(q_c, J)``: the configuration in curvature coordinates and ``J = dq_c/dq_e``.

        With ``nonsingular``, paper coordinates at bending angles below
        :data:`PAPER_SINGULAR_ANGLE` raise :class:`SingularConfigurationError`.
        """
        q = self.check_configuration(q_e)
        if self.coords == "curvature":
            return q, np.eye(3)
        if nonsingular and q[2] * q[0] < PAPER_SINGULAR_ANGLE:
            raise SingularConfigurationError(
                f"q_e: bending angle kappa*l = {q[2] * q[0]:.3e} rad is below {PAPER_SINGULAR_ANGLE:g} rad: "
                "the paper's (l, psi, kappa) coordinates are singular at kappa = 0 (psi is undefined "
                "and M_xi loses rank); use coords='curvature', which is regular there"
            )
        return _paper_to_curvature(q), _paper_jacobian(q)

    def _lift(self, J: np.ndarray) -> np.ndarray:
        """``T = blockdiag(I6, J)`` (9, 9)."""
        T = np.eye(9)
        T[6:, 6:] = J
        return T

    # ------------------------------------------------------------------- kinematics

    @_finite("slice placement")
    def slice_placement(self, q_e, alpha: float) -> pin.SE3:
        """Placement ``g(alpha) = exp6(alpha X(q_e))`` of slice ``alpha`` in the root frame: the
        paper's eq. (1) at ``s = alpha l`` (section III-C; docs/model.md section 2)."""
        a = as_real("alpha", alpha)
        if not 0.0 <= a <= 1.0:
            raise ValueError(f"alpha must be in [0, 1], got {alpha!r}")
        q_c = self.to_curvature(q_e)
        return pin.exp6(pin.Motion(a * q_c[0] * strain_twist(q_c)))

    def tip_placement(self, q_e) -> pin.SE3:
        """Placement of the tip frame (slice ``alpha = 1``) in the root frame: the paper's
        eq. (1a), (1b) (docs/model.md section 2)."""
        return self.slice_placement(q_e, 1.0)

    @_finite("backbone")
    def backbone(self, q_e, alpha) -> np.ndarray:
        """Backbone points ``p(alpha)`` in the root frame (m), shape ``(P, 3)`` for ``alpha`` (P,)
        (docs/model.md section 2)."""
        a = np.atleast_1d(as_real_array("alpha", alpha))
        if a.ndim != 1 or np.any((a < 0.0) | (a > 1.0)) or not np.all(np.isfinite(a)):
            raise ValueError("alpha must be a 1-D array of values in [0, 1]")
        q_c = self.to_curvature(q_e)
        return arc_nodes(a, q_c).p

    @_finite("centre of mass")
    def center_of_mass(self, q_e) -> np.ndarray:
        """Centre of mass ``r_cm = int_0^1 p(alpha) dalpha`` in the root frame (m), shape (3,);
        off the backbone when bent (the ``r_cm`` of eq. (6); docs/model.md section 3)."""
        q_c, _ = self._curvature(q_e)
        return self.alpha_weights @ arc_nodes(self.alpha_nodes, q_c).p

    @_finite("tip Jacobian")
    def tip_jacobian(self, q_e) -> np.ndarray:
        """Tip body twist per unit ``qdot_e``: ``S(1) J`` (6, 3), tip frame, ``[linear; angular]``
        (docs/model.md section 2)."""
        q_c, J = self._curvature(q_e)
        return arc_nodes(1.0, q_c).S[0] @ J

    # ------------------------------------------------------------------- dynamics

    def _mass_c(self, q_c: np.ndarray) -> np.ndarray:
        M = np.empty((9, 9))
        segment_mass(self.alpha_nodes, self.alpha_weights, self.mass, self.radius, q_c, M)
        return M

    def _newton_euler_c(self, q_c: np.ndarray, xi_c: np.ndarray, xid_c: np.ndarray) -> np.ndarray:
        Q = np.empty(9)
        segment_newton_euler(self.alpha_nodes, self.alpha_weights, self.mass, self.radius, q_c, xi_c, xid_c, Q)
        return Q

    @_finite("mass matrix M_xi")
    def mass_matrix(self, q_e) -> np.ndarray:
        """``M_xi(q_e)`` (9, 9), kg / kg m / kg m^2, in ``xi = (v, w, qdot_e)``.

        The paper's eq. (6) with its density field, eq. (5): ``int_0^1 Phi^T I_disk Phi dalpha``
        (:func:`qchain.model.slices.segment_mass`; docs/model.md sections 3 and 4). Its top-left 6x6
        block is the rigid composite inertia seen from the root,
        ``[[m I, -m [r_cm]], [m [r_cm], I(q_e)]]``. In paper coordinates ``T^T M_c T`` with
        ``T = blockdiag(I6, J)`` (docs/model.md section 1). ``1/2 xi^T M_xi xi`` is the kinetic
        energy, eq. (4).

        Raises
        ------
        SingularConfigurationError
            in paper coordinates at bending angles below :data:`PAPER_SINGULAR_ANGLE`.
        """
        q_c, J = self._curvature(q_e, nonsingular=True)
        T = self._lift(J)
        return T.T @ self._mass_c(q_c) @ T

    @_finite("Coriolis matrix C_xi")
    def coriolis_matrix(self, q_e, xi) -> np.ndarray:
        """``C_xi(q_e, xi)`` (9, 9) of eq. (9), with ``C_xi + C_xi^T = dM_xi/dt``.

        Per slice ``Phi^T (I_disk Phidot + [I_disk V]x*bar Phi)`` with the skew-symmetric
        ``[h]x*bar`` (``a x* h = [h]x*bar a``), so ``C_xi xi`` is the exact velocity-product
        force and the passivity identity holds exactly. ``Phidot = [-ad(S qdot) Ad(g)^-1,
        Sdot]``. In paper coordinates ``T^T C_c T + T^T M_c Tdot``. docs/model.md section 4;
        the paper's own ``C_xi`` (after eq. (9), from the Christoffel symbols of ``H``) is a
        different matrix with the same ``C_xi xi`` (docs/model.md section 7).
        """
        q_c, J = self._curvature(q_e, nonsingular=True)
        xi = as_vector("xi", xi, 9)
        T = self._lift(J)
        xi_c = T @ xi
        n = arc_nodes(self.alpha_nodes, q_c, xi_c[6:])
        N = self.node_count
        Phi = np.empty((N, 6, 9))
        Phi[:, :, :6] = n.Ad_inv
        Phi[:, :, 6:] = n.S
        Phidot = np.empty_like(Phi)
        Phidot[:, :, :6] = -ad_matrix(n.S @ xi_c[6:]) @ n.Ad_inv
        Phidot[:, :, 6:] = n.Sdot
        I = self.disk_inertia
        V = Phi @ xi_c
        inner = I @ Phidot + force_cross_bar(V @ I.T) @ Phi
        Cc = np.einsum("n,nai,naj->ij", self.alpha_weights, Phi, inner)
        if self.coords == "curvature":
            return Cc
        Td = np.zeros((9, 9))
        Td[6:, 6:] = _paper_jacobian_dot(self.check_configuration(q_e), xi[6:])
        return T.T @ Cc @ T + T.T @ self._mass_c(q_c) @ Td

    @_finite("velocity-product force C_xi xi")
    def velocity_product_force(self, q_e, xi) -> np.ndarray:
        """``C_xi(q_e, xi) xi`` (9,) without forming the matrix: the slice Newton-Euler
        integral (:func:`qchain.model.slices.segment_newton_euler`) at zero acceleration
        (docs/model.md section 4)."""
        q_c, J = self._curvature(q_e, nonsingular=True)
        xi = as_vector("xi", xi, 9)
        T = self._lift(J)
        xid_c = np.zeros(9)
        if self.coords == "paper":
            xid_c[6:] = _paper_jacobian_dot(self.check_configuration(q_e), xi[6:]) @ xi[6:]
        return T.T @ self._newton_euler_c(q_c, T @ xi, xid_c)

    @_finite("generalised gravity G")
    def generalized_gravity(self, q_e, gravity) -> np.ndarray:
        """``G(q_e)`` (9,): gradient of ``U = -int g . p dm``, gravity ``g`` (3,) m/s^2 in root coordinates.

        The ``g_xi`` of eq. (9). ``G[:3]`` is minus the weight and ``G[3:6]`` minus its moment
        about the root origin (root coordinates); ``G[6:]`` is ``dU/dq_e``. Computed as
        ``M_xi`` applied to a root acceleration ``(-g, 0)`` (the disks' centres are their slice
        origins; docs/model.md section 9).
        """
        g = as_vector("gravity", gravity, 3)
        q_c, J = self._curvature(q_e)
        xid_c = np.zeros(9)
        xid_c[:3] = -g
        return self._lift(J).T @ self._newton_euler_c(q_c, np.zeros(9), xid_c)

    @_finite("kinetic energy")
    def kinetic_energy(self, q_e, xi) -> float:
        """``T = 1/2 xi^T M_xi xi`` (J), the paper's eq. (4) (docs/model.md section 3)."""
        xi = as_vector("xi", xi, 9)
        return 0.5 * float(xi @ self.mass_matrix(q_e) @ xi)

    # ------------------------------------------------------------------- input matrix

    @_finite("input matrix B")
    def input_matrix(self, q_e) -> np.ndarray:
        """``B(q_e)`` (3, 3): generalised force on ``q_e`` per chamber pressure (N/Pa, N m/Pa).

        Column ``i`` belongs to chamber ``i`` (angle ``CHAMBER_ANGLES[i]``).
        ``actuation="volume"``: ``B[:, i] = A_ch d l_i / d q_e`` with the chamber fibre length
        ``l_i = l (1 - kappa r_ch cos(psi - phi_i))`` (virtual work of the chamber volume).
        ``actuation="paper"``: ``B[:, i] = A_ch J_ci^T R k``, the force ``p_i A_ch`` along the
        tip normal at the chamber's centre on the tip plate (the paper's eq. (8) and the
        display after it). The two share the ``l`` row; under equal pressures only the paper's
        bends a bent segment. docs/model.md section 5 gives both in closed form.
        """
        q_c, J = self._curvature(q_e)
        Bc = np.empty((3, 3))
        input_matrix_c(q_c, self.chamber_area, self.chamber_radius, self.actuation == "paper", Bc, np.empty(SCRATCH))
        return J.T @ Bc

    @_finite("pressure stiffness d(B p)/dq_e")
    def pressure_stiffness(self, q_e, p) -> np.ndarray:
        """``d(B(q_e) p)/d q_e`` (3, 3), exact, both actuation models
        (:func:`qchain.model.slices.pressure_jacobian_c`; ``B`` of docs/model.md section 5)."""
        p = as_vector("p", p, 3)
        q_c, J = self._curvature(q_e)
        paper_act = self.actuation == "paper"
        Kc = np.empty((3, 3))
        pressure_jacobian_c(q_c, p, self.chamber_area, self.chamber_radius, paper_act, Kc, np.empty(SCRATCH))
        if self.coords == "curvature":
            return Kc
        Bc = np.empty((3, 3))
        input_matrix_c(q_c, self.chamber_area, self.chamber_radius, paper_act, Bc, np.empty(SCRATCH))
        return J.T @ Kc @ J + _paper_hessian_term(self.check_configuration(q_e), Bc @ p)

    # ------------------------------------------------------------------- elasticity

    def _rest_damping_c(self) -> np.ndarray:
        D = np.empty((3, 3))
        rest_damping_c(self.length, self.bending_stiffness, self.axial_stiffness, self.damping, D)
        return D

    def _law_c(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        """``(D, K_e, q_e0, linear)``: the constant dissipation matrix (3, 3), the linear law's
        stiffness (3, 3) and rest configuration (3,) (zeros without it) and whether it is given,
        in curvature coordinates, as the compiled passes take them (``ChainArrays.D``, ``K``,
        ``q_rest``, ``linear_law``). In paper coordinates: the material law's ``beta K(q0)``
        (the literal matrices, in paper coordinates, stay with the Segment)."""
        if self.coords == "paper" or self.stiffness_matrix is None:
            D = self._rest_damping_c() if self.coords == "paper" else self.dissipation_matrix(self.neutral())
            return D, np.zeros((3, 3)), np.zeros(3), False
        return self.dissipation_matrix(self.neutral()), self.stiffness_matrix.copy(), self._rest().copy(), True

    def _rest(self) -> np.ndarray:
        return self.neutral() if self.rest_q_e is None else self.rest_q_e

    @_finite("elastic energy")
    def elastic_energy(self, q_e) -> float:
        """``U_el`` (J): ``1/2 EI (kappa l)^2 / l0 + 1/2 EA (l - l0)^2 / l0``, or the linear law
        (docs/model.md section 9)."""
        q = self.check_configuration(q_e)
        if self.stiffness_matrix is not None:
            dq = q - self._rest()
            return 0.5 * float(dq @ self.stiffness_matrix @ dq)
        l0 = self.length
        l = q[0]
        k2 = q[2] ** 2 if self.coords == "paper" else q[1] ** 2 + q[2] ** 2
        return 0.5 * self.bending_stiffness * k2 * l * l / l0 + 0.5 * self.axial_stiffness * (l - l0) ** 2 / l0

    def _elastic_grad_c(self, q_c: np.ndarray) -> np.ndarray:
        g = np.empty(3)
        elastic_gradient_c(q_c, self.length, self.bending_stiffness, self.axial_stiffness, g)
        return g

    @_finite("elastic force dU_el/dq_e")
    def elastic_force(self, q_e) -> np.ndarray:
        """``dU_el/dq_e`` (3,), the elastic term on the left of the equation of motion (the
        paper's ``K_xi (q - q0)`` of eq. (9); docs/model.md section 9)."""
        q = self.check_configuration(q_e)
        if self.stiffness_matrix is not None:
            return self.stiffness_matrix @ (q - self._rest())
        if self.coords == "paper":
            return _paper_jacobian(q).T @ self._elastic_grad_c(_paper_to_curvature(q))
        return self._elastic_grad_c(q)

    @_finite("elastic stiffness")
    def elastic_stiffness(self, q_e) -> np.ndarray:
        """``d^2 U_el / dq_e^2`` (3, 3), exact (docs/model.md section 9)."""
        q = self.check_configuration(q_e)
        if self.stiffness_matrix is not None:
            return self.stiffness_matrix.copy()
        q_c = _paper_to_curvature(q) if self.coords == "paper" else q
        Hc = np.empty((3, 3))
        elastic_hessian_c(q_c, self.length, self.bending_stiffness, self.axial_stiffness, Hc)
        if self.coords == "curvature":
            return Hc
        J = _paper_jacobian(q)
        return J.T @ Hc @ J + _paper_hessian_term(q, self._elastic_grad_c(q_c))

    @_finite("dissipation matrix D")
    def dissipation_matrix(self, q_e) -> np.ndarray:
        """Dissipation matrix ``D`` (3, 3) in the segment's coordinates (N s/m ...).

        ``damping_matrix`` if given; else ``beta K(q0)`` (``K`` the stiffness at rest:
        the linear ``K_e``, or the material law's in curvature coordinates mapped by
        ``J^T D J`` to paper coordinates). The paper's ``D`` of eq. (7) and (9)
        (docs/model.md section 9).
        """
        q = self.check_configuration(q_e)
        if self.damping_matrix is not None:
            return self.damping_matrix.copy()
        if self.stiffness_matrix is not None:
            return self.damping * self.stiffness_matrix
        Dc = self._rest_damping_c()
        if self.coords == "curvature":
            return Dc
        J = _paper_jacobian(q)
        return J.T @ Dc @ J

    @_finite("damping force D qdot_e")
    def damping_force(self, q_e, qdot_e) -> np.ndarray:
        """``D qdot_e`` (3,), the dissipative term on the left of the equation of motion
        (docs/model.md section 9)."""
        qd = as_vector("qdot_e", qdot_e, 3)
        return self.dissipation_matrix(q_e) @ qd


def nodes_for_tolerance(segment: Segment, theta_max: float, tol: float, reference_nodes: int = 24) -> int:
    """Smallest Gauss-Legendre node count whose ``M_xi`` is within ``tol`` (relative, Frobenius)
    of a ``reference_nodes`` one at bending angle ``theta_max`` (rad) and rest length.

    The quadrature error grows with the bending angle (docs/model.md section 4: the node
    count is a fidelity knob), so a scene that bends less needs fewer nodes. ``theta_max``
    is a finite angle >= 0 (bends past ``l0 / r_s`` are taken at ``|kappa| r_s = 0.999``),
    ``0 < tol < 1``, ``1 <= reference_nodes <= 100``.
    """
    if not isinstance(segment, Segment):
        raise TypeError(f"segment must be a qchain.Segment, got {type(segment).__name__}")
    theta = B.Range(0.0, None, "rad").check("theta_max", theta_max)  # any bend: kappa is capped below
    tol = B.NODE_TOLERANCE.check("tol", tol)
    reference_nodes = B.NODES.check("reference_nodes", reference_nodes)
    import dataclasses

    rest = segment.rest_q_e  # the M_xi compared here does not use it, but it must be valid in curvature coordinates
    if rest is not None and segment.coords == "paper":
        rest = paper_to_curvature(rest)
    base = dataclasses.replace(segment, coords="curvature", nodes=reference_nodes, rest_q_e=rest)
    kappa = min(theta / base.length, 0.999 / base.radius)
    q = np.array([base.length, kappa * np.cos(0.3), kappa * np.sin(0.3)])
    ref = base.mass_matrix(q)
    for n in range(1, reference_nodes):
        M = dataclasses.replace(base, nodes=n).mass_matrix(q)
        if np.linalg.norm(M - ref) <= tol * np.linalg.norm(ref):
            return n
    return reference_nodes
