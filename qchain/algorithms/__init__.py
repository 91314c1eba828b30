"""The chain algorithms, compiled with numba, on plain arrays (Pinocchio's names): the
recursive passes ``rnea``, ``crba``, ``aba``, ``frames`` (:mod:`~qchain.algorithms.recursive`),
the planar articulated-body pass (:mod:`~qchain.algorithms.planar`) and the exact derivative
passes, split by algorithm as Pinocchio's (:mod:`~qchain.algorithms.rnea_derivatives`,
:mod:`~qchain.algorithms.aba_derivatives`). They take the model's arrays and a workspace,
never a :class:`~qchain.Chain`; inputs are the caller's to check."""
