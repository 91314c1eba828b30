"""Step records of a simulated chain, for :mod:`qchain.logging`, computed in batches.

:class:`ChainRecorder` is the ``on_sample`` callback of :func:`qchain.sim.simulation`; a
sample costs a copy of the state, a batch's frames one compiled call
(:meth:`qchain.Chain.frames_batch`) and one :meth:`~qchain.logging.RunLogger.log_rows`
(docs/recording.md, "Cost")."""

from __future__ import annotations

import time

import numpy as np

from ..arm.chain import Frames
from .records import CONTACT_WIDTH, T_MAX, RecordLayout, pack_contacts

__all__ = ["ChainRecorder", "BACKBONE_POINTS", "series_names"]

BACKBONE_POINTS = 12  # backbone points a segment in a logged record


def series_names(chain) -> tuple[list[str], list[str]]:
    """Names with units of a chain's coordinates and velocities, for plots and layouts:
    ``"segment 2 ux [1/m]"``, ``"base qw"``, ``"segment 1 dl/dt [m/s]"``."""
    q, v = [], []
    if chain.floating:
        q += [f"base {c} [m]" for c in "xyz"] + [f"base q{c}" for c in "xyzw"]
        v += [f"base v{c} [m/s]" for c in "xyz"] + [f"base w{c} [rad/s]" for c in "xyz"]
    for i, s in enumerate(chain.segments):
        names = (("l", "m"), ("psi", "rad"), ("kappa", "1/m")) if s.coords == "paper" else \
            (("l", "m"), ("ux", "1/m"), ("uy", "1/m"))
        q += [f"segment {i + 1} {c} [{u}]" for c, u in names]
        v += [f"segment {i + 1} d{c}/dt [{u}/s]" for c, u in names]
    if len(q) != chain.nq or len(v) != chain.nv:  # a layout this function does not know
        return [f"q[{k}]" for k in range(chain.nq)], [f"v[{k}]" for k in range(chain.nv)]
    return q, v


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
    realtime : bool
        Pace the simulation to the wall clock: a sample at simulated time ``t`` is not
        handed over before ``t`` seconds of wall time after the first (to watch a short
        run live).
    contacts : callable or None
        ``contacts(t, q, v)`` -> the active contacts of a sample (anything with ``.point``,
        ``.normal``, ``.force`` (c, 3) world frame, m and N, ``.segment`` and ``.obstacle``
        (c,)), e.g. ``lambda t, q, v: chain.contacts(q, v, env, t)``; called once a sample
        when the logger's ``RunInfo.max_contacts`` > 0, with the sample's ``q`` (nq,) and
        ``v`` (nv,). None: no contacts recorded.
    tension : callable or None
        ``tension(t, q, v)`` -> the tendons' tensions (nt,) N of a sample, e.g. the run's
        tension schedule ``lambda t, q, v: schedule(t)``, for a chain with tendons: each
        sample then records them and each tendon's world path
        (:meth:`qchain.Chain.tendon_paths`, ``points_per_segment`` points a segment it passes,
        NaN-padded to ``n points_per_segment``). None: no tendon records.

    Notes
    -----
    Use it as a context manager inside the logger's, so that the samples still waiting are
    logged before the logger finishes its files, also when the simulation raises::

        with RunLogger(info, "runs/arm.mcap") as log, ChainRecorder(log, chain) as rec:
            simulate(chain, q0, v0, (0.0, 4.0), on_sample=rec)

    ``step`` of the records counts the samples from 0.
    """

    def __init__(self, logger, chain, points_per_segment: int = BACKBONE_POINTS, max_batch: int = 64,
                 max_wall: float = 0.05, realtime: bool = False, contacts=None, tension=None):
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
        self.realtime = bool(realtime)
        if contacts is not None and not callable(contacts):
            raise TypeError(f"contacts must be None or a callable (t, q, v) -> contacts, got {type(contacts).__name__}")
        self.contacts = contacts
        if tension is not None and not callable(tension):
            raise TypeError(f"tension must be None or a callable (t, q, v) -> (nt,) N, got {type(tension).__name__}")
        if tension is not None and not getattr(chain, "nt", 0):
            raise ValueError("tension is given but the chain has no tendons")
        self.tension = tension
        nt = getattr(chain, "nt", 0) if tension is not None else 0
        info = getattr(logger, "info", None)
        self._clock0: tuple[float, float] | None = None
        self.n_samples = 0
        self.layout = RecordLayout(chain.nq, chain.nv, chain.nu, chain.n, self.points_per_segment,
                                   int(getattr(info, "max_contacts", 0) or 0), nt, chain.n * self.points_per_segment if nt else 0)
        sl = self.layout.slices
        # q, v, p, kinetic, potential side by side: one copy a sample, one assignment a batch
        assert sl["q"].stop == sl["v"].start and sl["v"].stop == sl["p"].start and sl["p"].stop == sl["energy"].start
        self._sq, self._sx, self._se = sl["q"], slice(sl["q"].start, sl["energy"].start + 2), sl["energy"]
        self._nx = sl["energy"].start + 2 - sl["q"].start
        self._sbase, self._sbb, self._stf = sl["base"], sl["backbone"], sl["tip_frames"]
        self._rows = np.empty((self.max_batch, self.layout.row_width))  # the records of a batch
        n, B = chain.n, self.max_batch
        self._frames = Frames(np.empty((B, n + 1, 3, 3)), np.empty((B, n + 1, 3)), np.empty((B, n + 1, 4)),
                              np.empty((B, n, self.points_per_segment, 3)))  # the frames of a batch
        self._steps = np.arange(self.max_batch, dtype=np.float64)
        # the samples waiting: times, (q, v, p, kinetic, potential) copied into one array each
        self._t: list[float] = []
        self._t_taken: float | None = None  # the time of the last sample taken
        self._batch_t0: float | None = None  # the first time of the last batch taken (record_batch)
        self._x: list[np.ndarray] = []
        self._wall0 = 0.0

    def __call__(self, t, q, v, p, energies=None) -> None:
        # A sample is copied into lists, not into the rows: list appends and one concatenate
        # cost the simulation less than filling a numpy row field by field.
        # checked here, where the sample enters: a bad one found at the batch's flush would
        # take the good samples buffered with it
        if not (type(t) is float or isinstance(t, (int, np.integer, np.floating))) or isinstance(t, bool) \
                or not 0.0 <= t <= T_MAX:
            raise ValueError(f"t must be a time >= 0 and <= {T_MAX:.10g} s, got {t!r}")
        if self._t_taken is not None and t < self._t_taken:
            raise ValueError(f"t must not go back: got t = {t!r} s after a sample at t = {self._t_taken!r} s")
        if energies is None:
            energies = (self.chain.kinetic_energy(q, v, t=t), self.chain.potential_energy(q, t=t))
        elif np.shape(energies) != (2,):
            raise ValueError(f"energies must be (kinetic, potential) J, two numbers, got shape {np.shape(energies)}")
        ts = self._t
        if ts and t - ts[0] >= self.max_sim:  # a batch spans less than max_sim
            self.flush()
            ts = self._t
        if not ts:
            self._wall0 = time.monotonic()
        lay = self.layout
        if (np.shape(q), np.shape(v), np.shape(p)) != ((lay.nq,), (lay.nv,), (lay.n_p,)):
            raise ValueError(f"q, v, p must have shapes ({lay.nq},), ({lay.nv},), ({lay.n_p},), got "
                             f"{np.shape(q)}, {np.shape(v)}, {np.shape(p)}")
        x = np.concatenate((q, v, p, energies))  # a copy: the caller may reuse its arrays
        if not np.isfinite(x[: lay.nq]).all():  # the frames need them (v, p and energies may be NaN: null)
            k = int(np.flatnonzero(~np.isfinite(x[: lay.nq]))[0])
            raise ValueError(f"q[{k}] must be finite, got {float(x[k])!r} at t = {float(t)!r} s")
        ts.append(t)
        self._x.append(x)
        self._t_taken = t
        if self.realtime:
            self._pace(t)
        if len(ts) >= self.max_batch or time.monotonic() - self._wall0 >= self.max_wall:
            self.flush()

    def record_batch(self, t, q, v, p, kinetic, potential, *, skip_checks: bool = False) -> None:
        """Take ``K`` samples at once as arrays: ``t`` (K,) s, ``q`` (K, nq), ``v`` (K, nv),
        ``p`` (K, 3 n) Pa, ``kinetic``, ``potential`` (K,) J. The batch form of a call, for a
        caller that has its samples in arrays (no Python work a sample); the batches logged
        still span less than ``max_sim`` of simulated time each. Paced to the wall clock
        (``realtime``), the samples are taken one by one, so the view moves smoothly.

        ``skip_checks``: the configurations are a run's states, which the engine checked at
        every step (:meth:`qchain.Chain.frames_batch` does not check them again)."""
        t = np.asarray(t, dtype=np.float64)
        K = t.shape[0]
        if K > 1 and not (np.diff(t) >= 0.0).all():
            k = int(np.flatnonzero(~(np.diff(t) >= 0.0))[0])
            raise ValueError(f"t must not go back: t[{k + 1}] = {float(t[k + 1])!r} s after t[{k}] = {float(t[k])!r} s")
        if K and self._t_taken is not None and t[0] <= self._t_taken:
            if t[0] != self._batch_t0:  # another run's samples (a recorder used twice)
                raise ValueError(f"t must not go back: a batch from t = {float(t[0])!r} s after a sample at t = "
                                 f"{self._t_taken!r} s (one recorder a run)")
            # the same batch handed over again (a Ctrl-C inside this call, while it paced the
            # batch sample by sample): what was taken is not taken twice
            a = int(np.searchsorted(t, self._t_taken, side="right"))
            t, q, v, p, kinetic, potential = t[a:], q[a:], v[a:], p[a:], kinetic[a:], potential[a:]
            K = t.shape[0]
        elif K:
            self._batch_t0 = float(t[0])
        if self.realtime:
            try:
                for k in range(K):
                    self(t[k], q[k], v[k], p[k], energies=(kinetic[k], potential[k]))
            except KeyboardInterrupt:  # the rest of the batch at once, unpaced: the user asked to stop
                a = 0 if self._t_taken is None else int(np.searchsorted(t, self._t_taken, side="right"))
                self._take(t[a:], q[a:], v[a:], p[a:], kinetic[a:], potential[a:], skip_checks)
                raise
            return
        self._take(t, q, v, p, kinetic, potential, skip_checks)

    def _take(self, t, q, v, p, kinetic, potential, skip_checks: bool) -> None:
        """:meth:`record_batch` unpaced: log the samples in pieces within ``max_sim``."""
        K = t.shape[0]
        self.flush()
        if K == 0:
            return
        x = np.concatenate((q, v, p, np.asarray(kinetic)[:, None], np.asarray(potential)[:, None]), axis=1)
        if x.shape != (K, self._nx):
            lay = self.layout
            raise ValueError(f"q, v, p must have shapes (K, {lay.nq}), (K, {lay.nv}), (K, {lay.n_p}), got "
                             f"{np.shape(q)}, {np.shape(v)}, {np.shape(p)}")
        a = 0
        while a < K:  # cut where a batch would span max_sim (and at max_batch samples)
            b = min(K, a + self.max_batch, int(np.searchsorted(t, t[a] + self.max_sim, side="left")))
            b = max(b, a + 1)
            self._write(t[a:b], x[a:b], skip_checks)
            a = b

    @property
    def taken(self) -> int:
        """Samples taken so far (logged or waiting here)."""
        return self.n_samples + len(self._t)

    def _pace(self, t: float) -> None:
        now = time.monotonic()
        if self._clock0 is None:
            self._clock0 = (now, t)
            return
        ahead = (t - self._clock0[1]) - (now - self._clock0[0])
        if ahead > 0:
            self.flush()  # what is waiting goes out (to the viewer) before the pause
            time.sleep(ahead)

    def flush(self) -> None:
        """Compute the frames of the samples still waiting and log them."""
        K = len(self._t)
        if K == 0:
            return
        ts, xs = self._t, self._x
        self._t, self._x = [], []
        self._write(ts, xs)

    def _write(self, ts, xs, skip_checks: bool = False) -> None:
        """Log ``K`` samples: times (K,), rows (K, nx) of (q, v, p, kinetic, potential)."""
        K = len(ts)
        rows = self._rows[:K]
        rows[:, 0] = ts
        np.add(self._steps[:K], self.n_samples, out=rows[:, 1])
        rows[:, self._sx] = xs
        e = self._se.start
        np.add(rows[:, e], rows[:, e + 1], out=rows[:, e + 2])  # total = kinetic + potential
        f = self.chain.frames_batch(rows[:, self._sq], self.points_per_segment, t=rows[:, 0], skip_checks=skip_checks,
                                    out=self._frames if skip_checks else None)
        rows[:, self._sbb] = f.backbone.reshape(K, -1)
        b = self._sbase.start
        rows[:, b : b + 3] = f.translation[:, 0]
        rows[:, b + 3 : b + 7] = f.quaternion[:, 0]
        # tip frames (K, n, 7): x, y, z, qx, qy, qz, qw
        tf = rows[:, self._stf].reshape(K, -1, 7)  # a view into the rows
        tf[:, :, :3] = f.translation[:, 1:]
        tf[:, :, 3:] = f.quaternion[:, 1:]
        C = self.layout.C
        if C:
            sv = self.layout.slices["v"]
            blocks = rows[:, self.layout.slices["contacts"]].reshape(K, C, CONTACT_WIDTH)
            for k in range(K):
                found = None if self.contacts is None else \
                    self.contacts(float(rows[k, 0]), rows[k, self._sq].copy(), rows[k, sv].copy())
                blocks[k], dropped = pack_contacts(found, C, getattr(self.logger, "info", None))
                if dropped and hasattr(self.logger, "_said_dropped"):  # (said once, by the logger)
                    self.logger._said_dropped(dropped, float(rows[k, 0]))
        if self.layout.nt:
            self._write_tendons(rows, K)
        self.logger.log_rows(rows, self.layout)
        self.n_samples += K
        self._t_taken = float(rows[K - 1, 0])

    def _write_tendons(self, rows: np.ndarray, K: int) -> None:
        """Each sample's tensions (checked: ``nt`` finite numbers >= 0) and tendon paths into ``rows``."""
        lay = self.layout
        sl = lay.slices
        paths = rows[:, sl["tendons"]].reshape(K, lay.nt, lay.M, 3)
        paths[:] = np.nan
        for k in range(K):
            t, q, v = float(rows[k, 0]), rows[k, self._sq].copy(), rows[k, sl["v"]].copy()
            T = np.asarray(self.tension(t, q, v), dtype=np.float64)
            if T.shape != (lay.nt,) or not (np.isfinite(T).all() and (T >= 0.0).all()):
                raise ValueError(f"tension(t, q, v) must return {lay.nt} finite tensions >= 0 N, got {T!r} at "
                                 f"t = {t!r} s")
            rows[k, sl["tension"]] = T
            for i, path in enumerate(self.chain.tendon_paths(q, self.points_per_segment, t=t)):
                paths[k, i, : len(path)] = path

    def __enter__(self) -> ChainRecorder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.flush()
        except Exception:
            if exc_type is None:
                raise  # otherwise the simulation's own exception is the one to see
