"""qchain: quasi-Lagrangian dynamics of soft continuum arms (Olguin-Diaz et al.)."""

from .errors import DomainError, QchainError, SingularConfigurationError
from .chain import Chain
from .segment import Segment

__version__ = "0.1.0"

__all__ = ["Chain", "Segment", "QchainError", "DomainError", "SingularConfigurationError", "__version__"]
