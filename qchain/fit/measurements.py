"""Measured motion of a real arm, and the pressures that drove it, as the fit takes them.

One experiment is a :class:`Measurements`: the times of the measured samples, what was
measured there (points on the arm at known ``(segment, alpha)`` -- the tip is
``(n - 1, 1.0)`` -- optionally the tip's orientation, or the full coordinates), and the
chamber pressures as a piecewise-linear :class:`~qchain.sim.inputs.Table` on the same clock.
Readers:

* :func:`read_bag`: a ROS 2 bag (an MCAP file, an SQLite ``.db3`` file or a bag folder with
  ``metadata.yaml``), read with ``rosbags``: poses from a ``geometry_msgs/msg/PoseStamped``
  topic or from ``/tf`` (``tf2_msgs/msg/TFMessage``, the transform from a parent frame to a
  child frame composed within each message), the pressures from a
  ``sensor_msgs/msg/JointState`` topic (a field, by joint names or in order);
* :func:`read_qchain`: a qchain recording (tip poses, or the coordinates);
* :func:`read_csv`: a CSV file with a time column, position columns and pressure columns.

Every reader checks what it reads where it reads it: a topic that is not in the bag (the
error lists the topics it has, with their types), timestamps that go back, samples with
NaN (dropped, with a warning saying how many and when; all of them: an error), gaps longer
than ten median sample intervals (a warning), pressures that do not cover the measured span
(the samples outside it are dropped, said). :meth:`Measurements.check_model` refuses
measurements a model cannot mean (a point farther from the base than the arm reaches: units
that do not match), :meth:`Measurements.check_enough` too few numbers for the parameters asked.

Times: both streams on the bag's clock, shifted so that the first pressure sample is
``t = 0`` (the simulation starts there); ``start``/``stop`` (s on that shifted clock) cut a
window.
"""

from __future__ import annotations

import csv
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..recording.scenery import quat_mul, quat_rotate
from ..sim.inputs import Table

__all__ = ["Measurements", "MeasurementError", "MeasurementWarning", "read_bag", "read_qchain", "read_csv",
           "bag_topics", "beyond_reach", "pressure_noise", "filter_pressures", "coordinate_scale"]


class MeasurementError(ValueError):
    """Measurements that cannot be used as they are (the message says why and where)."""


class MeasurementWarning(UserWarning):
    """Measurements used with a part left out or a doubt (the message says which)."""


