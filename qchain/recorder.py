"""Step records of a simulated chain, for :mod:`qchain.logging`, computed in batches.

:class:`ChainRecorder` is the ``on_sample`` callback of :func:`qchain.simulate` that turns
each sample into a step record (time, q, v, p, energies, backbone points and segment-tip
frames) for a :class:`qchain.logging.RunLogger`. A sample only costs a copy of the state:
the frames of a batch of samples come from one compiled call
(:meth:`qchain.Chain.frames_batch`) and the batch goes to the logger in one
:meth:`~qchain.logging.RunLogger.log_rows` call. A sample waits here at most the logger's
``flush_interval`` of simulation time (0.25 s by default) and ``max_wall`` seconds of wall
time (50 ms): that is what a SIGKILL of the simulating process can lose (the writer process
then finishes the file with what it has).

The bound trades speed against what a crash loses: a batch costs the simulating process a
fixed ~0.15-0.2 ms (its caches are cold from the simulation), which for the three-segment
example (50 samples and ~0.1 s of wall time a simulated second) is ~1.5 % of the run time
with batches of 0.1 s of simulation time and ~0.8 % with 0.25 s.
"""

from __future__ import annotations

import time

import numpy as np

from .logging import RecordLayout

__all__ = ["ChainRecorder", "BACKBONE_POINTS"]

BACKBONE_POINTS = 12  # backbone points a segment in a logged record


class ChainRecorder:
    """``on_sample(t, q, v, p, energies=None)`` callback that logs a chain's samples.

    Parameters
    ----------
    logger : qchain.logging.RunLogger
        Where the records go.
    chain : qchain.Chain
        The simulated chain (its frames and, if ``simulate`` does not pass them, energies).
    points_per_segment : int
        Backbone points a segment (>= 2).
    max_batch : int
        Samples computed and logged together (>= 1).
    max_wall : float, s
        Wall time a sample may wait here (> 0).

    Notes
    -----
    Use it as a context manager inside the logger's, so that the samples still waiting are
    logged before the logger finishes its files, also when the simulation raises::

        with RunLogger(info, "runs/arm.mcap") as log, ChainRecorder(log, chain) as rec:
            simulate(chain, q0, v0, duration=4.0, on_sample=rec)

    ``step`` of the records counts the samples from 0.
    """

    def __init__(self, logger, chain, points_per_segment: int = BACKBONE_POINTS, max_batch: int = 64,
                 max_wall: float = 0.05):
        if not (isinstance(points_per_segment, (int, np.integer)) and points_per_segment >= 2):
            raise ValueError(f"points_per_segment must be an int >= 2, got {points_per_segment!r}")
        if not (isinstance(max_batch, (int, np.integer)) and max_batch >= 1):
            raise ValueError(f"max_batch must be an int >= 1, got {max_batch!r}")
        if not (isinstance(max_wall, (int, float)) and max_wall > 0):
            raise ValueError(f"max_wall must be > 0 s, got {max_wall!r}")
        self.logger = logger
        self.chain = chain
        self.points_per_segment = int(points_per_segment)
        self.max_batch = int(max_batch)
        self.max_wall = float(max_wall)
        self.max_sim = logger.flush_interval  # s of simulation time a sample waits here at most
        self.n_samples = 0
        self.layout = RecordLayout(chain.nq, chain.nv, chain.nu, chain.n, self.points_per_segment)
        sl = self.layout.slices
        assert sl["q"].stop == sl["v"].start and sl["v"].stop == sl["p"].start  # q, v, p side by side
        self._sq, self._sx, self._se = sl["q"], slice(sl["q"].start, sl["p"].stop), sl["energy"]
        self._nx = sl["p"].stop - sl["q"].start
        self._sbb, self._stf = sl["backbone"], sl["tip_frames"]
        self._rows = np.empty((self.max_batch, self.layout.row_width))  # the records of a batch
        # the samples waiting: times, (q, v, p) copied into one array each, (kinetic, potential)
        self._t: list[float] = []
        self._x: list[np.ndarray] = []
        self._e: list[tuple] = []
        self._wall0 = 0.0

    def __call__(self, t, q, v, p, energies=None) -> None:
        # A sample is copied into lists, not into the rows: three list appends and one
        # concatenate cost the simulation 7-10 us a call in the example, against 12-13 us for
        # filling a numpy row field by field (the caches are cold from the simulation).
        if energies is None:
            energies = (self.chain.kinetic_energy(q, v, t=t), self.chain.potential_energy(q, t=t))
        ts = self._t
        if ts and t - ts[0] >= self.max_sim:  # a batch spans less than max_sim
            self.flush()
            ts = self._t
        if not ts:
            self._wall0 = time.monotonic()
        x = np.concatenate((q, v, p))  # a copy: the caller may reuse its arrays
        if x.shape != (self._nx,):
            lay = self.layout
            raise ValueError(f"q, v, p must have shapes ({lay.nq},), ({lay.nv},), ({lay.n_p},), got "
                             f"{np.shape(q)}, {np.shape(v)}, {np.shape(p)}")
        ts.append(t)
        self._x.append(x)
        self._e.append(energies)
        if len(ts) >= self.max_batch or time.monotonic() - self._wall0 >= self.max_wall:
            self.flush()

    def flush(self) -> None:
        """Compute the frames of the samples still waiting and log them."""
        K = len(self._t)
        if K == 0:
            return
        ts, xs, es = self._t, self._x, self._e
        self._t, self._x, self._e = [], [], []
        rows = self._rows[:K]
        rows[:, 0] = ts
        rows[:, 1] = np.arange(self.n_samples, self.n_samples + K)
        rows[:, self._sx] = xs
        e = self._se.start
        rows[:, e : e + 2] = es
        rows[:, e + 2] = rows[:, e] + rows[:, e + 1]  # total = kinetic + potential
        f = self.chain.frames_batch(rows[:, self._sq], self.points_per_segment, t=rows[:, 0])
        rows[:, self._sbb] = f.backbone.reshape(K, -1)
        # tip frames (K, n, 7): x, y, z, qx, qy, qz, qw
        tips = np.concatenate([f.translation[:, 1:], f.quaternion[:, 1:]], axis=-1)
        rows[:, self._stf] = tips.reshape(K, -1)
        self.logger.log_rows(rows, self.layout)
        self.n_samples += K

    def __enter__(self) -> ChainRecorder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.flush()
        except Exception:
            if exc_type is None:
                raise  # otherwise the simulation's own exception is the one to see
