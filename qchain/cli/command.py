"""One command's harness: :func:`command` runs a command's body and turns whatever happens
(an exception, a warning, Ctrl-C at any moment, a standard output that cannot be written) into
one line on stderr and an exit code. ``qchain`` and ``qchain sweep`` both run inside it."""

from __future__ import annotations

import sys
import warnings
from contextlib import suppress

from .errors import (
    EXIT_FAILED, EXIT_OK, SummaryOutput, _forget_unhandled_interrupt, _Session, _show_warnings, _tolerant_streams,
    guarded)

__all__ = ["command"]


def command(name: str, body, debug: bool = False, session: _Session | None = None,
            result_on_stdout: bool = False) -> int:
    """Run ``body(session)`` as ``qchain NAME`` (``""`` for none) and return its exit code:
    exceptions, warnings and Ctrl-C (at any moment) one line each on stderr; ``debug`` prints
    tracebacks; ``session``: the command this one runs inside (``sweep`` from ``qchain``);
    ``result_on_stdout``: exit code 1 when standard output could not be written."""
    if session is not None:
        return guarded(session.prog, lambda: body(session), debug, session)
    session = _Session(name)
    if "stdout" in _tolerant_streams() and result_on_stdout:  # (info >&-): the result would go nowhere
        print(f"{session.prog}: error: standard output is closed: the result has nowhere to go", file=sys.stderr)
        return EXIT_FAILED
    stdout = sys.stdout
    sys.stdout = out = SummaryOutput(stdout, session.prog)
    sig = _sigint_handler(session.on_sigint)
    hook = sys.unraisablehook

    def unraisable(info):  # Ctrl-C dropped in a callback (llvmlite's): counted, no traceback
        if not (isinstance(info.exc_value, KeyboardInterrupt) and session.sigints):
            hook(info)

    sys.unraisablehook = unraisable
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warnings(session.prog)
            code = guarded(session.prog, lambda: body(session), debug, session)
    finally:
        with suppress(OSError, ValueError):
            sys.stdout.flush()  # (a write error here is the wrapper's to say)
        sys.stdout = stdout
        sys.unraisablehook = hook
        if sig is not None:
            sig.signal(sig.SIGINT, _PREVIOUS_SIGINT.pop())
        if session.sigints:
            _forget_unhandled_interrupt()
    if code == EXIT_OK and out.failed is not None and result_on_stdout:
        code = EXIT_FAILED  # what it was asked for did not reach its reader
    return code


_PREVIOUS_SIGINT: list = []


def _sigint_handler(handler):
    """Install ``handler`` for SIGINT where Python's own is (the main thread, Ctrl-C not
    ignored); returns the :mod:`signal` module if it did (the previous handler is kept)."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return None
    previous = signal.getsignal(signal.SIGINT)
    if previous is not signal.default_int_handler:
        return None
    signal.signal(signal.SIGINT, handler)
    _PREVIOUS_SIGINT.append(previous)
    return signal
