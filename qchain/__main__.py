"""``python -m qchain``: the ``qchain`` command (:func:`qchain.cli.main`), with the same
arguments, output and exit codes (0 success, 1 the run failed or was interrupted, 2 bad
input or usage)."""

import sys


def entry() -> int:
    """The ``qchain`` console script and ``python -m qchain``: :func:`qchain.cli.main`, imported
    here so that a Ctrl-C while it loads is one line, not a traceback."""
    try:
        from .cli.main import main
    except KeyboardInterrupt:  # Ctrl-C while Python loads the command: one line, no traceback
        print("qchain: interrupted during start-up (nothing was run)", file=sys.stderr)
        return 1
    return main()


if __name__ == "__main__":
    sys.exit(entry())