@dataclass(frozen=True)
class Measurements:
    """One experiment: measured samples and the pressures that drove the arm.

    Attributes
    ----------
    t : (K,) float, s
        Sample times, strictly increasing, on the pressures' clock (the first pressure sample
        at 0).
    points : (K, m, 3) float, m, world frame
        Measured positions of ``m`` points on the arm (``None`` when ``coordinates`` are
        measured instead).
    where : tuple of (int, float)
        Each point's ``(segment, alpha)``: 0-based segment, ``alpha`` in [0, 1] along it
        (``(-1, 1.0)``: the tip of the last segment, whatever the model's size).
    orientations : (K, 4) float or None
        The tip's measured orientation (x, y, z, w), world frame, when a pose was measured.
    coordinates : (K, nq) float or None
        Measured generalised coordinates (a qchain recording, or CSV columns): per segment
        ``(l, ux, uy)``, m, 1/m, 1/m.
    coordinate_scale : (nq,) float or float or None, m per coordinate unit
        What a coordinate's residual is multiplied by, so that it is a length comparable to a
        point's (a zero leaves that coordinate out). Default (:func:`coordinate_scale`): 1 for
        a segment's length ``l``, ``l0^2 / 2`` for its curvatures (the sideways move of the
        segment's tip that an error of the curvature causes alone: m), the coordinates the model
        holds (an inextensible segment's ``l``, a planar arm's ``uy``) left out.
    pressures : Table
        Chamber pressures (Pa), ``(3 n,)`` at each time, piecewise linear.
    source : str
        Where they were read from (file, topics, columns).
    """

    t: np.ndarray
    pressures: Table
    points: np.ndarray | None = None
    where: tuple = ((-1, 1.0),)
    orientations: np.ndarray | None = None
    coordinates: np.ndarray | None = None
    source: str = ""
    notes: list = field(default_factory=list)
    coordinate_scale: np.ndarray | float | None = None

    def __post_init__(self):
        t = np.asarray(self.t, dtype=float)
        if t.ndim != 1 or t.size == 0:
            raise MeasurementError(f"{self.source or 'measurements'}: no samples")
        _check_increasing("sample times", t, self.source)
        if self.points is None and self.coordinates is None:
            raise MeasurementError("measurements need points or coordinates")
        if self.points is not None:
            p = np.asarray(self.points, dtype=float)
            if p.shape != (t.size, len(self.where), 3):
                raise MeasurementError(f"points must have shape ({t.size}, {len(self.where)}, 3) (samples, points "
                                       f"at where, xyz), got {p.shape}")
            for seg, alpha in self.where:
                if not (isinstance(seg, (int, np.integer)) and 0.0 <= float(alpha) <= 1.0):
                    raise MeasurementError(f"where: each point is (segment, alpha) with alpha in [0, 1], got "
                                           f"{(seg, alpha)!r}")
        src = self.source or "measurements"
        if self.coordinates is not None:
            c = np.asarray(self.coordinates, dtype=float)
            if c.ndim != 2 or c.shape[0] != t.size or c.shape[1] == 0:
                raise MeasurementError(f"{src}: coordinates must have shape ({t.size}, nq) (samples, coordinates), "
                                       f"got {c.shape}")
            if not np.all(np.isfinite(c)):
                k, i = np.argwhere(~np.isfinite(c))[0]
                raise MeasurementError(f"{src}: coordinate {i} of sample {k} (t = {t[k]:.6g} s) is {float(c[k, i])!r}: "
                                       "measured coordinates must be finite (leave that sample out)")
            object.__setattr__(self, "coordinates", c)
        if self.coordinate_scale is not None:
            if self.coordinates is None:
                raise MeasurementError(f"{src}: coordinate_scale is given but no coordinates are measured")
            w = np.asarray(self.coordinate_scale, dtype=float)
            nq = self.coordinates.shape[1]
            if w.ndim == 0:
                w = np.full(nq, float(w))
            if w.shape != (nq,) or not np.all(np.isfinite(w)) or np.any(w < 0) or not np.any(w > 0):
                raise MeasurementError(f"{src}: coordinate_scale must be one number or {nq} (one a measured "
                                       f"coordinate), finite, >= 0 (m per coordinate unit; 0 leaves one out) and "
                                       f"not all 0, got {self.coordinate_scale!r}")
            object.__setattr__(self, "coordinate_scale", w)

    @property
    def n_samples(self) -> int:
        return int(self.t.size)

    @property
    def n_values(self) -> int:
        """The numbers measured (what a least-squares fit has as residuals)."""
        k = 0
        if self.points is not None:
            k += self.points.size
        if self.orientations is not None:
            k += 3 * self.t.size
        if self.coordinates is not None:
            k += self.coordinates.size
        return k

    @property
    def coordinate_index(self) -> np.ndarray:
        """The measured coordinates the residuals hold (those of nonzero ``coordinate_scale``;
        all when it is not set yet); empty without coordinates."""
        if self.coordinates is None:
            return np.zeros(0, dtype=int)
        if self.coordinate_scale is None:
            return np.arange(self.coordinates.shape[1])
        return np.flatnonzero(self.coordinate_scale > 0)

    @property
    def rows(self) -> int:
        """Residuals a sample: 3 a measured point, then one a used coordinate
        (:attr:`coordinate_index`); the orientations are not fitted."""
        return (0 if self.points is None else 3 * self.points.shape[1]) + self.coordinate_index.size

    @property
    def duration(self) -> float:
        """The time the simulation must cover (s): to the last sample."""
        return float(self.t[-1])

    def check_enough(self, n_parameters: int) -> None:
        """Refuse a fit of ``n_parameters`` from fewer measured numbers than twice that (a
        least-squares fit with as many residuals as unknowns has no standard errors)."""
        if self.n_values < 2 * n_parameters:
            raise MeasurementError(f"{self.source}: {self.n_samples} samples ({self.n_values} measured numbers) are "
                                   f"too few for {n_parameters} parameters: at least {2 * n_parameters} numbers "
                                   f"are needed; measure longer or fit fewer parameters")

    def check_model(self, chain, base_position=None, slack: float = 1.5) -> None:
        """Refuse measurements that the arm ``chain`` cannot mean: a measured point farther
        from the base than ``slack`` times the arm's length at full stretch (units that do not
        match, m against mm, or the wrong frame), pressures for another number of chambers.

        Parameters
        ----------
        chain : qchain.Chain
        base_position : (3,) m, optional
            The base's world position (default: the chain's base placement at t = 0).
        slack : float
            How much farther than the arm's rest length a point may be (stretching arms).
        """
        n_p = self.pressures.size
        if n_p != chain.nu:
            raise MeasurementError(f"{self.source}: {n_p} pressures a sample, the model has {chain.nu} chambers "
                                   f"({chain.n} segments x 3)")
        if self.coordinates is not None and self.coordinates.shape[1] != chain.nq:
            raise MeasurementError(f"{self.source}: {self.coordinates.shape[1]} coordinates a sample, the model has "
                                   f"nq = {chain.nq} ({chain.n} segments x (l, ux, uy))")
        if self.points is None:
            return
        for seg, _ in self.where:
            if not -chain.n <= seg < chain.n:
                raise MeasurementError(f"where: segment {seg} is not one of the model's {chain.n} segments")
        far = beyond_reach(chain, self.points, base_position, slack)
        if far is not None:
            k, j, d, reach = far
            raise MeasurementError(
                f"{self.source}: the measured point {j} is {d:.4g} m from the base at t = {self.t[k]:.6g} s, "
                f"and the arm is {reach:.4g} m long (at most {slack:g} x that is possible): units that do not match "
                "(mm for m?) or another frame than the base's world frame")


