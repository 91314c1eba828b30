"""``python benchmarks/_timed_command.py MARKS.json run SCENE ...``: ``qchain run ...`` with the
times (``time.monotonic()``, s) at which its phases begin and end written to MARKS.json, for
``bench_logging.py --example`` to say where a logged run spends its extra time.

Nothing is changed in the command but two wrappers that read the clock around
``Scene.build`` and ``Scene.simulate``. The marks: ``start`` (this script's first line:
the interpreter is up), ``imported`` (``qchain.cli`` imported), ``build0``/``build1``,
``sim0``/``sim1`` (the simulation, logging included; the logger is created between
``build1`` and ``sim0`` and its files finished between ``sim1`` and ``main``), ``main``
(the command returned) and ``atexit`` (the last exit handler; the interpreter's teardown
follows).
"""

import time

_marks = {"start": time.monotonic()}

import atexit  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402


def _mark(name: str) -> None:
    _marks[name] = time.monotonic()


def _write() -> None:  # registered first, so it runs after every later exit handler
    _mark("atexit")
    with open(sys.argv[1], "w") as fh:
        json.dump(_marks, fh)


atexit.register(_write)

from qchain.cli import main as cli  # noqa: E402
from qchain.scene.scene import Scene  # noqa: E402

_mark("imported")


def _timed(method, before: str, after: str):
    def wrapper(self, *args, **kwargs):
        _mark(before)
        out = method(self, *args, **kwargs)
        _mark(after)
        return out

    return wrapper


Scene.build = _timed(Scene.build, "build0", "build1")
Scene.simulate = _timed(Scene.simulate, "sim0", "sim1")

if __name__ == "__main__":
    try:
        code = cli.main(sys.argv[2:])
    finally:
        _mark("main")
    sys.exit(code)
