"""The command line's errors: one line on stderr with its exit code (:data:`EXIT_OK`,
:data:`EXIT_FAILED`, :data:`EXIT_USAGE`: ``docs/cli.md``), never a traceback (``--debug``
shows it); warnings one line each; Ctrl-C reported once."""

from __future__ import annotations

import os
import sys
import traceback
from contextlib import suppress

from ..checks.text import printable
from ..errors import BadInput, BudgetError, QchainError, SceneError

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2
DEBUG_HINT = "(run with --debug for the traceback)"

# --------------------------------------------------------------------------------------
# errors: one line, the right exit code


class _Session:
    """What the command knows of itself while it runs, for its error lines: ``phase``
    ``"start"`` until the simulation starts (an error is the input's: exit code 2), then
    ``"run"`` and ``"end"`` (exit code 1)."""

    def __init__(self, command: str):
        self.command = command
        self.phase = "start"
        self.reached: float | None = None
        self.sigints = 0  # Ctrl-C seen (some library code swallows the KeyboardInterrupt: see check_interrupt)
        self.reported = 0  # of them, said already

    def on_sigint(self, signum, frame):
        """The SIGINT handler while the command runs: Python's own, counting."""
        self.sigints += 1
        raise KeyboardInterrupt

    def check_interrupt(self) -> None:
        """Raise ``KeyboardInterrupt`` if Ctrl-C came during start-up and was swallowed
        (an exception in a ctypes callback, such as llvmlite's while numba loads the
        engine, is printed and dropped): start-up stops at the next check instead of
        running anyway."""
        if self.sigints > self.reported and self.phase == "start":
            raise KeyboardInterrupt

    @property
    def prog(self) -> str:
        return f"qchain {self.command}" if self.command else "qchain"

    def where(self) -> str:
        if self.phase == "start":
            return " during start-up (nothing was run)"
        if self.reached is not None:
            return f" at t = {self.reached:.6g} s"
        return ""


def _one_line(text: str, limit: int = 2000) -> str:
    text = printable(" ".join(str(text).split()))  # lines folded into one, then what a terminal would act on escaped
    return text if len(text) <= limit else text[: limit - 3] + "..."


def report_error(prog: str, err: BaseException, debug: bool = False, started: bool = False) -> int:
    """Print ``prog: error: ...`` for ``err`` on stderr (its traceback first with ``debug``) and
    return the exit code: 2 for bad input (and a value refused before the run ``started``), 1
    otherwise."""
    if debug:
        traceback.print_exception(err)
    if isinstance(err, (BadInput, SceneError, BudgetError)):
        code, text, foreseen = EXIT_USAGE, str(err), True  # a scene file's problems: one a line
    elif isinstance(err, (ValueError, QchainError)):
        code, text, foreseen = (EXIT_FAILED if started else EXIT_USAGE), _one_line(err), True
    elif isinstance(err, OSError):
        code, text, foreseen = EXIT_FAILED, _one_line(err), True
    elif isinstance(err, MemoryError):
        code, text, foreseen = EXIT_FAILED, "out of memory", True
    else:
        code, text, foreseen = EXIT_FAILED, _one_line(f"{type(err).__name__}: {err}"), False
    if not str(text).strip():
        text = type(err).__name__
    line = f"{prog}: error: {text}"
    if not foreseen and not debug:
        line += f" {DEBUG_HINT}"
    print(line, file=sys.stderr, flush=True)
    return code


def take_debug(argv: list[str]) -> tuple[list[str], bool]:
    """``argv`` without its ``--debug`` flags (before a ``--``), and whether there was one."""
    if "--debug" not in argv:
        return argv, False
    stop = argv.index("--") if "--" in argv else len(argv)
    debug = "--debug" in argv[:stop]
    return [a for a in argv[:stop] if a != "--debug"] + argv[stop:], debug


def _exit_code(exc: SystemExit, prog: str = "qchain") -> int:
    if exc.code is None:
        return EXIT_OK
    if isinstance(exc.code, int):
        return exc.code
    print(f"{prog}: error: {_one_line(exc.code)}", file=sys.stderr)  # sys.exit("message")
    return EXIT_USAGE