def coordinate_scale(chain, meas: Measurements) -> tuple[np.ndarray, list[str]]:
    """``meas``'s coordinate scale (nq,) m per unit for the model ``chain`` and the coordinates
    it leaves out because the model holds them (their names, :meth:`~qchain.Chain.coordinate_name`).

    The default scale: 1 for a segment's length ``l`` (m already), ``l0^2 / 2`` for each
    curvature ``ux``, ``uy`` (a curvature error ``du`` over a segment of rest length ``l0``
    moves its tip sideways by ``l0^2 du / 2`` to first order: the coordinate's residual becomes
    that length, comparable to a measured point's). ``meas.coordinate_scale``, when given,
    replaces it. Either way the coordinates the model holds still (``chain.active`` false: an
    inextensible segment's length, a planar arm's ``uy``) get 0: they are not free to fit.
    A floating base's coordinates are refused (the sensitivities do not take one)."""
    if chain.nq != chain.nv or chain.base == "floating":
        raise MeasurementError(f"{meas.source}: measured coordinates need a fixed or prescribed base (nq = nv), the "
                               f"model has base={chain.base!r}")
    if meas.coordinate_scale is not None:
        w = np.array(meas.coordinate_scale, dtype=float)
    else:
        l0 = np.array([s.length for s in chain.segments])
        w = np.column_stack([np.ones(chain.n), l0 ** 2 / 2, l0 ** 2 / 2]).reshape(-1)
    held = np.flatnonzero(~chain.active & (w > 0))
    w[~chain.active] = 0.0
    if not np.any(w > 0):
        raise MeasurementError(f"{meas.source}: coordinate_scale leaves no coordinate the model can move")
    return w, [chain.coordinate_name(int(i), velocity=False) for i in held]


