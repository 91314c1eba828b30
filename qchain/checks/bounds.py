"""The ranges of qchain's physical parameters and run settings, declared once.

A :class:`Range` is what a number may be (bounds, open or closed, unit, integer or not). The
ranges are those the model is checked at (finite results over the whole box,
``tests/test_segment.py``): far wider than any soft arm needs, small enough that no product
of them overflows. What a whole run may cost is a budget, not a range: :mod:`qchain.sim.budget`."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .convert import as_real, describe_value

__all__ = ["Range", "LENGTH", "RADIUS", "MASS", "CHAMBER_AREA", "CHAMBER_RADIUS", "YOUNGS_MODULUS", "DAMPING", "DRAG_LINEAR",
           "DRAG_QUADRATIC", "DAMPING_MATRIX", "NODES", "TENDON_RADIUS", "TENDON_PITCH", "TENSION",
           "GRAVITY", "POSITION", "ANGLE", "PSI", "VELOCITY", "ANGULAR_VELOCITY", "RATE", "DIRECTION", "AMPLITUDE",
           "FREQUENCY", "PRESSURE", "PRESSURE_AMPLITUDE", "TENSION_AMPLITUDE", "TIME", "DURATION", "STEP", "RTOL", "ATOL", "SAMPLE_RATE",
           "NODE_TOLERANCE", "MAX_BEND", "LENGTH_TOLERANCE", "WALL_LIMIT", "VACUUM_GAUGE", "SEGMENT_COUNT", "WORKERS", "RETRIES",
           "EXTENT", "CONTACT_STIFFNESS", "CONTACT_EXPONENT", "CONTACT_DAMPING", "FRICTION", "SLIP_VELOCITY",
           "RESTITUTION", "IMPACT_SPEED", "CONTACT_NODES", "HORIZON", "TIP_WEIGHT", "PRESSURE_WEIGHT", "TENSION_WEIGHT",
           "ITERATIONS"]


def _num(x: float) -> str:
    if x == math.inf:
        return "inf"
    if x == -math.inf:
        return "-inf"
    return f"{x:g}"


@dataclass(frozen=True)
class Range:
    """An interval of real numbers (or integers) with a unit.

    Parameters
    ----------
    low, high : float or None
        Bounds; ``None`` for none.
    unit : str
        SI unit of the quantity ("" for a pure number).
    low_open, high_open : bool
        Whether the bound itself is excluded (``> low`` instead of ``>= low``).
    integer : bool
        Whole numbers only (Python ``int`` or numpy integers; never ``bool``).
    """

    low: float | None = None
    high: float | None = None
    unit: str = ""
    low_open: bool = False
    high_open: bool = False
    integer: bool = False

    def _bounds(self) -> str:
        """``"> 0 and <= 100"``, or ``""`` without bounds."""
        parts = []
        if self.low is not None:
            parts.append(f"{'>' if self.low_open else '>='} {_num(self.low)}")
        if self.high is not None:
            parts.append(f"{'<' if self.high_open else '<='} {_num(self.high)}")
        return " and ".join(parts)

    def text(self) -> str:
        """The bounds as words: ``"> 0 and <= 100 m"``."""
        return f"{self._bounds() or 'any value'} {self.unit}".rstrip()

    def what(self) -> str:
        """``"a number > 0 and <= 100 (m)"`` or ``"an integer >= 1 and <= 100"``."""
        bound = f" {self._bounds()}" if self._bounds() else ""
        return f"{'an integer' if self.integer else 'a number'}{bound}{f' ({self.unit})' if self.unit else ''}"

    def contains(self, x: float) -> bool:
        """Whether the finite number ``x`` is inside (the type is not checked)."""
        if self.low is not None and (x <= self.low if self.low_open else x < self.low):
            return False
        if self.high is not None and (x >= self.high if self.high_open else x > self.high):
            return False
        return True

    def outside(self, arr: np.ndarray) -> np.ndarray:
        """Boolean mask of the entries of ``arr`` outside the range (NaN counts as outside)."""
        a = np.asarray(arr, dtype=float)
        bad = ~np.isfinite(a)
        if self.low is not None:
            bad |= (a <= self.low) if self.low_open else (a < self.low)
        if self.high is not None:
            bad |= (a >= self.high) if self.high_open else (a > self.high)
        return bad

    def shown(self, value) -> str:
        """``value`` as an error shows it: ``%g`` (``inf`` and ``-inf`` spelled), or all its
        digits (``repr``) where ``%g`` would read as a bound it is outside
        (``1000000000.0000001`` is not ``1e+09``)."""
        x = float(value)
        text = _num(x)
        near = any(b is not None and text == _num(b) and x != b for b in (self.low, self.high))
        return repr(x) if near else text

    def check(self, name: str, value):
        """``value`` as a ``float`` (``int`` for an integer range) inside the range.

        Raises
        ------
        TypeError
            ``value`` is not a real number (a bool, a string, None, complex), or not an
            integer where one is needed; the message names ``name``.
        ValueError
            non-finite or outside the range; the message names ``name``, the value and the bound.
        """
        if self.integer:
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
                raise TypeError(f"{name} must be {self.what()}, got {describe_value(value)}")
            x = int(value)
        else:
            x = as_real(name, value)
        if not self.contains(x):
            u = f" {self.unit}" if self.unit else ""
            raise ValueError(f"{name} must be {'an integer ' if self.integer else ''}{self.text()}, got "
                             f"{self.shown(x) if not self.integer else x}{u}")
        return x

    def check_array(self, name: str, arr: np.ndarray) -> np.ndarray:
        """Raise ``ValueError`` naming the first entry of the (real, finite) ``arr`` outside the range."""
        bad = self.outside(arr)
        if bad.any():
            k = int(np.flatnonzero(bad.ravel())[0])
            u = f" {self.unit}" if self.unit else ""
            raise ValueError(f"{name}[{k}] must be {self.text()}, got {self.shown(np.ravel(arr)[k])}{u}")
        return arr


#: Lowest gauge pressure a chamber can hold (Pa): a vacuum.
VACUUM_GAUGE = -101325.0

# -- a segment (tests/test_segment.py checks finite dynamics over the whole box)
LENGTH = Range(1e-5, 1e2, "m")  #: rest length l0
RADIUS = Range(1e-6, 10.0, "m")  #: outer radius r_s
MASS = Range(1e-9, 1e6, "kg")  #: segment mass
CHAMBER_AREA = Range(0.0, 1e3, "m^2", low_open=True)  #: each chamber's cross-section (it must also fit)
CHAMBER_RADIUS = Range(0.0, 10.0, "m", low_open=True)  #: distance of the chamber centres from the axis
YOUNGS_MODULUS = Range(1.0, 1e12, "Pa")  #: from a gel to steel and beyond
DAMPING = Range(0.0, 1e2, "s")  #: beta of D = beta K(q0)
#: c_1 of the drag force per unit length ``-(c_1 + c_2 |v|) v`` (a viscous medium: Stokes-like)
DRAG_LINEAR = Range(0.0, 1e4, "N s/m^2")
#: c_2 of the same (``1/2 rho C_d 2 r_s`` in a fluid of density rho: water on a 4 cm arm about 24)
DRAG_QUADRATIC = Range(0.0, 1e5, "kg/m^2")
#: An entry of a segment's damping matrix ``D`` (curvature coordinates ``(l, ux, uy)``: N s/m on
#: ``l``, N m^3 s on ``ux``, ``uy``, N m s between): a guard against absurd magnitudes whose
#: products overflow, not a physical limit.
DAMPING_MATRIX = Range(-1e15, 1e15, "N s/m, N m s, N m^3 s")
NODES = Range(1, 100, integer=True)  #: Gauss-Legendre nodes along a segment (the node count converges by ~24)

# -- a tendon (qchain.model.tendon; docs/tendons.md)
TENDON_RADIUS = Range(0.0, 10.0, "m", low_open=True)  #: offset of a tendon from the backbone
TENDON_PITCH = Range(1e-4, 1e6, "m")  #: |pitch| of a helical tendon: rest length per turn
TENSION = Range(0.0, 1e9, "N")  #: a tendon's tension: a tendon pulls, it cannot push
TENSION_AMPLITUDE = Range(-1e9, 1e9, "N")  #: a sine's amplitude of tension (its sign is a phase of pi)

# -- the world, the base and the initial state
GRAVITY = Range(-1e4, 1e4, "m/s^2")  #: each component
POSITION = Range(-1e6, 1e6, "m")  #: each component of a base position
ANGLE = Range(-1e3, 1e3, "rad")  #: roll-pitch-yaw angles, phases
PSI = Range(-1e3, 1e3, "rad")  #: the bending plane angle psi of paper coordinates (l, psi, kappa)
VELOCITY = Range(-1e3, 1e3, "m/s")  #: each component of a base velocity
ANGULAR_VELOCITY = Range(-1e4, 1e4, "rad/s")  #: each component of a base angular velocity
RATE = Range(-1e6, 1e6, "m/s or 1/(m s)")  #: initial rates of the segment coordinates
DIRECTION = Range(-1e6, 1e6)  #: components of an axis (normalised after the check)
AMPLITUDE = Range(-1e3, 1e3, "m or rad")  #: a base motion's amplitude
FREQUENCY = Range(0.0, 1e4, "Hz")  #: sine inputs and base motions
PRESSURE = Range(VACUUM_GAUGE, 1e9, "Pa")  #: gauge chamber pressures: a vacuum to 1 GPa
PRESSURE_AMPLITUDE = Range(-1e9, 1e9, "Pa")  #: a sine's amplitude (its sign is a phase of pi)

# -- time and the run
TIME = Range(-1e12, 1e12, "s")  #: times of schedules


def check_time(t, name: str = "t") -> float:
    """A time ``t`` (s): a real number within :data:`TIME` (a float inside it passes at once:
    a schedule or a chain's method checks every call)."""
    return t if type(t) is float and -1e12 <= t <= 1e12 else TIME.check(name, t)
DURATION = Range(1e-12, 1e12, "s")  #: a run's length (its cost is bounded by the budget; from 1e-12 s, which
#: the solver can always step: qchain.sim.simulation needs 64 float64 epsilons of max(1 s, |t0|, |t1|))
STEP = Range(0.0, 1e12, "s", low_open=True)  #: dt, max_step, first_step
RTOL = Range(1e-15, 1.0)  #: relative tolerance of the adaptive methods
ATOL = Range(1e-20, 1e3)  #: absolute tolerance (units of each state entry)
SAMPLE_RATE = Range(0.0, 1e9, "Hz", low_open=True)  #: output samples a second
NODE_TOLERANCE = Range(0.0, 1.0, low_open=True, high_open=True)  #: relative M_xi accuracy
MAX_BEND = Range(0.0, 1e3, "rad")  #: the bend the node count is sized for
LENGTH_TOLERANCE = Range(0.0, 1e3, "m", low_open=True)  #: tip change the inextensible reduction may make
WALL_LIMIT = Range(0.0, 1e9, "s", low_open=True)  #: wall-clock limit of a run

SEGMENT_COUNT = Range(1, 10**6, integer=True)  #: segments of a chain (a workspace's n)
WORKERS = Range(1, 1024, integer=True)  #: worker processes of a batch (each one a Python process with the engine)
RETRIES = Range(0, 100, integer=True)  #: runs of a rollout again after its worker process died

#: Each entry of the generalised forces ``tau`` (N, N m, or N m^2 for a curvature
#: coordinate): wider than what 1 GPa in the largest chamber of :mod:`this module` makes
#: (3e13), small enough that no product with the model's quantities overflows.
FORCE = Range(-1e15, 1e15)

# -- environments (qchain.envs): a reaching task's settings
REWARD_WEIGHT = Range(0.0, 1e6, "m")  #: weight of the pressure effort in a reward measured in metres
PENALTY = Range(0.0, 1e9, "m")  #: what leaving the model's domain costs, in the reward's metres
ENV_COUNT = Range(1, 4096, integer=True)  #: sub-environments of a vectorised environment

# -- control (qchain.control): model-predictive control's settings
HORIZON = Range(1, 10_000, integer=True)  #: control intervals an MPC plans over
TIP_WEIGHT = Range(0.0, 1e15, "1/m^2")  #: weight of the squared tip error in an MPC cost
PRESSURE_WEIGHT = Range(0.0, 1e3, "1/Pa^2")  #: weight of the squared pressures in an MPC cost
TENSION_WEIGHT = Range(0.0, 1e9, "1/N^2")  #: weight of the squared tendon tensions in an MPC cost
ITERATIONS = Range(1, 10_000, integer=True)  #: iterations of an optimiser

# -- contact (qchain.contact): obstacles and the contact law
EXTENT = Range(0.0, 1e4, "m", low_open=True)  #: an obstacle's radius, half-extent or length
CONTACT_STIFFNESS = Range(0.0, 1e15, "N/m^(1+exponent)", low_open=True)  #: normal force per metre of tube
CONTACT_EXPONENT = Range(1.0, 3.0)  #: the power of the penetration in the normal force
CONTACT_DAMPING = Range(0.0, 1e4, "s/m")  #: Hunt-Crossley damping c of f = k d^e (1 + c d')
FRICTION = Range(0.0, 10.0)  #: a Coulomb coefficient (static or dynamic)
SLIP_VELOCITY = Range(0.0, 1e2, "m/s", low_open=True)  #: a friction regularisation or Stribeck speed
RESTITUTION = Range(0.0, 1.0, low_open=True)  #: a coefficient of restitution
IMPACT_SPEED = Range(0.0, 1e3, "m/s", low_open=True)  #: the impact speed a restitution is set at
CONTACT_NODES = Range(1, 64, integer=True)  #: contact points along a segment
