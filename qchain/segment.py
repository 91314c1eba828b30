"""One soft segment (public face): :class:`Segment`, its coordinate maps between the paper's
``(l, psi, kappa)`` and the curvature coordinates ``(l, ux, uy)``, and the node rule.
The code is :mod:`qchain.model.segment`'s."""

from .model.segment import (
    CHAMBER_ANGLES, DEFAULT_NODES, PAPER_SINGULAR_ANGLE, Segment, curvature_to_paper, curvature_velocity_to_paper,
    nodes_for_tolerance, paper_bias_derivative, paper_jacobian, paper_jacobian_derivative, paper_jacobian_dot,
    paper_to_curvature, paper_velocity_to_curvature)

__all__ = ["Segment", "nodes_for_tolerance", "CHAMBER_ANGLES", "DEFAULT_NODES", "PAPER_SINGULAR_ANGLE",
           "paper_to_curvature", "curvature_to_paper", "paper_jacobian", "paper_jacobian_dot",
           "paper_jacobian_derivative", "paper_bias_derivative", "paper_velocity_to_curvature",
           "curvature_velocity_to_paper"]
