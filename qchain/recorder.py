"""Step records of a simulated chain, for :mod:`qchain.logging`, computed in batches.

:class:`ChainRecorder` is the ``on_sample`` callback of :func:`qchain.simulate` that turns
each sample into a step record (time, q, v, p, energies, backbone points and segment-tip
frames) for a :class:`qchain.logging.RunLogger`. A sample only costs a copy of the state:
the frames of a batch of samples come from one compiled call
(:meth:`qchain.Chain.frames_batch`) and the batch goes to the logger in one
:meth:`~qchain.logging.RunLogger.log_rows` call. A sample waits here at most the logger's
``flush_interval`` of simulation time (0.1 s by default) and ``max_wall`` seconds of wall
time: that is what a SIGKILL of the simulating process can lose (the writer process then
finishes the file with what it has).
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
        self._sq, self._sv, self._sp, self._se = sl["q"], sl["v"], sl["p"], sl["energy"]
        self._sbb, self._stf = sl["backbone"], sl["tip_frames"]
        self._rows = np.empty((self.max_batch, self.layout.row_width))  # the next records, filled in place
        self._k = 0  # samples waiting
        self._wall0 = 0.0

    def __call__(self, t, q, v, p, energies=None) -> None:
        if energies is None:
            energies = (self.chain.kinetic_energy(q, v, t=t), self.chain.potential_energy(q, t=t))
        k = self._k
        if k and t - self._rows[0, 0] >= self.max_sim:  # a batch spans less than max_sim
            self.flush()
            k = 0
        if k == 0:
            self._wall0 = time.monotonic()
        row = self._rows[k]
        row[0] = t
        row[1] = self.n_samples + k
        row[self._sq] = q
        row[self._sv] = v
        row[self._sp] = p
        ke, pe = energies
        row[self._se] = (ke, pe, ke + pe)
        self._k = k = k + 1
        if k >= self.max_batch or time.monotonic() - self._wall0 >= self.max_wall:
            self.flush()

    def flush(self) -> None:
        """Compute the frames of the samples still waiting and log them."""
        K = self._k
        if K == 0:
            return
        self._k = 0
        rows = self._rows[:K]
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
