"""One segment's model, the paper's per-segment math (no I/O, no chain): spatial algebra
(:mod:`~qchain.model.spatial`), a slice's kinematics along the arc and its derivatives
(:mod:`~qchain.model.arc`), the slice integrals that give
``M_xi``, the Newton-Euler bias, the input matrix ``B`` and the elastic law
(:mod:`~qchain.model.slices`), and :class:`~qchain.model.segment.Segment` with its coordinate
maps (:mod:`~qchain.model.segment`)."""
