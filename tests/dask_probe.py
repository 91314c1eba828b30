"""A sweep metric that worker processes import by name (tests/test_dask.py): it logs which
worker process runs which run, and when, so a test can tell which runs a killed worker cost."""

import os
import time


def logged(scene, model, traj):
    """A scene described as ``"probe LOG SECONDS"`` appends ``start DAMPING PID`` to LOG,
    waits SECONDS (the run's work, as far as the test is concerned), then appends ``end
    DAMPING PID``; the run is named by its first segment's damping. The set-up travels with
    the runs, to whichever worker process runs them."""
    words = scene.description.split()
    if len(words) == 3 and words[0] == "probe":
        mark = f"{scene.segments[0].damping!r} {os.getpid()}\n"
        with open(words[1], "a") as fh:
            fh.write("start " + mark)
        time.sleep(float(words[2]))
        with open(words[1], "a") as fh:
            fh.write("end " + mark)
    return {"tip_path_points": int(len(traj.t))}


def read_log(path) -> list[tuple[str, float, int]]:
    """The log's lines as (``"start"`` or ``"end"``, damping, pid), in the order written."""
    try:
        text = open(path).read()
    except FileNotFoundError:
        return []
    out = []
    for line in text[:text.rfind("\n") + 1].splitlines():  # a line being written is left for later
        kind, damping, pid = line.split()
        out.append((kind, float(damping), int(pid)))
    return out


def die_once(shared, items):
    """``i -> -i``; the first time item 3 runs (no file ``shared`` yet) it makes the file and
    kills its worker process."""
    out = []
    for i in items:
        if i == 3 and not os.path.exists(shared):
            open(shared, "w").close()
            os._exit(7)
        out.append(-i)
    return out
