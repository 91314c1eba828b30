"""The ``qchain`` command, the only place with argparse, exit codes and printed lines:
:mod:`~qchain.cli.main` (``run``, ``info`` and the dispatch), :mod:`~qchain.cli.sweep`,
:mod:`~qchain.cli.recording` (``replay``, ``recover``, ``layout`` and the recording flags),
:mod:`~qchain.cli.command` (one command's harness: errors, warnings and Ctrl-C as one line),
:mod:`~qchain.cli.checks` (flag values and paths), :mod:`~qchain.cli.errors` and
:mod:`~qchain.cli.outputs` (plots and files of a run)."""
