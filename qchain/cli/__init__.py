"""The ``qchain`` command, the only place with argparse, exit codes and printed lines
(``docs/architecture.md``; each module's docstring says its part)."""
