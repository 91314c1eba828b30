"""The recursive passes over a chain's segment blocks (public face), in Pinocchio's names:
:func:`rnea`, :func:`crba`, :func:`aba`, :func:`frames`, :func:`tip_maps`,
:func:`internal_forces`, and their derivative passes :func:`rnea_derivatives`,
:func:`aba_derivatives` and :func:`internal_forces_derivatives`. They work on plain arrays
(layouts in :mod:`qchain.algorithms.recursive`); :class:`qchain.Chain`'s methods call them.
The code is :mod:`qchain.algorithms`'s (the derivatives split by algorithm as Pinocchio's:
:mod:`~qchain.algorithms.rnea_derivatives`, :mod:`~qchain.algorithms.aba_derivatives`)."""

from .algorithms.aba_derivatives import aba_derivatives
from .algorithms.recursive import aba, crba, frames, internal_forces, rnea, tip_maps
from .algorithms.rnea_derivatives import internal_forces_derivatives, rnea_derivatives

__all__ = ["rnea", "crba", "aba", "frames", "tip_maps", "internal_forces", "rnea_derivatives", "aba_derivatives",
           "internal_forces_derivatives"]