def guarded(prog: str, body, debug: bool = False, session: _Session | None = None) -> int:
    """``body()``'s exit code, every exception one line on stderr and its exit code
    (:func:`report_error`), Ctrl-C one line and exit code 1; ``session`` says where the command
    is (start-up, running)."""
    session = session or _Session(prog.removeprefix("qchain").strip())
    try:
        code = int(body() or 0)
        session.check_interrupt()
        return code
    except SystemExit as exc:  # argparse: --help, --version (0) and usage errors (2)
        return _exit_code(exc, prog)
    except KeyboardInterrupt as exc:
        session.reported = session.sigints
        if debug:
            traceback.print_exception(exc)
        print(f"{prog}: interrupted{session.where()}", file=sys.stderr, flush=True)
        return EXIT_FAILED
    except BrokenPipeError:  # the reader of stdout went away (qchain info x | head): nothing to say
        with suppress(OSError, ValueError, AttributeError):  # no second error when Python flushes stdout at exit
            _to_devnull(sys.stdout.fileno())
        return EXIT_FAILED
    except Exception as err:  # noqa: BLE001 - the one place every error becomes a line
        return report_error(prog, err, debug, started=session.phase != "start")


def _to_devnull(fd: int) -> None:
    """Point the file descriptor ``fd`` at ``os.devnull``: what is written there goes nowhere."""
    null = os.open(os.devnull, os.O_WRONLY)
    if null != fd:
        os.dup2(null, fd)
        os.close(null)


def _forget_unhandled_interrupt() -> None:
    """Let the process end with its exit code after a Ctrl-C it handled: CPython remembers a
    ``KeyboardInterrupt`` that left code run through ``PyRun_String`` (Boost.Python's, while
    Pinocchio loads) and would end the process by SIGINT; running a statement through it forgets."""
    with suppress(Exception):  # not CPython: nothing to forget
        import ctypes

        ctypes.pythonapi.PyRun_SimpleString(b"pass")


def _show_warnings(prog: str):
    """A ``warnings.showwarning`` that prints ``prog: warning: MESSAGE``, one line."""

    def show(message, category, filename, lineno, file=None, line=None):
        text = str(message).removeprefix("qchain.logging: ")
        with suppress(OSError, ValueError):
            print(f"{prog}: warning: {_one_line(text)}", file=sys.stderr if file is None else file, flush=True)

    return show


def _tolerant_streams() -> set[str]:
    """Let stdout and stderr print any path (a file name that is not UTF-8, a character the
    locale's encoding lacks, e.g. under ``LC_ALL=C``: shown escaped instead of raising
    ``UnicodeEncodeError``), and give a closed stdout or stderr (``>&-``) a place to go
    (``os.devnull``), so that printing never stops a run. Returns the names of those that
    were closed."""
    closed = set()
    for fd, name in ((1, "stdout"), (2, "stderr")):
        try:
            os.fstat(fd)
        except OSError:  # closed: a file opened later (the recording) must not take its number
            closed.add(name)
            with suppress(OSError):
                _to_devnull(fd)
        if getattr(sys, name) is None:
            with suppress(OSError):
                setattr(sys, name, open(os.devnull, "w", encoding="utf-8"))
    for stream in (sys.stdout, sys.stderr):
        if getattr(stream, "errors", None) not in (None, "backslashreplace") and hasattr(stream, "reconfigure"):
            with suppress(ValueError, OSError, AttributeError, TypeError):
                stream.reconfigure(errors="backslashreplace")
    return closed


class SummaryOutput:
    """``sys.stdout`` while a command runs: the same stream, except that an error writing to
    it (a closed pipe, ``/dev/full``: EPIPE, ENOSPC) does not stop the command or lose its
    recording. It is said once on stderr (``PROG: warning: standard output: ... (the rest of
    the summary is not shown)``) and what is printed after it is dropped."""

    def __init__(self, stream, prog: str = "qchain"):
        self._stream = stream
        self._prog = prog
        self.failed: OSError | None = None

    def _fail(self, err: OSError) -> None:
        if self.failed is None:
            self.failed = err
            with suppress(OSError, ValueError):
                print(f"{self._prog}: warning: standard output: {err.strerror or err} (the rest of the summary is "
                      "not shown)", file=sys.stderr, flush=True)
        # what is left in the stream's buffer goes nowhere, also when Python exits
        with suppress(OSError, ValueError, AttributeError):
            _to_devnull(self._stream.fileno())

    def write(self, text):
        if self.failed is not None:
            return len(text)
        try:
            return self._stream.write(text)
        except OSError as err:
            self._fail(err)
            return len(text)

    def writelines(self, lines):
        for line in lines:
            self.write(line)

    def flush(self):
        if self.failed is not None:
            return
        try:
            self._stream.flush()
        except OSError as err:
            self._fail(err)

    def __getattr__(self, name):
        return getattr(self._stream, name)
