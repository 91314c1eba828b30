"""The compiled simulation engine (``docs/engine.md``): what ``qchain.simulate``
runs for ``radau5``, ``dopri5``, ``rk4`` and ``midpoint``.

``system`` packs a chain and its inputs for numba and evaluates the first-order system and
its exact Jacobian; ``steppers`` takes whole stretches of steps of each method; ``driver``
is the one Python loop between stretches; ``schedules`` and ``lie`` are the compiled input
schedules and free-flyer algebra; ``linalg`` a small LU; ``warmup`` the first-use compile;
``jit`` the decorators.
"""