def beyond_reach(chain, points: np.ndarray, base_position=None, slack: float = 1.5):
    """The measured point (K, m, 3) farthest from the base, as ``(sample, point, distance m,
    the arm's length m)``, when it is farther than ``slack`` times the arm's rest length; else None."""
    reach = sum(s.length for s in chain.segments)
    base = np.asarray(chain.base_placement.translation if base_position is None else base_position, float)
    d = np.linalg.norm(points - base, axis=-1)
    k, j = np.unravel_index(int(np.argmax(d)), d.shape)
    return (int(k), int(j), float(d[k, j]), reach) if d[k, j] > slack * reach else None


def pressure_noise(table: Table) -> np.ndarray:
    """Each chamber's pressure-sensor noise (standard deviation, Pa) estimated from the recorded
    samples themselves: the noise's white, the signal smooth at the sample rate.

    From fourth differences: a white noise of standard deviation ``s`` has fourth differences of
    standard deviation ``sqrt(70) s``, a signal of amplitude ``a`` and angular frequency ``w``
    sampled every ``dt`` fourth differences of at most ``a (w dt)^4`` (1 Pa for 10 kPa at 1.6 Hz
    and 100 Hz), so ``s = 1.4826 MAD(d4) / sqrt(70)`` (the MAD so that a few steps in the signal
    do not count as noise). Uneven sampling is taken as even (the differences of the values).

    Parameters
    ----------
    table : Table
        The pressures, (K, nu) Pa at K >= 6 samples.

    Returns
    -------
    (nu,) float, Pa
    """
    v = np.asarray(table.values, dtype=float)
    if v.shape[0] < 6:
        raise MeasurementError(f"pressure_noise: {v.shape[0]} pressure samples, at least 6 are needed")
    d4 = np.diff(v, n=4, axis=0)
    mad = np.median(np.abs(d4 - np.median(d4, axis=0)), axis=0)
    return 1.4826 * mad / np.sqrt(70.0)


def filter_pressures(table: Table, cutoff: float) -> Table:
    """The pressures low-passed without delay: a 4th-order Butterworth filter run forwards and
    backwards (``scipy.signal.sosfiltfilt``) at ``cutoff`` Hz on the table's median sample
    interval (uneven sampling is taken as even).

    The arm's own dynamics low-pass its input, so a cutoff above the arm's bandwidth (and the
    drive's frequencies) changes the motion little and removes the sensor noise above it.

    Parameters
    ----------
    table : Table
        (K, nu) Pa.
    cutoff : float, Hz
        In (0, Nyquist), Nyquist being half the sample rate.
    """
    from scipy.signal import butter, sosfiltfilt

    t = np.asarray(table.times, dtype=float)
    nyq = 0.5 / float(np.median(np.diff(t)))
    c = float(cutoff)
    if not (np.isfinite(c) and 0.0 < c < nyq):
        raise MeasurementError(f"pressure_filter: cutoff {cutoff!r} Hz must lie in (0, {nyq:.6g}) Hz (the pressures' "
                               f"Nyquist frequency, half their sample rate)")
    sos = butter(4, c / nyq, output="sos")
    if t.size <= 3 * (2 * sos.shape[0] + 1):
        raise MeasurementError(f"pressure_filter: {t.size} pressure samples are too few to filter (more than "
                               f"{3 * (2 * sos.shape[0] + 1)} are needed)")
    return Table(t, sosfiltfilt(sos, np.asarray(table.values, dtype=float), axis=0))


def _check_increasing(what: str, t: np.ndarray, source: str) -> None:
    if not np.all(np.isfinite(t)):
        k = int(np.flatnonzero(~np.isfinite(t))[0])
        raise MeasurementError(f"{source}: {what}: sample {k} has no time ({t[k]!r})")
    d = np.diff(t)
    if np.any(~(d > 0)):
        k = int(np.flatnonzero(~(d > 0))[0])
        how = "go back" if d[k] < 0 else "repeat"
        raise MeasurementError(f"{source}: {what} {how}: sample {k + 1} at {float(t[k + 1]):.6f} s after sample {k} "
                               f"at {float(t[k]):.6f} s (timestamps must increase: a recorder restarted or two "
                               "streams mixed?)")


