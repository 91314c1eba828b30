"""Module-level helpers that worker processes import by name (tests/test_batch.py, test_sweep.py, test_dask.py)."""

import os
import time

import numpy as np


class Hold:
    """A controller holding a constant pressure."""

    def __init__(self, p):
        self.p = np.asarray(p, dtype=float)

    def __call__(self, t, q, v):
        return self.p


class Broken:
    """A controller with a bug: it returns NaN."""

    def __call__(self, t, q, v):
        return np.full(6, np.nan)


class Never:
    """An event function that never crosses zero."""

    def __call__(self, t, q, v):
        return 1.0


def square_logged(shared, items):
    """``i -> i * i``, appending each finished item to the log ``shared[0]`` after ``shared[1]`` s."""
    path, pause = shared
    out = []
    for i in items:
        time.sleep(pause)
        with open(path, "a") as fh:
            fh.write(f"{i}\n")
        out.append(i * i)
    return out


def die_on_three(shared, items):
    """``i -> -i``; item 3 kills its worker process."""
    out = []
    for i in items:
        if i == 3:
            os._exit(7)
        out.append(-i)
    return out


def damping_logged(scene, model, traj):
    """A sweep metric that logs which run ran (by its segment damping): a scene described as
    ``"probe LOG SECONDS"`` appends to LOG after SECONDS (the set-up travels with the runs,
    to whichever worker process runs them)."""
    words = scene.description.split()
    if len(words) == 3 and words[0] == "probe":
        time.sleep(float(words[2]))
        with open(words[1], "a") as fh:
            fh.write(f"{scene.segments[0].damping!r}\n")
    return {"tip_path_points": int(len(traj.t))}
