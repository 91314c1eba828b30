"""Checked entry points made from unchecked kernels: :func:`checked` wraps a kernel so that
each argument passes its converter (which raises ``TypeError``/``ValueError`` naming the
argument) before the kernel runs. The model's own passes call the kernels on values they have
already validated; users call the checked form. One kernel, one docstring: no copied twin."""

from __future__ import annotations

import functools
import inspect

__all__ = ["checked"]


def checked(kernel, /, joint=None, **convert):
    """The public, checked form of ``kernel``.

    Parameters
    ----------
    kernel : callable
        The unchecked function, named with a leading underscore (``_skew``); the checked form
        takes its name without it, its signature and its docstring.
    joint : callable, optional
        ``joint(**converted)``: a check of the converted arguments together (shapes that must
        agree), raising ``ValueError`` naming them.
    **convert : callable
        ``convert[name](name, value) -> value`` for each argument that is checked.
    """
    sig = inspect.signature(kernel)
    names = list(sig.parameters)
    steps = [convert.get(n) for n in names]

    @functools.wraps(kernel)
    def public(*args, **kwargs):
        if kwargs or len(args) != len(names):
            bound = sig.bind(*args, **kwargs)  # a missing or unknown argument: Python's TypeError
            bound.apply_defaults()
            args = tuple(bound.arguments[n] for n in names)
        args = tuple(a if step is None else step(n, a) for n, a, step in zip(names, args, steps))
        if joint is not None:
            joint(*args)
        return kernel(*args)

    public.__name__ = public.__qualname__ = kernel.__name__.lstrip("_")
    return public
