"""An n-segment soft arm (public face): :class:`Chain` (the model and its methods),
:class:`Data` (per-evaluation workspaces), :class:`Frames`, :class:`LagrangianChain` (the
Lagrangian form with a minimal base attitude) and :func:`equilibrium`. The code is
:mod:`qchain.arm`'s."""

from .arm.chain import BASES, Chain
from .arm.data import Data
from .arm.kinematics import Frames
from .arm.lagrangian import LagrangianChain
from .arm.statics import EquilibriumResult, equilibrium

__all__ = ["Chain", "Data", "Frames", "BASES", "LagrangianChain", "equilibrium", "EquilibriumResult"]
