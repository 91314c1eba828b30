"""The model's per-node and per-segment arrays, as one named structure the compiled passes take
first: :class:`ChainArrays`, a ``typing.NamedTuple`` (numba compiles it with attribute access,
at no run-time cost). Declared once: :class:`qchain.Chain` builds it, every pass of
:mod:`qchain.algorithms` reads it, and the engine's model (``qchain.sim.engine.system``) holds it."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["ChainArrays"]


class ChainArrays(NamedTuple):
    """A chain's model arrays (never written by a pass); ``N`` nodes over all segments, ``n``
    segments.

    Attributes
    ----------
    alpha : (N,) float
        The nodes' arc parameters in [0, 1].
    w : (N,) float
        Their quadrature weights (sum 1 a segment).
    offs : (n + 1,) int64
        Segment ``j``'s nodes are ``offs[j]:offs[j + 1]``.
    mass, radius, l0 : (n,) float
        Segment mass (kg), radius (m), rest length (m).
    EI, EA : (n,) float
        Bending (N m^2) and axial (N) stiffness.
    beta : (n,) float
        Stiffness-proportional damping (s).
    A_ch, r_ch : (n,) float
        Chamber area (m^2) and the chambers' distance from the axis (m).
    paper_act : (n,) bool
        The paper's actuation law.
    locked : (n, 3) bool
        Coordinates held still (``planar``, inextensible segments).
    """

    alpha: np.ndarray
    w: np.ndarray
    offs: np.ndarray
    mass: np.ndarray
    radius: np.ndarray
    l0: np.ndarray
    EI: np.ndarray
    EA: np.ndarray
    beta: np.ndarray
    A_ch: np.ndarray
    r_ch: np.ndarray
    paper_act: np.ndarray
    locked: np.ndarray