def _drop_nonfinite(t: np.ndarray, values: list[np.ndarray], what: str, source: str):
    """Drop samples with a non-finite value (warning how many and when); all of them: error."""
    bad = np.zeros(t.size, bool)
    for v in values:
        if v is not None:
            bad |= ~np.all(np.isfinite(v.reshape(t.size, -1)), axis=1)
    if bad.all():
        raise MeasurementError(f"{source}: every {what} sample has a NaN or infinite value")
    if bad.any():
        k = np.flatnonzero(bad)
        warnings.warn(f"{source}: {k.size} of {t.size} {what} samples have NaN or infinite values and are left out "
                      f"(the first at t = {t[k[0]]:.6g} s)", MeasurementWarning, stacklevel=3)
    keep = ~bad
    return t[keep], [None if v is None else v[keep] for v in values]


def _warn_gaps(t: np.ndarray, what: str, source: str) -> None:
    if t.size < 3:
        return
    d = np.diff(t)
    med = float(np.median(d))
    big = np.flatnonzero(d > 10.0 * med)
    if big.size:
        k = int(big[np.argmax(d[big])])
        warnings.warn(f"{source}: {big.size} gaps in the {what} samples longer than 10 x their median interval "
                      f"({med:.3g} s); the longest {d[k]:.4g} s after t = {t[k]:.6g} s", MeasurementWarning,
                      stacklevel=3)


def _assemble(t_meas, points, orientations, coordinates, t_p, p, where, source, start, stop) -> Measurements:
    """Check both streams, put them on the pressures' clock (first pressure sample = 0), cut
    the window and the samples the pressures do not cover."""
    t_p = np.asarray(t_p, dtype=float)
    p = np.asarray(p, dtype=float)
    if t_p.size < 2:
        raise MeasurementError(f"{source}: {t_p.size} pressure samples: at least 2 are needed")
    _check_increasing("pressure timestamps", t_p, source)
    t_meas = np.asarray(t_meas, dtype=float)
    if t_meas.size == 0:
        raise MeasurementError(f"{source}: no measured samples")
    _check_increasing("measurement timestamps", t_meas, source)
    t0 = t_p[0]  # the clock's origin: the first pressure sample
    t_p, t_meas = t_p - t0, t_meas - t0
    t_p, (p,) = _drop_nonfinite(t_p, [p], "pressure", source)
    t_meas, (points, orientations, coordinates) = _drop_nonfinite(t_meas, [points, orientations, coordinates],
                                                                  "measured", source)
    lo = 0.0 if start is None else float(start)
    hi = t_p[-1] if stop is None else min(float(stop), t_p[-1])
    inside = (t_meas >= lo) & (t_meas <= hi)
    if not inside.any():
        raise MeasurementError(f"{source}: no measured sample lies within the pressures' span [{lo:.6g}, {hi:.6g}] s "
                               f"(measured from {t_meas[0]:.6g} to {t_meas[-1]:.6g} s on the same clock)")
    if (~inside).sum() and start is None and stop is None:
        warnings.warn(f"{source}: {(~inside).sum()} measured samples outside the pressures' span [0, {hi:.6g}] s are "
                      "left out", MeasurementWarning, stacklevel=3)
    sel = lambda a: None if a is None else a[inside]  # noqa: E731
    t_meas, points, orientations, coordinates = t_meas[inside], sel(points), sel(orientations), sel(coordinates)
    if lo > 0.0:  # the window starts later: the simulation starts at its first pressure sample
        k = max(int(np.searchsorted(t_p, lo, side="right")) - 1, 0)
        t_p, p, t_meas = t_p[k:] - t_p[k], p[k:], t_meas - t_p[k]
    _warn_gaps(t_meas, "measured", source)
    _warn_gaps(t_p, "pressure", source)
    return Measurements(t=t_meas, pressures=Table(t_p, p), points=points, where=tuple(where),
                        orientations=orientations, coordinates=coordinates, source=source)


