"""The automatic inextensible reduction of a scene: whether locking every segment's length
``l`` at ``l0`` may apply (:meth:`StretchEstimate.inextensible_obstacle`), and an estimate of
what it changes at the tip (:meth:`StretchEstimate.estimate_stretch`); "Model reduction" in
the docstring of :mod:`qchain.scene.scene` says what the estimate covers and what it does not.
:class:`~qchain.scene.model.ModelBuilder` inherits these methods."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, replace

import numpy as np
import scipy.linalg

from ..arm.chain import Chain
from ..checks.text import show_vector
from ..model.segment import DEFAULT_NODES

__all__ = ["StretchEstimate", "Stretch", "STRETCH_MARGIN", "DRIFT_RATE", "AXIAL_SEPARATION",
           "DEFAULT_LENGTH_TOLERANCE"]

#: Overshoot of an undamped axial mode under a load applied at once (step response): the
#: dynamic stretch is taken as this times the static one.
STRETCH_MARGIN = 2.0
#: Relative shift of the slowest bending frequency per unit (dynamic) axial strain. At fixed
#: mass and ``EI`` a segment stretched to ``l0 (1 + e)`` bends at ``omega ~ l^(-3/2)``: 1.5;
#: a swinging arm's own tension shifts it further (on the cantilever release the phase drift
#: between the two models is 3.6 static strains, 1.8 x ``STRETCH_MARGIN``): 2 covers it.
DRIFT_RATE = 2.0
#: The lowest axial mode must lie at least this factor above the fastest sine input (pressure
#: or base motion): nearer, the inputs drive the axial mode near resonance.
AXIAL_SEPARATION = 3.0
#: ``model.length_tolerance`` when the file gives none (m at the tip).
DEFAULT_LENGTH_TOLERANCE = 1e-4


@dataclass(frozen=True)
class Stretch:
    """The estimated tip change of locking ``l`` (:meth:`StretchEstimate.estimate_stretch`).

    Attributes
    ----------
    tip : float, m
        The estimate: ``shape + drift``.
    shape : float, m
        ``STRETCH_MARGIN`` x the largest tip distance between the extensible and the locked
        static shapes.
    drift : float, m
        Phase drift of the slowest bending mode over the run,
        ``A omega_1 T DRIFT_RATE STRETCH_MARGIN e_max``, at most ``2 A``.
    strain : float
        ``e_max``: the largest static axial strain ``|l - l0| / l0`` of any segment.
    excursion : float, m
        ``A``: the largest tip distance between the start and a static shape, plus the arm's
        length times the bend the initial kinetic energy could store.
    bend_frequency, axial_frequency : float, Hz
        The slowest mode, and the slowest axial mode, of the arm at rest (base held still,
        no gravity, no pressure).
    """

    tip: float
    shape: float
    drift: float
    strain: float
    excursion: float
    bend_frequency: float
    axial_frequency: float


def _common_mode_varies(P: np.ndarray, n: int) -> list[int]:
    """Segments whose mean chamber pressure is not the same at all rows of ``P`` (K, 3 n)."""
    mean = P.reshape(len(P), n, 3).mean(axis=2)  # (K, n)
    scale = max(1.0, float(np.abs(P).max()))
    return [j for j in range(n) if np.ptp(mean[:, j]) > 1e-9 * scale]


def _ranges(idx) -> str:
    """``[0, 1, 2, 5]`` -> ``"segments 0-2, 5"``."""
    idx = sorted(idx)
    # runs of consecutive indices: constant index - position within each
    runs = [[i for _, i in g] for _, g in itertools.groupby(enumerate(idx), lambda ki: ki[1] - ki[0])]
    parts = [f"{r[0]}" if len(r) == 1 else f"{r[0]}-{r[-1]}" for r in runs]
    word = "segment" if len(idx) == 1 else "segments"
    return f"{word} {', '.join(parts)}"


class StretchEstimate:
    """The inextensible reduction's checks and estimate (a base class of
    :class:`~qchain.scene.model.ModelBuilder`; see the module docstring)."""

    def inextensible_obstacle(self, controlled: bool = False) -> str | None:
        """Why ``l`` may not be locked automatically whatever the estimate says, or None."""
        if controlled:
            return "the pressures come from a controller (their common mode, which stretches the arm, is unknown)"
        free = [j for j, s in enumerate(self.segments) if s.extensible]
        bad = [j for j in free if self.q_e0[j, 0] != self.segments[j].length or self.v_e0[j, 0] != 0.0]
        if bad:
            return f"{_ranges(bad)}: initial l differs from l0 or its rate is not 0"
        if self.tendons:
            return "tendons: their tensions shorten the arm (not estimated)"
        coupled = [j for j in free if self.segments[j].axial_damping_coupling]
        if coupled:  # a bending rate would load l: a dynamic stretch the static estimate cannot see
            return f"{_ranges(coupled)}: damping_matrix couples l to ux or uy (not estimated)"
        drag = [j for j, s in enumerate(self.segments) if s.drag_linear or s.drag_quadratic]  # loads every parent
        if drag:
            return f"{_ranges(drag)}: the medium's drag loads the axial mode (not estimated)"
        env = self.surroundings.environment
        if env is not None and env.obstacles:
            return "obstacles: contact impacts load the axial mode (not estimated)"
        if self.pressure is not None:
            P = np.array([self.pressure(t) for t in self._pressure_times()])
            varies = _common_mode_varies(P, self.n)
            if varies:
                return (f"the pressures actuate elongation: the mean chamber pressure of {_ranges(varies)} changes "
                        "during the run (the axial mode is the motion)")
        return None

    def axial_frequencies(self) -> tuple[float, float]:
        """The slowest mode and the slowest axial mode of the arm at rest (Hz): base held
        still, no gravity, no pressure, every coordinate free. At the straight rest shape the
        lengths do not couple to the bends, so the axial modes are those of the ``l`` block."""
        ch = Chain(_curvature_copies(self.segments), base="fixed", gravity=np.zeros(3), payload=self.payload)
        q = ch.neutral()
        M, K = ch.mass_matrix(q), ch.elastic_stiffness(q)
        w2 = scipy.linalg.eigh(K, M, eigvals_only=True)
        ll = np.arange(0, ch.nv, 3)
        w2_ax = scipy.linalg.eigh(K[np.ix_(ll, ll)], M[np.ix_(ll, ll)], eigvals_only=True)
        return math.sqrt(max(w2[0], 0.0)) / (2 * math.pi), math.sqrt(w2_ax[0]) / (2 * math.pi)

    def _start_in_curvature(self) -> tuple[np.ndarray, np.ndarray]:
        """The initial ``q_e`` and rates of every segment in curvature coordinates, (3 n,) each."""
        q, v = [], []
        for spec, qe, ve in zip(self.segments, self.q_e0, self.v_e0):
            seg = spec.segment(nodes=1)
            q.append(seg.to_curvature(qe))
            v.append(seg.coordinate_jacobian(qe) @ ve)
        return np.concatenate(q), np.concatenate(v)

    def estimate_stretch(self, planar: bool = False) -> Stretch | str:
        """Estimate what locking every segment's ``l`` at ``l0`` changes at the tip over the
        run (a :class:`Stretch`), or why it cannot be estimated (str).

        The static shapes are those of :meth:`estimate_bend` (the same base conditions and
        peak pressures, point loads included), solved twice: every segment extensible and
        every one locked. See "Model reduction" in :mod:`qchain.scene.scene` for what the
        estimate covers.
        """
        from ..arm.statics import equilibrium

        segs, locked = _curvature_copies(self.segments), _curvature_copies(self.segments, extensible=False)
        q_start, v_start = self._start_in_curvature()
        env = self.surroundings.environment  # point loads only (obstacles refuse the reduction before)
        l0 = np.array([s.length for s in self.segments])
        shape = strain = excursion = 0.0
        for placement, g in self._static_conditions():
            full = Chain(segs, base="fixed", gravity=g, base_placement=placement, planar=planar, payload=self.payload)
            lock = Chain(locked, base="fixed", gravity=g, base_placement=placement, planar=planar,
                         payload=self.payload)
            start = full.tip_placement(q_start).translation
            guesses = [None, None]
            for p in self._pressure_candidates():
                tips = []
                for k, ch in enumerate((full, lock)):
                    res = equilibrium(ch, p, q0=guesses[k], env=env)
                    if not res.success and guesses[k] is not None:
                        res = equilibrium(ch, p, env=env)
                    if not res.success:
                        return f"equilibrium failed at p = {show_vector(p)} Pa ({res.message})"
                    guesses[k] = res.q
                    tips.append(ch.tip_placement(res.q).translation)
                l = guesses[0].reshape(self.n, 3)[:, 0]
                strain = max(strain, float(np.max(np.abs(l - l0) / l0)))
                shape = max(shape, float(np.linalg.norm(tips[0] - tips[1])))
                excursion = max(excursion, float(np.linalg.norm(tips[0] - start)))
        # the initial kinetic energy of the deformation rates, stored as bend over the whole arm
        ch0 = Chain(segs, base="fixed", gravity=np.zeros(3), payload=self.payload)
        T0 = ch0.kinetic_energy(q_start, v_start)
        EI = np.array([s.bending_stiffness for s in segs])
        excursion += float(np.sqrt(2.0 * T0 * l0 / EI).max() * l0.sum())
        f_bend, f_axial = self.axial_frequencies()
        e = STRETCH_MARGIN * strain
        drift = min(2.0 * excursion, excursion * 2 * math.pi * f_bend * self.duration * DRIFT_RATE * e)
        shape *= STRETCH_MARGIN
        return Stretch(tip=shape + drift, shape=shape, drift=drift, strain=strain, excursion=excursion,
                       bend_frequency=f_bend, axial_frequency=f_axial)


def _curvature_copies(specs, **change) -> list:
    """The segments of ``specs`` in curvature coordinates (regular where the paper's are
    singular, at the straight shape), with ``DEFAULT_NODES`` nodes and ``change`` applied."""
    return [replace(s, coords="curvature", **change).segment(nodes=DEFAULT_NODES) for s in specs]
