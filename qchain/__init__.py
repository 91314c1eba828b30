"""qchain: quasi-Lagrangian dynamics of soft continuum arms (Olguin-Diaz et al.)."""

from .errors import DomainError, QchainError, SingularConfigurationError
from .chain import Chain
from .lagrangian import LagrangianChain
from .scene import Scene, SceneError, load_scene
from .segment import Segment

__version__ = "0.1.0"

__all__ = ["Chain", "LagrangianChain", "Segment", "Scene", "SceneError", "load_scene", "QchainError", "DomainError", "SingularConfigurationError", "__version__"]
