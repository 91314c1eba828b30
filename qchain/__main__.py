"""``python -m qchain``: the ``qchain`` command (:func:`qchain.cli.main`), with the same
arguments, output and exit codes (0 success, 1 the run failed or was interrupted, 2 bad
input or usage)."""

import sys


def _main() -> int:
    try:
        from .cli import main
    except KeyboardInterrupt:  # Ctrl-C while Python loads the command: one line, no traceback
        print("qchain: interrupted during start-up (nothing was run)", file=sys.stderr)
        return 1
    return main()


if __name__ == "__main__":
    sys.exit(_main())
