"""Contact and external loads: obstacles (:mod:`~qchain.contact.shapes`), their signed
distances (:mod:`~qchain.contact.distance`), the contact law and loads
(:mod:`~qchain.contact.environment`) and the compiled passes that turn them into generalised
forces (:mod:`~qchain.contact.forces`). docs/contact.md is the user's guide."""

from .. import lazy_exports

_EXPORTS = {
    "HalfSpace": "shapes", "Sphere": "shapes", "Capsule": "shapes", "Cylinder": "shapes", "Box": "shapes", "Motion": "shapes",
    "ContactLaw": "environment", "PointLoad": "environment", "Environment": "environment",
    "Contacts": "environment", "hunt_crossley_damping": "environment", "contact_nodes": "environment",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