# --------------------------------------------------------------------------------------
# ROS 2 bags
# --------------------------------------------------------------------------------------


def _bag_reader(path):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(path)
    if not path.exists():
        raise MeasurementError(f"{path}: no such bag (a .mcap or .db3 file, or a bag folder)")
    return AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))


def bag_topics(path) -> dict[str, str]:
    """The topics of a ROS 2 bag and their message types."""
    with _bag_reader(path) as reader:
        return {c.topic: c.msgtype for c in reader.connections}


def _stamp_s(header, log_time_ns: int) -> float:
    s = header.stamp.sec + 1e-9 * header.stamp.nanosec
    return s if s > 0 else 1e-9 * log_time_ns  # a zero header stamp: the recorder's time


def read_bag(path, *, pressure_topic: str, pose_topic: str | None = None,
             tf: tuple[str, str] | None = None, pressure_field: str = "effort",
             pressure_names: list[str] | None = None, where=((-1, 1.0),), orientation: bool = False,
             start: float | None = None, stop: float | None = None) -> Measurements:
    """One experiment from a ROS 2 bag.

    Parameters
    ----------
    path : path
        An ``.mcap`` or ``.db3`` file, or a bag folder (``metadata.yaml``).
    pressure_topic : str
        A ``sensor_msgs/msg/JointState`` topic carrying the chamber pressures (Pa).
    pose_topic : str, optional
        A ``geometry_msgs/msg/PoseStamped`` topic: the measured tip (or the one point of
        ``where``), world frame, m.
    tf : (parent, child), optional
        Instead of ``pose_topic``: the transform from ``parent`` (the world) to ``child`` (the
        tip frame) in ``/tf``, composed within each ``tf2_msgs/msg/TFMessage`` (a qchain bag:
        ``("world", "segment_3_tip")``).
    pressure_field : {"effort", "position", "velocity"}
        The JointState field holding the pressures.
    pressure_names : list of str, optional
        Their joint names, in the model's chamber order (default: the message's order).
    where : sequence of (int, float)
        The measured point's ``(segment, alpha)`` (default the tip).
    orientation : bool
        Keep the measured orientation too.
    start, stop : float, optional, s
        A window on the pressures' clock.
    """
    if (pose_topic is None) == (tf is None):
        raise MeasurementError("read_bag: give pose_topic (PoseStamped) or tf=(parent, child), one of them")
    if pressure_field not in ("effort", "position", "velocity"):
        raise MeasurementError(f"pressure_field must be 'effort', 'position' or 'velocity', got {pressure_field!r}")
    source = f"{path}"
    with _bag_reader(path) as reader:
        topics = {c.topic: c.msgtype for c in reader.connections}
        listing = ", ".join(f"{t} ({ty})" for t, ty in sorted(topics.items())) or "none"

        def conns(topic: str, types: tuple[str, ...]):
            if topic not in topics:
                raise MeasurementError(f"{source}: no topic {topic!r}; the bag has: {listing}")
            if topics[topic] not in types:
                raise MeasurementError(f"{source}: topic {topic!r} is {topics[topic]}, expected {' or '.join(types)}")
            return [c for c in reader.connections if c.topic == topic]

        pc = conns(pressure_topic, ("sensor_msgs/msg/JointState",))
        mc = conns(pose_topic, ("geometry_msgs/msg/PoseStamped",)) if pose_topic else \
            conns("/tf", ("tf2_msgs/msg/TFMessage",))
        t_p, p, names0 = [], [], None
        for conn, lt, raw in reader.messages(connections=pc):
            msg = reader.deserialize(raw, conn.msgtype)
            names = list(msg.name)
            vals = np.asarray(getattr(msg, pressure_field), dtype=float)
            if pressure_names is not None:
                missing = [nm for nm in pressure_names if nm not in names]
                if missing or vals.size != len(names):
                    why = f"no joint {missing[0]!r}" if missing else f"{vals.size} values for {len(names)} names"
                    raise MeasurementError(f"{source}: {pressure_topic} at t = {_stamp_s(msg.header, lt):.6g} s has "
                                           f"{why}; its names: {names}")
                vals = vals[[names.index(nm) for nm in pressure_names]]
            if names0 is None:
                names0 = names
                width = vals.size
            if vals.size != width:
                raise MeasurementError(f"{source}: {pressure_topic} has {vals.size} values in {pressure_field!r} at "
                                       f"t = {_stamp_s(msg.header, lt):.6g} s and {width} before")
            t_p.append(_stamp_s(msg.header, lt))
            p.append(vals)
        if not p or width == 0:
            raise MeasurementError(f"{source}: {pressure_topic} holds no pressures in its {pressure_field!r} field")
        t_m, pos, quat = [], [], []
        for conn, lt, raw in reader.messages(connections=mc):
            msg = reader.deserialize(raw, conn.msgtype)
            if pose_topic:
                t_m.append(_stamp_s(msg.header, lt))
                pp, oo = msg.pose.position, msg.pose.orientation
                pos.append([pp.x, pp.y, pp.z])
                quat.append([oo.x, oo.y, oo.z, oo.w])
            else:
                found = _compose_tf(msg.transforms, *tf)
                if found is not None:
                    (x, q), header = found
                    t_m.append(_stamp_s(header, lt))
                    pos.append(x)
                    quat.append(q)
        if not t_m:
            what = f"{pose_topic}" if pose_topic else f"/tf: no message holds the chain {tf[0]!r} -> {tf[1]!r}"
            frames = "" if pose_topic else f" (its frames: {sorted(_tf_frames(reader, mc))})"
            raise MeasurementError(f"{source}: no pose in {what}{frames}")
    if len(where) != 1:
        raise MeasurementError(f"a pose topic measures one point, got where = {where!r}")
    pos = np.asarray(pos, dtype=float)[:, None, :]
    quat = np.asarray(quat, dtype=float) if orientation else None
    src = f"{source} ({pose_topic or 'tf ' + ' -> '.join(tf)}, pressures {pressure_topic}.{pressure_field})"
    return _assemble(t_m, pos, quat, None, t_p, np.asarray(p), where, src, start, stop)


