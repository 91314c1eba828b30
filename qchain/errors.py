"""Every exception class qchain raises on purpose, grouped by the layer that raises it.

The modules that raise them import them from here (and keep their names, so that
``from qchain.scene.format import SceneError`` still works: it is the same class).
:class:`QchainError` is the base of most; three are not, for their callers' sake:
:class:`BadInput` (the command line's usage errors), :class:`OutputError` (an ``OSError``)
and :class:`LoggingWarning` (a warning).

Standard library only: the recording's writer process and the command line's error path
import this module before (or without) numpy. The argument converters that raise
``TypeError``/``ValueError`` are :mod:`qchain.checks.convert`'s.
"""

from __future__ import annotations

__all__ = [
    "QchainError",
    # the model (model, arm)
    "DomainError",
    "SingularConfigurationError",
    "NonFiniteError",
    # simulation (sim)
    "BudgetError",
    # scene files (scene)
    "SceneError",
    "MAX_LISTED",
    # recordings (recording)
    "LoggingError",
    "RecordingFormatError",
    "LimitExceeded",
    "LoggingWarning",
    "PythonBackendWarning",
    # batches and sweeps (batch)
    "RolloutError",
    "SweepError",
    "ClusterLost",
    # fits (fit)
    "FitSpecError",
    # the command line (cli)
    "BadInput",
    "OutputError",
    # message text
    "printable",
]


class QchainError(Exception):
    """Base class of every error qchain raises on purpose."""


# --------------------------------------------------------------------------------------
# The model (qchain.model, qchain.arm): configurations and results
# --------------------------------------------------------------------------------------


class DomainError(QchainError, ValueError):
    """A configuration outside the model's domain (l <= 0, |kappa| r_s >= 1, ...)."""


class SingularConfigurationError(QchainError, ValueError):
    """The paper's (l, psi, kappa) coordinates are singular at this configuration.

    Also raised by :class:`qchain.LagrangianChain` at the attitude singularity of its
    roll-pitch-yaw base coordinates (``|pitch| -> pi/2``).
    """


class NonFiniteError(QchainError, ValueError):
    """A model quantity came out infinite or NaN; the message names the quantity, the
    segment and (in a run) the time. Raised instead of returning the value: nothing
    non-finite leaves the model silently."""


# --------------------------------------------------------------------------------------
# Simulation (qchain.sim)
# --------------------------------------------------------------------------------------


class BudgetError(QchainError, ValueError):
    """A run that would exceed its :class:`~qchain.sim.budget.Budget`; the message names the
    budget and how to raise it; ``cost`` is the run's :class:`~qchain.sim.budget.Cost`."""

    def __init__(self, message: str, cost=None):  # cost: a qchain.sim.budget.Cost (a layer above) or None
        super().__init__(message)
        self.cost = cost


# --------------------------------------------------------------------------------------
# Scene files (qchain.scene)
# --------------------------------------------------------------------------------------

#: Problems a :class:`SceneError`'s message lists (``problems`` holds them all).
MAX_LISTED = 50


class SceneError(QchainError, ValueError):
    """A scene file that cannot be used; ``problems`` lists every problem found
    (:class:`~qchain.scene.format.Problem`).

    The message names the file and, for each problem, the key, what was expected and
    what was found.
    """

    def __init__(self, path: str, problems: list):
        self.path = str(path)
        self.problems = list(problems)
        where = self.path if len(self.path) <= 200 else f"{self.path[:100]}...{self.path[-97:]}"  # a 4 KB path: cut
        where = printable(where)  # a problem a line: a newline or escape sequence in a name stays in its line
        if len(self.problems) == 1:
            msg = f"{where}: {printable(self.problems[0])}"
        else:
            shown = self.problems[:MAX_LISTED]
            msg = f"{where}: {len(self.problems)} problems:\n" + "\n".join(f"  {printable(p)}" for p in shown)
            if len(self.problems) > MAX_LISTED:
                msg += f"\n  ... and {len(self.problems) - MAX_LISTED} more (SceneError.problems lists them all)"
        super().__init__(msg)


# --------------------------------------------------------------------------------------
# Recordings (qchain.recording)
# --------------------------------------------------------------------------------------


class LoggingError(QchainError):
    """The run log could not be written (a writer that cannot start, a bad output path)."""


class RecordingFormatError(LoggingError, ValueError):
    """A file that is not a (readable) qchain MCAP recording; the message names the file."""


class LimitExceeded(RecordingFormatError):
    """A reading limit exceeded at byte ``offset`` (the reader prefixes the file's name)."""

    def __init__(self, message: str, offset: int):
        super().__init__(message)
        self.offset = offset


class LoggingWarning(UserWarning):
    """Something of the logging did not work out (a viewer out of reach); the run goes on."""


class PythonBackendWarning(UserWarning):
    """A run asked for a compiled method (``radau5``, ``dopri5``, ``rk4``, ``midpoint``) that
    the compiled engine cannot serve: it runs on the Python steppers (``Trajectory.meta["engine"]
    == "python"``, one to two orders of magnitude slower); the message names the reason."""


# --------------------------------------------------------------------------------------
# Batches and sweeps (qchain.batch)
# --------------------------------------------------------------------------------------


class RolloutError(QchainError):
    """A rollout of a batch raised an exception (``index``: which; ``detail``: what)."""

    def __init__(self, index: int, detail: str):
        super().__init__(f"rollout {index} raised {detail}")
        self.index = index
        self.detail = detail

    def __reduce__(self):
        return (RolloutError, (self.index, self.detail))


class SweepError(SceneError):
    """A sweep (file or arguments) that cannot be run; ``problems`` lists every problem,
    each naming the key, what was expected and what was found."""


class FitSpecError(SceneError):
    """A fit file (``qchain fit``) that cannot be used; ``problems`` lists every problem, each
    naming the key, what was expected and what was found."""


class ClusterLost(QchainError, RuntimeError):
    """A Dask cluster had no worker, or its scheduler could not be reached, for longer than
    the engine's ``lost_timeout`` (or the client closed): the items not finished were not
    computed. A sweep with a results folder keeps every run it finished and resumes the
    rest when started again."""


# --------------------------------------------------------------------------------------
# The command line (qchain.cli)
# --------------------------------------------------------------------------------------


class BadInput(Exception):
    """Input the command refuses before anything runs (exit code 2); the message says why."""


class OutputError(OSError):
    """Outputs of a run that could not be written (each named, with why); ``written`` lists
    those that were."""

    def __init__(self, message: str, written: list):
        super().__init__(message)
        self.written = written


# --------------------------------------------------------------------------------------
# Message text
# --------------------------------------------------------------------------------------
# Defined here, below every layer, because SceneError's message needs it; the layers above
# take it from qchain.checks.text.

_CONTROL = {c: f"\\x{c:02x}" for c in [*range(0x20), 0x7F, *range(0x80, 0xA0)] if c != 0x09}
_CONTROL.update({0x0A: "\\n", 0x0D: "\\r"})


def printable(text: str) -> str:
    """``text`` as one line any terminal shows as it is: control characters (a newline, an
    escape sequence from a file's name or its outcome message) and bytes that are not
    UTF-8 (a file name's, kept as surrogates) escaped."""
    text = str(text).translate(_CONTROL)
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        text = "".join(f"\\x{ord(ch) - 0xDC00:02x}" if 0xDC80 <= ord(ch) <= 0xDCFF
                       else ch.encode("utf-8", "backslashreplace").decode("ascii") if 0xD800 <= ord(ch) <= 0xDFFF
                       else ch for ch in text)
    return text
