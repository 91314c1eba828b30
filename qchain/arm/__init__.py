"""The arm: :class:`~qchain.arm.chain.Chain`, the model of an n-segment arm with its
user-facing methods (each checks its input and calls one algorithm of :mod:`qchain.algorithms`),
its per-evaluation workspaces (:mod:`~qchain.arm.data`), world kinematics
(:mod:`~qchain.arm.kinematics`), input checks (:mod:`~qchain.arm.checks`), the derivatives of
the dynamics in either coordinate set (:mod:`~qchain.arm.dynamics_derivatives`), the Lagrangian
form (:mod:`~qchain.arm.lagrangian`) and statics (:mod:`~qchain.arm.statics`)."""