def _tf_frames(reader, conns) -> set[str]:
    frames: set[str] = set()
    for k, (conn, _, raw) in enumerate(reader.messages(connections=conns)):
        msg = reader.deserialize(raw, conn.msgtype)
        for tr in msg.transforms:
            frames |= {tr.header.frame_id, tr.child_frame_id}
        if k > 50:
            break
    return frames


def _compose_tf(transforms, parent: str, child: str):
    """The placement of ``child`` in ``parent`` from one message's transforms (a path of
    child -> parent links), with the header of the last link; None if they do not join."""
    up = {tr.child_frame_id: tr for tr in transforms}
    chain = []
    frame = child
    while frame != parent:
        tr = up.get(frame)
        if tr is None or len(chain) > len(transforms):
            return None
        chain.append(tr)
        frame = tr.header.frame_id
    x, q = np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])
    for tr in reversed(chain):  # parent first: X = X_parent * X_link
        r, p = tr.transform.rotation, tr.transform.translation
        x = x + quat_rotate(q, np.array([p.x, p.y, p.z]))
        q = quat_mul(q, [r.x, r.y, r.z, r.w])
    return (x, q), chain[0].header if chain else transforms[0].header


# --------------------------------------------------------------------------------------
# qchain recordings and CSV
# --------------------------------------------------------------------------------------


