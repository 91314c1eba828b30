"""Text from outside (file names, recorded messages) shown to a person on one line.

Standard library only: the command line's error path imports it before numpy loads.
:func:`printable` is defined in :mod:`qchain.errors` (a :class:`~qchain.errors.SceneError`'s
message needs it, and that module is below this one); this is where the layers take it from.
"""

from __future__ import annotations

from ..errors import printable

__all__ = ["printable"]