def read_qchain(path, *, measure: str = "tip", start: float | None = None, stop: float | None = None,
                limits=None, coordinate_scale=None) -> Measurements:
    """One experiment from a qchain recording: ``measure`` ``"tip"`` (the last tip's position
    and orientation) or ``"coordinates"`` (q, with ``coordinate_scale`` as
    :class:`Measurements` says); the pressures as recorded."""
    from dataclasses import replace

    from ..recording.reader import read_recording

    if measure not in ("tip", "coordinates"):
        raise MeasurementError(f"measure must be 'tip' or 'coordinates', got {measure!r}")
    rec = read_recording(path, limits=limits)
    src = f"{path} ({measure})"
    if measure == "tip":
        tip = rec.tip_frames[:, -1]
        return _assemble(rec.t, tip[:, None, :3], tip[:, 3:], None, rec.t, rec.p, ((-1, 1.0),), src, start, stop)
    m = _assemble(rec.t, None, None, rec.q, rec.t, rec.p, ((-1, 1.0),), src, start, stop)
    return m if coordinate_scale is None else replace(m, coordinate_scale=coordinate_scale)


def read_csv(path, *, time: str = "t", points: list[tuple[str, str, str]] | None = None,
             where=((-1, 1.0),), pressures: list[str], scale: float = 1.0, start: float | None = None,
             stop: float | None = None, coordinates: list[str] | None = None,
             coordinate_scale=None) -> Measurements:
    """One experiment from a CSV file with a header row: a time column (s), the measured
    points' x, y, z columns (``points``: one triple of column names a point, in ``where``'s
    order; ``scale`` multiplies them, e.g. 1e-3 for mm) and/or the measured coordinates'
    columns (``coordinates``: one a coordinate of ``q``, in its order, SI units; weighted by
    ``coordinate_scale`` as :class:`Measurements` says), the pressure columns (Pa), all on
    one clock and one row a sample (empty cells are NaN: that sample is left out, said)."""
    from dataclasses import replace

    path = Path(path)
    ccols = list(coordinates or [])
    cols = [time] + [c for triple in (points or []) for c in triple] + ccols + list(pressures)
    data = csv_columns(path, cols, empty=math.nan)
    t = data[:, 0]
    npts = len(points or [])
    pts = data[:, 1:1 + 3 * npts].reshape(len(t), npts, 3) * float(scale) if npts else None
    at = 1 + 3 * npts
    q = data[:, at:at + len(ccols)] if ccols else None
    p = data[:, at + len(ccols):]
    if pts is None and q is None:
        raise MeasurementError(f"{path}: no measured columns (points= or coordinates=)")
    m = _assemble(t, pts, None, q, t, p, where, f"{path}", start, stop)
    return m if coordinate_scale is None else replace(m, coordinate_scale=coordinate_scale)


def csv_columns(path, cols: list[str], *, empty: float | None = None) -> np.ndarray:
    """(rows, len(cols)) float: the named columns of a CSV file with a header row, one row a
    line after it. An empty cell reads as ``empty`` (refused, naming its line and column, when
    None); a cell that is not a number is refused the same way; a missing column lists those
    the file has."""
    path = Path(path)
    try:
        with open(path, newline="") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise MeasurementError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if len(rows) < 2:
        raise MeasurementError(f"{path}: no header row and data rows")
    header = [h.strip() for h in rows[0]]
    missing = [c for c in cols if c not in header]
    if missing:
        raise MeasurementError(f"{path}: no column {missing[0]!r}; the columns: {header}")
    idx = [header.index(c) for c in cols]

    def num(cell: str, r: int, c: str) -> float:
        cell = cell.strip()
        if cell == "" and empty is not None:
            return empty
        try:
            return float(cell)
        except ValueError:
            raise MeasurementError(f"{path}: line {r + 1}, column {c!r}: {cell[:20]!r} is not a number") from None

    return np.array([[num(row[i] if i < len(row) else "", r, c) for i, c in zip(idx, cols)]
                     for r, row in enumerate(rows[1:], start=1)], dtype=float).reshape(len(rows) - 1, len(cols))
