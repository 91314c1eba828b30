"""Run logging: one record a simulation step, to an MCAP file and to a Rerun viewer.

The simulation hands :class:`RunLogger` one :class:`StepRecord` a step (``log()``), or many
at once as columns (``log_columns()``) or as rows of float64 numbers (``log_rows()``, see
:class:`RecordLayout`); :class:`qchain.recorder.ChainRecorder` does the latter for
:func:`qchain.simulate`, computing the frames of a batch of samples in one compiled call.
Logging only packs records into rows of bytes (microseconds); the encoding and the I/O
happen away from the simulation. By default that is a separate writer process (the *process* worker: its
own interpreter, so it takes no time from the simulating process's GIL and runs on another
core), fed through a pipe; with an in-memory stream as the MCAP target it is a background
thread (the *thread* worker). Both queues are bounded (the pipe, 1 MiB, and a 64 KiB buffer
in the simulating process; the thread's queue holds ``max_queue`` records), so memory stays
flat on long runs: when the writer falls behind, ``log()`` waits rather than dropping
records. ``flush()`` waits until everything logged so far is in the files.

Sinks
-----
MCAP (always on by default)
    One JSON channel per quantity with a JSON schema, zstd-compressed chunks, ``log_time``
    = simulation time in ns, ``sequence`` = step:

    ==========================  =============================  =============================
    topic                       schema                         payload
    ==========================  =============================  =============================
    ``/qchain/q``               ``qchain.Coordinates``         ``{t, step, q: [nq]}``
    ``/qchain/v``               ``qchain.Velocities``          ``{t, step, v: [nv]}``
    ``/qchain/p``               ``qchain.ChamberPressures``    ``{t, step, p: [3n]}`` (Pa)
    ``/qchain/energy``          ``qchain.Energy``              ``{t, step, kinetic, potential,
                                                               total}`` (J)
    ``/qchain/tip_frames``      ``foxglove.FrameTransforms``   ``world`` -> ``segment_<i>_tip``
    ``/qchain/backbone``        ``foxglove.SceneUpdate``       one line strip a segment, its
                                                               thickness = segment diameter
    ==========================  =============================  =============================

    ``t`` is repeated in every payload as a JSON number (shortest round-trip form), so it
    reads back bit for bit; ``log_time`` is ``round(t * 1e9)``. Non-finite numbers are
    written as JSON ``null`` and read back as NaN. A metadata record ``qchain`` carries the
    scene text, the model parameters (JSON), the qchain version, the segment count and
    radii; a metadata record ``qchain.outcome`` written when the log is closed says how the
    run ended. Foxglove shows the arm from ``/qchain/backbone`` and the tip frames.

    Chunks are closed (compressed and written to the operating system) every
    ``flush_interval`` seconds of simulation time (default 0.25 s), every
    ``flush_wall_interval`` seconds of wall time (default 0.5 s) and every 4 MiB.

Crash safety
    Leaving the ``with RunLogger(...)`` block normally, by an exception or by Ctrl-C
    (KeyboardInterrupt) finishes the MCAP (summary and ``qchain.outcome`` written; the
    exception's text is the outcome message). Ctrl-C in a terminal reaches only the
    simulation: the writer runs in its own process group, and SIGINT is held back while a
    frame is written to the pipe, so the stream is never cut mid-record. If the simulating
    process is killed (SIGKILL), the writer sees its pipe close and still finishes the file,
    with an outcome saying so. If the writer is killed too, the file is readable up to its
    last closed chunk. A record waits at most ``flush_interval`` of simulation time (or
    50 ms of wall time) in the simulating process (the buffer of ``log()`` holds
    ``flush_interval / 2``; :class:`~qchain.recorder.ChainRecorder` a batch of up to
    ``flush_interval``), ``flush_interval / 2`` in the writer's batch and ``flush_interval``
    in the open chunk. So at default settings a SIGKILL of the simulation loses at most
    0.25 s of simulation time, and one of both processes at most about
    ``2.5 * flush_interval`` = 0.6 s, while the writer keeps up. A smaller
    ``flush_interval`` loses less and costs more: each batch of the recorder costs the
    simulating process a fixed ~0.15-0.2 ms, and each chunk the writer ~0.1-0.3 ms.

Rerun (``serve``, ``connect``, ``rrd``)
    ``serve=True`` hosts a gRPC server with ``rr.GrpcServerSink`` bound to ``bind``
    (default ``127.0.0.1``) and serves the Rerun web viewer, also on ``bind`` (the
    ``rerun`` program shipped in the rerun-sdk wheel, ``--serve-web --bind``), and prints
    the URL to open. ``connect=URL`` streams to a viewer the user already runs;
    ``rrd=PATH`` writes a ``.rrd`` file. A blueprint puts the 3D arm (backbone as tubes of
    the segments' radii, tip axes, chamber pressures as arrows on the tip plates, length
    and colour by pressure) beside time series of the pressures, coordinates, velocities and
    energies. Per-step data go on the ``sim_time`` (duration) and ``step`` (sequence)
    timelines in column batches (``send_columns``), gathered for ``rerun_latency`` (0.2 s)
    of wall time: a batch costs the writer ~2-4 ms whatever its size, and a record ~10 us
    more. The first batch goes at once: it starts Rerun's recording. If a viewer cannot be
    reached, one :class:`LoggingWarning` says so and the run goes on; the MCAP is still
    written.

Replay
------
:func:`read_mcap` reads a recording back as a :class:`qchain.trajectory.Trajectory`;
:func:`replay` re-logs it into Rerun with its original times; :func:`replay_main` is the
``qchain replay LOG.mcap [--serve | --connect URL | --rrd OUT]`` command. Reading parses
JSON only: nothing in a file is executed.

Command line
------------
:func:`add_logging_arguments` adds ``--mcap OUT``, ``--serve``, ``--connect URL`` and
``--rrd OUT`` to a parser; :func:`logger_from_args` builds the logger. Without flags a run
records to ``runs/<scene-stem>-<YYYYmmdd-HHMMSS>.mcap`` (:func:`default_mcap_path`).

This module knows no dynamics: it never imports the simulation.
"""

from __future__ import annotations

import argparse
import atexit
import datetime as _dt
import json
import math
import operator
import os
import queue
import select
import signal
import _signal
import socket
import struct
import subprocess
import sys
import threading
import time
import uuid
import warnings
import zlib
import weakref
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO
from urllib.parse import quote, urlsplit

import numpy as np

from . import __version__
from .errors import QchainError
from .spatial import quaternion_to_rotation
from .trajectory import Trajectory

__all__ = [
    "StepRecord",
    "RecordLayout",
    "RunInfo",
    "RunLogger",
    "LoggingError",
    "RecordingFormatError",
    "LoggingWarning",
    "Recording",
    "read_recording",
    "read_mcap",
    "replay",
    "ReplaySession",
    "replay_main",
    "add_logging_arguments",
    "logger_from_args",
    "default_mcap_path",
    "prepare_writer",
    "TOPICS",
    "DEFAULT_FLUSH_INTERVAL",
    "DEFAULT_FLUSH_WALL_INTERVAL",
]

FORMAT_NAME = "qchain-mcap"
FORMAT_VERSION = 1

#: MCAP topic of each logged quantity.
TOPICS = {
    "q": "/qchain/q",
    "v": "/qchain/v",
    "p": "/qchain/p",
    "energy": "/qchain/energy",
    "tip_frames": "/qchain/tip_frames",
    "backbone": "/qchain/backbone",
}

#: Seconds of simulation time between forced MCAP chunk flushes (and the longest a
#: ChainRecorder's batch spans): what a SIGKILL of the simulating process loses at most.
DEFAULT_FLUSH_INTERVAL = 0.25
#: Seconds of wall time between forced MCAP chunk flushes.
DEFAULT_FLUSH_WALL_INTERVAL = 0.5
#: Uncompressed bytes after which a chunk is flushed regardless of time.
DEFAULT_CHUNK_BYTES = 4 << 20
#: Records the queue between ``log()`` and the writer holds before ``log()`` waits.
DEFAULT_MAX_QUEUE = 4096
#: Wall time (s) records gather in the writer before they go to Rerun in one batch.
DEFAULT_RERUN_LATENCY = 0.2

# s the writer process pauses between two reads of its pipe when it is idle: a record's
# write does not wake it; a flush or the end does (its doorbell, _launch_writer)
_WRITER_POLL = 0.01
DEFAULT_BIND = "127.0.0.1"
DEFAULT_GRPC_PORT = 9876
DEFAULT_WEB_PORT = 9090

#: Segment colours (RGB) of the arm in Rerun and Foxglove, cycled along the chain.
SEGMENT_COLORS = ((255, 140, 0), (230, 95, 0), (255, 185, 50))


class LoggingError(QchainError):
    """The run log could not be written (a writer that cannot start, a bad output path)."""


class RecordingFormatError(LoggingError, ValueError):
    """A file that is not a (readable) qchain MCAP recording; the message names the file."""


class LoggingWarning(UserWarning):
    """Something of the logging did not work out (a viewer out of reach); the run goes on."""


# --------------------------------------------------------------------------------------
# Records and run information
# --------------------------------------------------------------------------------------


@dataclass
class StepRecord:
    """The state of the arm at one simulation step, as the logger takes it.

    Attributes
    ----------
    t : float, s
        Simulation time, finite and >= 0.
    step : int
        Step counter (>= 0), also the MCAP ``sequence`` (modulo 2**32).
    q : (nq,) array
        Generalised coordinates, in the chain's layout.
    v : (nv,) array
        Velocities.
    p : (3 n,) array, Pa
        Chamber pressures, segment by segment, chambers 1..3.
    kinetic, potential, total : float, J
        Energies; potential = gravity + elastic, total = kinetic + potential.
    backbone : (n, P, 3) array, m
        World points along each segment's axis, from its root to its tip.
    tip_frames : (n, 7) array
        World placement of each segment's tip frame as ``(x, y, z, qx, qy, qz, qw)`` (m and
        a unit quaternion, scalar last).

    Arrays may be reused by the caller after ``log()`` returns: the logger copies them.
    Every record of a run must have the shapes of the first one.
    """

    t: float
    step: int
    q: np.ndarray
    v: np.ndarray
    p: np.ndarray
    kinetic: float
    potential: float
    total: float
    backbone: np.ndarray
    tip_frames: np.ndarray


def _jsonable(value: Any, where: str) -> Any:
    """``value`` as plain JSON types (numpy arrays and scalars, tuples and paths
    converted); ``ValueError`` naming ``where`` for anything else."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value)
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist(), where)
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise ValueError(f"{where} keys must be strings, got {k!r}")
            out[k] = _jsonable(v, f"{where}[{k!r}]")
        return out
    if isinstance(value, (list, tuple)):
        return [_jsonable(v, f"{where}[{i}]") for i, v in enumerate(value)]
    raise ValueError(
        f"{where} must hold only JSON-like values (numbers, strings, lists, dicts, numpy "
        f"arrays), got {type(value).__name__}: {value!r}"
    )


@dataclass(kw_only=True)
class RunInfo:
    """Static information about a run, recorded once.

    Attributes
    ----------
    n_segments : int
        Number of segments ``n`` of the arm.
    radii : (n,) sequence of float, m
        Segment radii, used to draw the backbone as tubes.
    scene : str
        The scene text (e.g. the TOML file's content); may be empty.
    scene_path : str or None
        Where the scene came from, for the record and for default file names.
    params : dict
        Model parameters; JSON-like values only (numpy arrays become lists).
    qchain_version : str
        Defaults to ``qchain.__version__``.
    chamber_radii : (n,) sequence of float or None, m
        Distance of the chambers from the axis, for drawing the pressure arrows; ``None``
        draws them at 0.6 x the segment radius.
    chamber_angles : (3,) sequence of float, rad
        Angular positions of chambers 1..3 about a tip frame's z axis, from its x axis.
    pressure_ref : float, Pa
        Pressure drawn as an arrow half a segment long.
    name : str
        Run name (the Rerun recording name).
    """

    n_segments: int
    radii: Sequence[float]
    scene: str = ""
    scene_path: str | None = None
    params: dict = field(default_factory=dict)
    qchain_version: str = __version__
    chamber_radii: Sequence[float] | None = None
    chamber_angles: Sequence[float] = (0.0, 2.0 * math.pi / 3.0, -2.0 * math.pi / 3.0)
    pressure_ref: float = 1.0e5
    name: str = "qchain run"

    def __post_init__(self) -> None:
        if isinstance(self.n_segments, bool) or not isinstance(self.n_segments, (int, np.integer)):
            raise ValueError(f"n_segments must be an int >= 1, got {self.n_segments!r}")
        if self.n_segments < 1:
            raise ValueError(f"n_segments must be >= 1, got {self.n_segments}")
        self.n_segments = int(self.n_segments)
        self.radii = [float(r) for r in self._vector("radii", self.radii, self.n_segments)]
        if self.chamber_radii is not None:
            self.chamber_radii = [
                float(r) for r in self._vector("chamber_radii", self.chamber_radii, self.n_segments)
            ]
        angles = np.asarray(self.chamber_angles, dtype=float)
        if angles.shape != (3,) or not np.all(np.isfinite(angles)):
            raise ValueError(f"chamber_angles must be 3 finite angles (rad), got {self.chamber_angles!r}")
        self.chamber_angles = [float(a) for a in angles]
        if not (math.isfinite(float(self.pressure_ref)) and float(self.pressure_ref) > 0.0):
            raise ValueError(f"pressure_ref must be > 0 Pa, got {self.pressure_ref!r}")
        self.pressure_ref = float(self.pressure_ref)
        if not isinstance(self.scene, str):
            raise ValueError(f"scene must be a str (the scene text), got {type(self.scene).__name__}")
        if self.scene_path is not None:
            self.scene_path = os.fspath(self.scene_path)
        if not isinstance(self.params, dict):
            raise ValueError(f"params must be a dict, got {type(self.params).__name__}")
        self.params = _jsonable(self.params, "params")
        self.qchain_version = str(self.qchain_version)
        self.name = str(self.name)

    @staticmethod
    def _vector(name: str, value, n: int) -> np.ndarray:
        arr = np.asarray(value, dtype=float)
        if arr.shape != (n,):
            raise ValueError(f"{name} must have shape ({n},) (one a segment), got shape {arr.shape}")
        if not np.all(np.isfinite(arr)) or np.any(arr <= 0.0):
            raise ValueError(f"{name} must be finite and > 0 m, got {arr.tolist()}")
        return arr

    def to_json(self) -> dict:
        """The information as a JSON-ready dict (inverse of :meth:`from_json`)."""
        return {
            "n_segments": self.n_segments,
            "radii": list(self.radii),
            "scene": self.scene,
            "scene_path": self.scene_path,
            "params": self.params,
            "qchain_version": self.qchain_version,
            "chamber_radii": None if self.chamber_radii is None else list(self.chamber_radii),
            "chamber_angles": list(self.chamber_angles),
            "pressure_ref": self.pressure_ref,
            "name": self.name,
        }

    @classmethod
    def from_json(cls, data: dict) -> RunInfo:
        """Rebuild from :meth:`to_json` output; unknown keys are ignored."""
        known = {k: data[k] for k in cls.__dataclass_fields__ if k in data}
        return cls(**known)


# --------------------------------------------------------------------------------------
# Row layout: how a record is packed into one float64 row
# --------------------------------------------------------------------------------------

_HEAD = struct.Struct("<2d")  # t, step (as float64: a row is all float64)
_ENERGY = struct.Struct("<3d")  # kinetic, potential, total
_T = struct.Struct("<d")  # t, at the start of a packed record
_F8 = np.dtype(np.float64)
# _signal's pthread_sigmask: signal's converts its answer to enums, costing more than the write it guards
_sigmask = getattr(_signal, "pthread_sigmask", None)  # None where not POSIX
_SIGINT_SET = {int(signal.SIGINT)}
_FRAME = struct.Struct("<cI")  # kind, payload length
# frame kinds; a record frame holds one or more rows of a RecordLayout
_FRAME_RECORD, _FRAME_LAYOUT, _FRAME_END, _FRAME_CONFIG, _FRAME_FLUSH = b"R", b"L", b"E", b"C", b"F"
_COLUMNS = ("step", "q", "v", "p", "kinetic", "potential", "total", "backbone", "tip_frames")


@dataclass(frozen=True)
class RecordLayout:
    """A step record as one row of float64 numbers, the form records travel in.

    The row holds, in this order, ``t`` (s), ``step`` (an integer value), ``q`` (nq),
    ``v`` (nv), ``p`` (n_p, Pa), ``kinetic``, ``potential``, ``total`` (J), the backbone
    (n x P x 3, m, row-major) and the tip frames (n x 7: x, y, z, qx, qy, qz, qw): the fields
    of :class:`StepRecord` flattened. :attr:`slices` says where each field is.

    Attributes
    ----------
    nq, nv, n_p : int
        Lengths of q, v and p.
    n : int
        Segments.
    P : int
        Backbone points a segment.
    """

    nq: int
    nv: int
    n_p: int
    n: int
    P: int

    @property
    def row_width(self) -> int:
        """Numbers in a row."""
        return 2 + self.nq + self.nv + self.n_p + 3 + self.n * self.P * 3 + self.n * 7

    @property
    def slices(self) -> dict[str, slice]:
        """Field name -> its columns in a row (``t``, ``step``, ``q``, ``v``, ``p``,
        ``energy`` (kinetic, potential, total), ``backbone``, ``tip_frames``)."""
        sizes = (("t", 1), ("step", 1), ("q", self.nq), ("v", self.nv), ("p", self.n_p), ("energy", 3),
                 ("backbone", self.n * self.P * 3), ("tip_frames", self.n * 7))
        out, a = {}, 0
        for name, size in sizes:
            out[name] = slice(a, a + size)
            a += size
        return out

    def to_json(self) -> dict:
        return {"nq": self.nq, "nv": self.nv, "np": self.n_p, "n": self.n, "P": self.P}

    @classmethod
    def from_json(cls, d: dict) -> RecordLayout:
        return cls(int(d["nq"]), int(d["nv"]), int(d["np"]), int(d["n"]), int(d["P"]))


@dataclass
class _Batch:
    """K records, stacked: t (K,), step (K,), q (K, nq), v (K, nv), p (K, 3n),
    energy (K, 3) = (kinetic, potential, total), backbone (K, n, P, 3), tip_frames (K, n, 7)."""

    t: np.ndarray
    step: np.ndarray
    q: np.ndarray
    v: np.ndarray
    p: np.ndarray
    energy: np.ndarray
    backbone: np.ndarray
    tip_frames: np.ndarray

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @classmethod
    def from_rows(cls, rows: np.ndarray, lay: RecordLayout) -> _Batch:
        """From rows (K, lay.row_width)."""
        K = rows.shape[0]
        sl = lay.slices
        col = lambda name: np.ascontiguousarray(rows[:, sl[name]])  # noqa: E731
        return cls(
            t=col("t")[:, 0],
            step=col("step")[:, 0].astype(np.int64),
            q=col("q"),
            v=col("v"),
            p=col("p"),
            energy=col("energy"),
            backbone=col("backbone").reshape(K, lay.n, lay.P, 3),
            tip_frames=col("tip_frames").reshape(K, lay.n, 7),
        )

    @classmethod
    def from_payloads(cls, payloads: list[bytes], lay: RecordLayout) -> _Batch:
        rows = np.frombuffer(b"".join(payloads), dtype=np.float64).reshape(-1, lay.row_width)
        return cls.from_rows(rows, lay)

    @classmethod
    def concatenate(cls, batches: Sequence[_Batch]) -> _Batch:
        return cls(*(np.concatenate([getattr(x, f) for x in batches]) for f in cls.__dataclass_fields__))

    def slice(self, a: int, b: int) -> _Batch:
        return _Batch(*(getattr(self, f)[a:b] for f in self.__dataclass_fields__))


# --------------------------------------------------------------------------------------
# MCAP sink
# --------------------------------------------------------------------------------------


def _num(description: str) -> dict:
    # a non-finite value is written as JSON null; the schema still says "number", the one
    # form Foxglove's JSON-schema reader takes for a float field
    return {"type": "number", "description": description}


def _time_schema(description: str) -> dict:
    return {
        "type": "object",
        "title": "time",
        "description": description,
        "properties": {
            "sec": {"type": "integer", "minimum": 0},
            "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
        },
    }


def _xyz_schema(title: str, keys: str, description: str) -> dict:
    return {
        "type": "object",
        "title": title,
        "description": description,
        "properties": {k: _num(f"{k} component") for k in keys},
        "required": list(keys),
    }


def _array(items: dict, description: str) -> dict:
    return {"type": "array", "items": items, "description": description}


def _qchain_vector_schema(title: str, key: str, description: str) -> dict:
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": {
            "t": {"type": "number", "description": "simulation time, s"},
            "step": {"type": "integer", "description": "step counter"},
            key: _array({"type": "number"}, description),
        },
        "required": ["t", "step", key],
    }


def _schemas() -> dict[str, tuple[str, dict]]:
    """JSON schemas of the channels: key -> (schema name, schema)."""
    color = {
        "type": "object",
        "title": "foxglove.Color",
        "description": "RGBA colour, components 0..1",
        "properties": {c: {"type": "number"} for c in "rgba"},
        "required": list("rgba"),
    }
    pose = {
        "type": "object",
        "title": "foxglove.Pose",
        "description": "Origin of the primitive in the entity's frame",
        "properties": {
            "position": _xyz_schema("foxglove.Vector3", "xyz", "position, m"),
            "orientation": _xyz_schema("foxglove.Quaternion", "xyzw", "orientation"),
        },
        "required": ["position", "orientation"],
    }
    line = {
        "type": "object",
        "title": "foxglove.LinePrimitive",
        "description": "A series of points connected by lines",
        "properties": {
            "type": {"type": "integer", "description": "0 line strip, 1 line loop, 2 line list"},
            "pose": pose,
            "thickness": {"type": "number", "description": "line thickness, m"},
            "scale_invariant": {"type": "boolean"},
            "points": _array(_xyz_schema("foxglove.Point3", "xyz", "point, m"), "points"),
            "color": color,
            "colors": _array(color, "per-point colours"),
            "indices": _array({"type": "integer"}, "indices into points"),
        },
        "required": ["type", "pose", "thickness", "scale_invariant", "points", "color", "colors", "indices"],
    }
    empty_list = {"type": "array", "items": {"type": "object", "properties": {}}, "description": "unused: empty"}
    entity = {
        "type": "object",
        "title": "foxglove.SceneEntity",
        "description": "One segment's backbone",
        "properties": {
            "timestamp": _time_schema("time of the entity (simulation time)"),
            "frame_id": {"type": "string"},
            "id": {"type": "string"},
            "lifetime": _time_schema("0: until replaced"),
            "frame_locked": {"type": "boolean"},
            "metadata": _array(
                {"type": "object", "properties": {"key": {"type": "string"}, "value": {"type": "string"}}},
                "key-value pairs",
            ),
            "arrows": empty_list,
            "cubes": empty_list,
            "spheres": empty_list,
            "cylinders": empty_list,
            "lines": _array(line, "line primitives"),
            "triangles": empty_list,
            "texts": empty_list,
            "models": empty_list,
        },
    }
    scene_update = {
        "title": "foxglove.SceneUpdate",
        "description": "The arm's backbone: one line strip a segment (thickness = diameter)",
        "type": "object",
        "properties": {
            "deletions": empty_list,
            "entities": _array(entity, "scene entities to add or replace"),
        },
        "required": ["deletions", "entities"],
    }
    transform = {
        "type": "object",
        "title": "foxglove.FrameTransform",
        "description": "Placement of a segment's tip frame in the world frame",
        "properties": {
            "timestamp": _time_schema("simulation time"),
            "parent_frame_id": {"type": "string"},
            "child_frame_id": {"type": "string"},
            "translation": _xyz_schema("foxglove.Vector3", "xyz", "tip position, m"),
            "rotation": _xyz_schema("foxglove.Quaternion", "xyzw", "tip orientation"),
        },
        "required": ["timestamp", "parent_frame_id", "child_frame_id", "translation", "rotation"],
    }
    transforms = {
        "title": "foxglove.FrameTransforms",
        "description": "Tip frames of the segments",
        "type": "object",
        "properties": {"transforms": _array(transform, "one a segment")},
        "required": ["transforms"],
    }
    energy = {
        "title": "qchain.Energy",
        "description": "Energies of the arm, J",
        "type": "object",
        "properties": {
            "t": {"type": "number", "description": "simulation time, s"},
            "step": {"type": "integer"},
            "kinetic": _num("kinetic energy, J"),
            "potential": _num("potential energy (gravity + elastic), J"),
            "total": _num("kinetic + potential, J"),
        },
        "required": ["t", "step", "kinetic", "potential", "total"],
    }
    return {
        "q": ("qchain.Coordinates", _qchain_vector_schema("qchain.Coordinates", "q", "generalised coordinates")),
        "v": ("qchain.Velocities", _qchain_vector_schema("qchain.Velocities", "v", "velocities")),
        "p": (
            "qchain.ChamberPressures",
            _qchain_vector_schema("qchain.ChamberPressures", "p", "chamber pressures, Pa, segment by segment"),
        ),
        "energy": ("qchain.Energy", energy),
        "tip_frames": ("foxglove.FrameTransforms", transforms),
        "backbone": ("foxglove.SceneUpdate", scene_update),
    }


class _Template:
    """A JSON text with holes: ``fill(values)`` interleaves fixed parts and byte values."""

    def __init__(self, parts: list[bytes]):
        self.parts = parts
        self._buf: list[bytes] = [b""] * (2 * len(parts) - 1)
        self._buf[0::2] = parts

    def fill(self, values: list[bytes]) -> bytes:
        buf = self._buf
        buf[1::2] = values
        return b"".join(buf)


def _rgb01(rgb: Sequence[int]) -> str:
    return '{"r":%r,"g":%r,"b":%r,"a":1.0}' % tuple(round(c / 255.0, 6) for c in rgb)


class _TemplateBuilder:
    def __init__(self) -> None:
        self.parts = [""]

    def lit(self, text: str) -> None:
        self.parts[-1] += text

    def hole(self) -> None:
        self.parts.append("")

    def holes(self, *separators: str) -> None:
        """A hole after each separator: ``holes('"x":', ',"y":')`` -> ``"x":#,"y":#``."""
        for s in separators:
            self.lit(s)
            self.hole()

    def build(self) -> _Template:
        return _Template([p.encode() for p in self.parts])


def _tf_template(n: int) -> _Template:
    """foxglove.FrameTransforms of n tips; holes a tip: sec, nsec, x, y, z, qx, qy, qz, qw."""
    tb = _TemplateBuilder()
    tb.lit('{"transforms":[')
    for i in range(n):
        tb.lit("," if i else "")
        tb.holes('{"timestamp":{"sec":', ',"nsec":')
        tb.lit('},"parent_frame_id":"world","child_frame_id":"segment_%d_tip",' % (i + 1))
        tb.holes('"translation":{"x":', ',"y":', ',"z":', '},"rotation":{"x":', ',"y":', ',"z":', ',"w":')
        tb.lit("}}")
    tb.lit("]}")
    return tb.build()


def _scene_template(n: int, P: int, radii: Sequence[float]) -> _Template:
    """foxglove.SceneUpdate with one line strip a segment; holes a segment: sec, nsec, then
    x, y, z of its P points."""
    tb = _TemplateBuilder()
    tb.lit('{"deletions":[],"entities":[')
    for i in range(n):
        tb.lit("," if i else "")
        tb.holes('{"timestamp":{"sec":', ',"nsec":')
        tb.lit(
            '},"frame_id":"world","id":"segment_%d","lifetime":{"sec":0,"nsec":0},"frame_locked":false,'
            '"metadata":[],"arrows":[],"cubes":[],"spheres":[],"cylinders":[],"lines":[{"type":0,'
            '"pose":{"position":{"x":0.0,"y":0.0,"z":0.0},"orientation":{"x":0.0,"y":0.0,"z":0.0,"w":1.0}},'
            '"thickness":%r,"scale_invariant":false,"points":[' % (i + 1, 2.0 * float(radii[i]))
        )
        for j in range(P):
            tb.holes(("," if j else "") + '{"x":', ',"y":', ',"z":')
            tb.lit("}")
        tb.lit(
            '],"color":%s,"colors":[],"indices":[]}],"triangles":[],"texts":[],"models":[]}'
            % _rgb01(SEGMENT_COLORS[i % len(SEGMENT_COLORS)])
        )
    tb.lit("]}")
    return tb.build()


def _numbers(arr: np.ndarray, dumps, opt) -> list[bytes]:
    """Shortest round-trip JSON forms (``null`` if not finite) of the entries of a float
    array, in C order."""
    return dumps(np.ascontiguousarray(arr).ravel(), option=opt)[1:-1].split(b",")


def _rows(arr: np.ndarray, dumps, opt) -> list[bytes]:
    """The JSON texts of the rows of a 2-D float array, without their brackets."""
    if arr.shape[1] == 0:
        return [b""] * arr.shape[0]
    return dumps(np.ascontiguousarray(arr), option=opt)[2:-2].split(b"],[")


_MCAP_MAGIC = b"\x89MCAP0\r\n"
_MSG_HEAD = struct.Struct("<BQHIQQ")  # opcode, record length, channel, sequence, log time, publish time


class _McapWriter:
    """A small MCAP writer for many small messages.

    The records are those of the ``mcap`` package (serialised with its ``RecordBuilder``),
    except the messages, which are packed in bulk: per message one ``struct.pack`` instead
    of the package's per-message record objects, which would cost the writer more than the
    JSON encoding. Layout: magic, Header, Schema and Channel records and Metadata in the
    data section (outside chunks, so a truncated file still names its channels), messages
    in zstd chunks each followed by its MessageIndex records, DataEnd, then a summary
    (schemas, channels, statistics, chunk and metadata indexes, summary offsets), Footer
    and magic.
    """

    def __init__(self, stream: BinaryIO, library: str, level: int = 1):
        import zstandard
        from mcap import records

        self._r = records
        self._zstd = zstandard.ZstdCompressor(level=level)
        self._s = stream
        self._pos = 0
        self._schemas: list = []
        self._channels: list = []
        self._chunk_indexes: list = []
        self._metadata_indexes: list = []
        self._counts: dict[int, int] = {}
        self._n_messages = 0
        self._t_start: int | None = None
        self._t_end = 0
        self._n_chunks = 0
        self._reset_chunk()
        self._write(_MCAP_MAGIC)
        self._record(records.Header(profile="", library=library))

    def _write(self, data: bytes) -> None:
        self._s.write(data)
        self._pos += len(data)

    def _record(self, rec) -> int:
        from mcap.data_stream import RecordBuilder

        rb = RecordBuilder()
        rec.write(rb)
        data = rb.end()
        self._write(data)
        return len(data)

    def _reset_chunk(self) -> None:
        self.parts: list[bytes] = []
        self.chunk_len = 0
        self.index: dict[int, list] = {}
        self.c_start: int | None = None
        self.c_end = 0
        self.c_count = 0

    def add_schema(self, name: str, encoding: str, data: bytes) -> int:
        sc = self._r.Schema(id=len(self._schemas) + 1, name=name, encoding=encoding, data=data)
        self._schemas.append(sc)
        self._record(sc)
        return sc.id

    def add_channel(self, topic: str, encoding: str, schema_id: int) -> int:
        ch = self._r.Channel(
            id=len(self._channels) + 1, topic=topic, message_encoding=encoding, metadata={}, schema_id=schema_id
        )
        self._channels.append(ch)
        self._counts[ch.id] = 0
        self.index[ch.id] = []
        self._record(ch)
        return ch.id

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        offset = self._pos
        length = self._record(self._r.Metadata(name=name, metadata=data))
        self._metadata_indexes.append(self._r.MetadataIndex(offset=offset, length=length, name=name))

    def note_messages(self, channel_counts: dict[int, int], t_min: int, t_max: int) -> None:
        """Account for messages packed into ``parts`` by the caller."""
        n = 0
        for cid, k in channel_counts.items():
            self._counts[cid] += k
            n += k
        self._n_messages += n
        self.c_count += n
        if self.c_start is None or t_min < self.c_start:
            self.c_start = t_min
        if t_max > self.c_end:
            self.c_end = t_max

    def flush_chunk(self) -> None:
        """Compress and write the open chunk and its message indexes; flush the stream."""
        if self.c_count:
            r = self._r
            raw = b"".join(self.parts)
            data = self._zstd.compress(raw)
            chunk = r.Chunk(
                message_start_time=self.c_start,
                message_end_time=self.c_end,
                uncompressed_size=len(raw),
                uncompressed_crc=zlib.crc32(raw),
                compression="zstd",
                data=data,
            )
            chunk_start = self._pos
            chunk_length = self._record(chunk)
            offsets = {}
            index_start = self._pos
            for cid in sorted(self.index):
                entries = self.index[cid]
                if entries:  # MessageIndex record, packed in one go
                    offsets[cid] = self._pos
                    flat = [x for pair in entries for x in pair]
                    body = struct.pack("<HI%dQ" % len(flat), cid, 8 * len(flat), *flat)
                    self._write(struct.pack("<BQ", 0x07, len(body)) + body)
            self._chunk_indexes.append(
                r.ChunkIndex(
                    message_start_time=self.c_start,
                    message_end_time=self.c_end,
                    chunk_start_offset=chunk_start,
                    chunk_length=chunk_length,
                    message_index_offsets=offsets,
                    message_index_length=self._pos - index_start,
                    compression="zstd",
                    compressed_size=len(data),
                    uncompressed_size=len(raw),
                )
            )
            self._n_chunks += 1
            if self._t_start is None or self.c_start < self._t_start:
                self._t_start = self.c_start
            self._t_end = max(self._t_end, self.c_end)
            cids = list(self.index)
            self._reset_chunk()
            self.index = {cid: [] for cid in cids}
        self._s.flush()

    def finish(self) -> None:
        from mcap.data_stream import RecordBuilder

        r = self._r
        self.flush_chunk()
        self._record(r.DataEnd(data_section_crc=0))
        summary_start = self._pos
        rb = RecordBuilder()
        offsets = []

        def group(opcode, recs) -> None:
            if not recs:
                return
            start = rb.count
            for rec in recs:
                rec.write(rb)
            offsets.append(r.SummaryOffset(group_opcode=opcode, group_start=summary_start + start,
                                           group_length=rb.count - start))

        from mcap.opcode import Opcode

        stats = r.Statistics(
            message_count=self._n_messages,
            schema_count=len(self._schemas),
            channel_count=len(self._channels),
            attachment_count=0,
            metadata_count=len(self._metadata_indexes),
            chunk_count=self._n_chunks,
            message_start_time=self._t_start or 0,
            message_end_time=self._t_end,
            channel_message_counts=dict(self._counts),
        )
        group(Opcode.SCHEMA, self._schemas)
        group(Opcode.CHANNEL, self._channels)
        group(Opcode.STATISTICS, [stats])
        group(Opcode.CHUNK_INDEX, self._chunk_indexes)
        group(Opcode.METADATA_INDEX, self._metadata_indexes)
        summary_offset_start = summary_start + rb.count
        for off in offsets:
            off.write(rb)
        summary = rb.end()
        crc = zlib.crc32(summary)
        crc = zlib.crc32(struct.pack("<BQQQ", Opcode.FOOTER, 20, summary_start, summary_offset_start), crc)
        self._write(summary)
        self._record(r.Footer(summary_start=summary_start, summary_offset_start=summary_offset_start, summary_crc=crc))
        self._write(_MCAP_MAGIC)
        self._s.flush()


class _McapSink:
    """Encodes batches of records as JSON messages into an MCAP file or binary stream."""

    def __init__(
        self,
        out: str | os.PathLike | BinaryIO,
        info: RunInfo,
        *,
        recording_id: str,
        flush_interval: float = DEFAULT_FLUSH_INTERVAL,
        flush_wall_interval: float = DEFAULT_FLUSH_WALL_INTERVAL,
        chunk_bytes: int = DEFAULT_CHUNK_BYTES,
    ):
        import orjson

        self._dumps = orjson.dumps
        self._opt = orjson.OPT_SERIALIZE_NUMPY
        self.info = info
        if isinstance(out, (str, os.PathLike)):
            self.path: str | None = os.fspath(out)
            self._stream = open(self.path, "wb")
            self._owns = True
        else:
            self.path = None
            self._stream = out
            self._owns = False
        self._w = _McapWriter(self._stream, library=f"qchain {info.qchain_version}")
        self._w.add_metadata(
            "qchain",
            {
                "format": FORMAT_NAME,
                "format_version": str(FORMAT_VERSION),
                "qchain_version": info.qchain_version,
                "scene": info.scene,
                "scene_path": info.scene_path or "",
                "params": json.dumps(info.params, sort_keys=True),
                "n_segments": str(info.n_segments),
                "radii": json.dumps(list(info.radii)),
                "recording_id": recording_id,
                "created_utc": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
                "info": json.dumps(info.to_json(), sort_keys=True),
            },
        )
        self._ch: dict[str, int] = {}
        for key, (name, schema) in _schemas().items():
            sid = self._w.add_schema(name, "jsonschema", json.dumps(schema).encode())
            self._ch[key] = self._w.add_channel(TOPICS[key], "json", sid)
        self._w.flush_chunk()
        self.flush_interval = float(flush_interval)
        self.flush_wall_interval = float(flush_wall_interval)
        self.chunk_bytes = int(chunk_bytes)
        self._last_flush_t: float | None = None
        self._last_flush_wall = time.monotonic()
        self._tf_tmpl: _Template | None = None
        self._scene_tmpl: _Template | None = None
        self.n_records = 0
        self.last_t: float | None = None
        self.last_step: int | None = None
        self.finished = False

    def _flush(self) -> None:
        self._w.flush_chunk()
        self._last_flush_wall = time.monotonic()

    def write_batch(self, b: _Batch) -> None:
        K = len(b)
        if K == 0:
            return
        n, P = b.backbone.shape[1], b.backbone.shape[2]
        if self._tf_tmpl is None:
            self._tf_tmpl = _tf_template(n)
            self._scene_tmpl = _scene_template(n, P, self.info.radii)
            # value order of a template fill from the tokens [sec, nsec, number 0, number 1, ...]
            self._tf_pick = operator.itemgetter(*[j for i in range(n) for j in (0, 1, *range(2 + 7 * i, 9 + 7 * i))])
            w3 = 3 * P
            self._sc_pick = operator.itemgetter(
                *[j for i in range(n) for j in (0, 1, *range(2 + w3 * i, 2 + w3 * (i + 1)))]
            )
        dumps, opt, w = self._dumps, self._opt, self._w
        ch = self._ch
        cids = (ch["q"], ch["v"], ch["p"], ch["energy"], ch["tip_frames"], ch["backbone"])
        tf_fill, sc_fill, tf_pick, sc_pick = self._tf_tmpl.fill, self._scene_tmpl.fill, self._tf_pick, self._sc_pick
        pack = _MSG_HEAD.pack
        # number texts of the whole batch at once (shortest round-trip forms, null if not finite)
        t_tok = _numbers(b.t, dumps, opt)
        q_rows = _rows(b.q, dumps, opt)
        v_rows = _rows(b.v, dumps, opt)
        p_rows = _rows(b.p, dumps, opt)
        e_tok = _numbers(b.energy, dumps, opt)
        tf_tok = _numbers(b.tip_frames, dumps, opt)
        bb_tok = _numbers(b.backbone, dumps, opt)
        ntf, nbb = 7 * n, 3 * P * n
        ts = b.t.tolist()
        steps = b.step.tolist()
        ns = np.rint(b.t * 1e9).astype(np.int64)
        if ns.size and ns.min() < 0:
            raise ValueError("negative simulation time")
        ns_list = ns.tolist()
        last_flush_t = self._last_flush_t
        start = 0
        for k in range(K):
            t, step, lt = ts[k], steps[k], ns_list[k]
            seq = step & 0xFFFFFFFF
            tb = t_tok[k]
            stamp = [b"%d" % (lt // 1_000_000_000), b"%d" % (lt % 1_000_000_000)]
            msgs = (
                b'{"t":%b,"step":%d,"q":[%b]}' % (tb, step, q_rows[k]),
                b'{"t":%b,"step":%d,"v":[%b]}' % (tb, step, v_rows[k]),
                b'{"t":%b,"step":%d,"p":[%b]}' % (tb, step, p_rows[k]),
                b'{"t":%b,"step":%d,"kinetic":%b,"potential":%b,"total":%b}'
                % (tb, step, e_tok[3 * k], e_tok[3 * k + 1], e_tok[3 * k + 2]),
                tf_fill(tf_pick(stamp + tf_tok[ntf * k : ntf * (k + 1)])),
                sc_fill(sc_pick(stamp + bb_tok[nbb * k : nbb * (k + 1)])),
            )
            parts, index, off = w.parts, w.index, w.chunk_len
            for cid, m in zip(cids, msgs):
                index[cid].append((lt, off))
                parts.append(pack(5, 22 + len(m), cid, seq, lt, lt))
                parts.append(m)
                off += 31 + len(m)
            w.chunk_len = off
            if last_flush_t is None:
                last_flush_t = t
            cut = t - last_flush_t >= self.flush_interval or off >= self.chunk_bytes
            if cut or k == K - 1:
                w.note_messages({cid: k + 1 - start for cid in cids}, min(ns_list[start : k + 1]),
                                max(ns_list[start : k + 1]))
                start = k + 1
                if cut:
                    self._flush()
                    last_flush_t = t
        self._last_flush_t = last_flush_t
        self.n_records += K
        self.last_t, self.last_step = ts[-1], steps[-1]
        self.tick()

    def tick(self) -> None:
        """Flush the open chunk if it is older than the wall-time interval."""
        if self._w.c_count and time.monotonic() - self._last_flush_wall >= self.flush_wall_interval:
            self._flush()

    def finish(self, outcome: dict) -> None:
        if self.finished:
            return
        self._w.flush_chunk()
        self._w.add_metadata(
            "qchain.outcome",
            {
                "success": "true" if outcome.get("success") else "false",
                "status": str(int(outcome.get("status", 0))),
                "message": str(outcome.get("message", "")),
                "nfev": str(int(outcome.get("nfev", 0) or 0)),
                "n_records": str(self.n_records),
                "last_t": "" if self.last_t is None else repr(self.last_t),
            },
        )
        self._w.finish()
        if self._owns:
            self._stream.close()
        self.finished = True


# --------------------------------------------------------------------------------------
# Rerun sink
# --------------------------------------------------------------------------------------


def _pressure_colors(p_rel: np.ndarray) -> np.ndarray:
    """Colours (..., 3) uint8 for pressures relative to the reference, blue (0) to red (1)."""
    s = np.clip(np.nan_to_num(p_rel), 0.0, 1.0)[..., None]
    lo = np.array([60.0, 120.0, 255.0])
    hi = np.array([220.0, 20.0, 60.0])
    return (lo + (hi - lo) * s).astype(np.uint8)


def _pick_port(host: str, preferred: int | None, default: int) -> int:
    """``preferred`` if given; else ``default`` when free on ``host``, else a free port."""
    if preferred:
        return int(preferred)
    for candidate in (default, 0):
        try:
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
                s.bind((host, candidate))
                return int(s.getsockname()[1])
        except OSError:
            continue
    raise LoggingError(f"no free TCP port on {host}")


def _wait_listening(host: str, port: int, timeout: float, proc: subprocess.Popen | None = None) -> bool:
    deadline = time.monotonic() + timeout
    target = "127.0.0.1" if host in ("0.0.0.0", "") else host
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            return False
        try:
            with socket.create_connection((target, port), timeout=0.5):
                return True
        except OSError:
            time.sleep(0.05)
    return False


def _probe_url(url: str, timeout: float = 2.0) -> str | None:
    """None when a TCP connection to the URL's host and port opens, else why not."""
    parts = urlsplit(url)
    if parts.scheme not in ("rerun", "rerun+http", "rerun+https", "http", "https"):
        return f"unsupported URL scheme {parts.scheme!r} (use rerun+http://HOST:PORT/proxy)"
    host = parts.hostname
    if not host:
        return "the URL names no host"
    try:
        port = parts.port or (443 if parts.scheme.endswith("https") else 9876)
    except ValueError as exc:
        return f"bad port in URL: {exc}"
    try:
        with socket.create_connection((host, port), timeout=timeout):
            return None
    except OSError as exc:
        return f"{exc.strerror or exc}"


def _rerun_cli() -> str | None:
    """Path of the ``rerun`` program shipped in the rerun-sdk wheel (or on PATH)."""
    try:
        import rerun_cli

        exe = Path(rerun_cli.__file__).parent / ("rerun.exe" if os.name == "nt" else "rerun")
        if exe.exists():
            return str(exe)
    except ImportError:
        pass
    import shutil

    return shutil.which("rerun")


_LIBC = None


def _die_with_parent() -> None:  # runs in the forked child before exec
    if _LIBC is not None:
        _LIBC.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    _normal_priority()  # the viewer serves at normal priority, not the writer's idle one


def _load_libc() -> None:
    global _LIBC
    if _LIBC is None and sys.platform.startswith("linux"):
        try:
            import ctypes

            _LIBC = ctypes.CDLL(None)
        except OSError:
            _LIBC = None


class _RerunSink:
    """Logs batches to a Rerun recording stream (live server, remote viewer, .rrd file)."""

    def __init__(
        self,
        info: RunInfo,
        *,
        serve: bool = False,
        connect: str | None = None,
        rrd: str | os.PathLike | None = None,
        bind: str = DEFAULT_BIND,
        grpc_port: int | None = None,
        web_port: int | None = None,
        recording_id: str,
        server_memory_limit: str = "1GiB",
        warn,
    ):
        self.info = info
        self.rec = None
        self.viewer_url: str | None = None
        self.grpc_url: str | None = None
        self.serving = False
        self._web: subprocess.Popen | None = None
        self._started = False
        try:
            import rerun as rr
            import rerun.blueprint as rrb
        except ImportError as exc:  # pragma: no cover - rerun-sdk is a dependency
            warn(f"Rerun is not available ({exc}); no live view or .rrd file, the MCAP is still written")
            return
        self.rr, self.rrb = rr, rrb
        rec = rr.RecordingStream("qchain", recording_id=recording_id)
        sinks = []
        if rrd is not None:
            sinks.append(rr.FileSink(os.fspath(rrd)))
        if connect:
            why = _probe_url(connect)
            if why is None:
                sinks.append(rr.GrpcSink(connect))
            else:
                warn(
                    f"no Rerun viewer can be reached at {connect} ({why}); the run goes on "
                    "without it and the MCAP log is still written"
                )
        server_port = None
        if serve:
            server_port = _pick_port(bind, grpc_port, DEFAULT_GRPC_PORT)
            server = rr.GrpcServerSink(bind_ip=bind, port=server_port, server_memory_limit=server_memory_limit)
            sinks.append(server)
            self.grpc_url = server.uri
        if not sinks:
            return
        rec.set_sinks(*sinks)
        self.rec = rec
        if serve:
            if not _wait_listening(bind, server_port, 5.0):
                warn(
                    f"the Rerun gRPC server could not listen on {bind}:{server_port} (port in use?); "
                    "no live view, the MCAP log is still written"
                )
            else:
                self.serving = True
                self._start_web_viewer(bind, web_port, warn)
        rec.send_recording_name(info.name)

    def _start_web_viewer(self, bind: str, web_port: int | None, warn) -> None:
        exe = _rerun_cli()
        if exe is None:
            warn(
                "the `rerun` program of rerun-sdk was not found, so no web viewer is served; "
                f"open the data with a Rerun viewer: rerun --connect {self.grpc_url}"
            )
            return
        port = _pick_port(bind, web_port, DEFAULT_WEB_PORT)
        _load_libc()
        env = dict(os.environ)
        env.setdefault("RUST_LOG", "warn")
        self._web = subprocess.Popen(
            [exe, "--serve-web", "--bind", bind, "--web-viewer-port", str(port), self.grpc_url],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            env=env,
            preexec_fn=_die_with_parent if _LIBC is not None else None,
        )
        if not _wait_listening(bind, port, 15.0, self._web):
            warn(
                f"the Rerun web viewer did not start on {bind}:{port}; connect a Rerun viewer to "
                f"{self.grpc_url} instead"
            )
            self._stop_web()
            return
        host = "127.0.0.1" if bind in ("0.0.0.0", "") else bind
        self.viewer_url = f"http://{host}:{port}/?url={quote(self.grpc_url, safe='')}"

    def _stop_web(self) -> None:
        if self._web is not None and self._web.poll() is None:
            self._web.terminate()
            try:
                self._web.wait(5.0)
            except subprocess.TimeoutExpired:
                self._web.kill()
                self._web.wait()
        self._web = None

    # -- static part ---------------------------------------------------------------------

    def _start(self, b: _Batch) -> None:
        rr, rrb, rec, info = self.rr, self.rrb, self.rec, self.info
        n, P = b.backbone.shape[1], b.backbone.shape[2]
        bb0 = np.nan_to_num(b.backbone[0])
        seg_len = np.linalg.norm(np.diff(bb0, axis=1), axis=2).sum(axis=1) if P > 1 else np.zeros(n)
        seg_len = np.where(seg_len > 0, seg_len, 4.0 * np.asarray(info.radii))
        self._arrow_scale = 0.5 * seg_len / info.pressure_ref  # m/Pa, (n,)
        radii = np.asarray(info.radii)
        self._axis_len = 2.5 * radii
        self._chamber_r = (
            np.asarray(info.chamber_radii) if info.chamber_radii is not None else 0.6 * radii
        )
        ang = np.asarray(info.chamber_angles)
        self._cos, self._sin = np.cos(ang), np.sin(ang)
        colors = np.array([SEGMENT_COLORS[i % len(SEGMENT_COLORS)] for i in range(n)], dtype=np.uint8)
        extent = float(np.max(np.abs(bb0))) if bb0.size else 0.1
        extent = max(extent, float(seg_len.sum()), 1e-3)

        rec.log("/", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log(
            "world/axes",
            rr.Arrows3D(
                origins=np.zeros((3, 3)),
                vectors=np.eye(3) * 0.25 * extent,
                colors=[(200, 60, 60), (60, 170, 60), (60, 90, 220)],
                radii=0.05 * float(radii.min()),
            ),
            static=True,
        )
        rec.log("arm/backbone", rr.LineStrips3D.from_fields(radii=radii, colors=colors), static=True)
        rec.log(
            "arm/tip_axes",
            rr.Arrows3D.from_fields(
                colors=np.tile(np.array([(220, 40, 40), (40, 180, 40), (40, 80, 230)], np.uint8), (n, 1)),
                radii=np.repeat(0.12 * radii, 3),
            ),
            static=True,
        )
        rec.log("arm/pressure", rr.Arrows3D.from_fields(radii=np.repeat(0.08 * radii, 3)), static=True)
        names = [f"segment {i + 1} chamber {j + 1}" for i in range(n) for j in range(3)]
        rec.log("plots/pressure", rr.SeriesLines(names=names[: b.p.shape[1]]), static=True)
        rec.log("plots/q", rr.SeriesLines(names=[f"q[{i}]" for i in range(b.q.shape[1])]), static=True)
        rec.log("plots/v", rr.SeriesLines(names=[f"v[{i}]" for i in range(b.v.shape[1])]), static=True)
        rec.log(
            "plots/energy",
            rr.SeriesLines(names=["kinetic", "potential", "total"],
                           colors=[(40, 120, 220), (60, 170, 60), (30, 30, 30)]),
            static=True,
        )
        text = f"# {info.name}\n\nqchain {info.qchain_version}, {n} segment(s)"
        if info.scene_path:
            text += f", scene `{info.scene_path}`"
        if info.scene:
            text += "\n\n```toml\n" + info.scene + "\n```"
        if info.params:
            text += "\n\n## Model parameters\n\n```json\n" + json.dumps(info.params, indent=2, sort_keys=True) + "\n```"
        rec.log("scene", rr.TextDocument(text, media_type=rr.MediaType.MARKDOWN), static=True)

        # the camera sees the whole reach: a sphere of the arm's length about its root
        reach = max(float(seg_len.sum()), 1e-3)
        root = bb0[0, 0] if bb0.size else np.zeros(3)
        center = root + np.array([0.0, 0.0, 0.4 * reach])
        eye = center + 2.1 * reach * np.array([0.55, -0.7, 0.45])
        blueprint = rrb.Blueprint(
            rrb.Horizontal(
                rrb.Spatial3DView(
                    name="arm",
                    origin="/",
                    contents=["+ /arm/**", "+ /world/**"],
                    eye_controls=rrb.EyeControls3D(position=eye, look_target=center, eye_up=[0.0, 0.0, 1.0]),
                ),
                rrb.Vertical(
                    rrb.TimeSeriesView(name="chamber pressures (Pa)", origin="/plots/pressure"),
                    rrb.Tabs(
                        rrb.TimeSeriesView(name="coordinates q", origin="/plots/q"),
                        rrb.TimeSeriesView(name="velocities v", origin="/plots/v"),
                        rrb.TextDocumentView(name="scene", origin="/scene"),
                    ),
                    rrb.TimeSeriesView(name="energy (J)", origin="/plots/energy"),
                ),
                column_shares=[3, 2],
            ),
            rrb.BlueprintPanel(state="collapsed"),
            rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(state="collapsed", timeline="sim_time"),
        )
        rec.send_blueprint(blueprint, make_active=True, make_default=True)
        self._started = True

    # -- per-step part -----------------------------------------------------------------------

    def write_batch(self, b: _Batch) -> None:
        if self.rec is None or len(b) == 0:
            return
        rr, rec = self.rr, self.rec
        if not self._started:
            self._start(b)
        K, n, P = b.backbone.shape[:3]
        idx = [rr.TimeColumn("sim_time", duration=b.t), rr.TimeColumn("step", sequence=b.step)]
        rec.send_columns(
            "arm/backbone",
            indexes=idx,
            columns=rr.LineStrips3D.columns(strips=b.backbone.reshape(K * n, P, 3)).partition(np.full(K, n)),
        )
        pos = b.tip_frames[..., :3]  # (K, n, 3)
        R = quaternion_to_rotation(b.tip_frames[..., 3:])  # (K, n, 3, 3)
        axes = np.swapaxes(R, -1, -2) * self._axis_len[None, :, None, None]  # rows = axis vectors
        rec.send_columns(
            "arm/tip_axes",
            indexes=idx,
            columns=rr.Arrows3D.columns(
                origins=np.repeat(pos, 3, axis=1).reshape(-1, 3), vectors=axes.reshape(-1, 3)
            ).partition(np.full(K, 3 * n)),
        )
        # chamber arrows: at the chamber centres on each tip plate, along the backbone's end
        # tangent, length and colour by pressure
        radial = (
            self._cos[None, None, :, None] * R[:, :, None, :, 0] + self._sin[None, None, :, None] * R[:, :, None, :, 1]
        )  # (K, n, 3, 3): chamber j direction
        origins = pos[:, :, None, :] + self._chamber_r[None, :, None, None] * radial
        if P > 1:
            tangent = b.backbone[:, :, -1, :] - b.backbone[:, :, -2, :]
        else:
            tangent = R[..., 2]
        tangent = tangent / np.maximum(np.linalg.norm(tangent, axis=-1, keepdims=True), 1e-300)
        npress = min(b.p.shape[1], 3 * n)
        press = np.zeros((K, 3 * n))
        press[:, :npress] = b.p[:, :npress]
        press = press.reshape(K, n, 3)
        vec = tangent[:, :, None, :] * (press * self._arrow_scale[None, :, None])[..., None]
        rec.send_columns(
            "arm/pressure",
            indexes=idx,
            columns=rr.Arrows3D.columns(
                origins=origins.reshape(-1, 3),
                vectors=vec.reshape(-1, 3),
                colors=_pressure_colors(press / self.info.pressure_ref).reshape(-1, 3),
            ).partition(np.full(K, 3 * n)),
        )
        rec.send_columns("plots/pressure", indexes=idx, columns=rr.Scalars.columns(scalars=b.p))
        rec.send_columns("plots/q", indexes=idx, columns=rr.Scalars.columns(scalars=b.q))
        rec.send_columns("plots/v", indexes=idx, columns=rr.Scalars.columns(scalars=b.v))
        rec.send_columns("plots/energy", indexes=idx, columns=rr.Scalars.columns(scalars=b.energy))

    def finish(self) -> None:
        """Flush everything; finalise a .rrd file (keep a live server up)."""
        if self.rec is None:
            return
        try:
            self.rec.flush(timeout_sec=10.0)
        except TypeError:  # pragma: no cover - older signature
            self.rec.flush()
        if not self.serving:
            self.rec.disconnect()
        else:
            try:
                import rerun_bindings

                rerun_bindings.finalize_deferred_sinks(recording=self.rec.to_native())
            except Exception:  # pragma: no cover - best effort
                pass

    def close(self) -> None:
        if self.rec is not None:
            self.rec.disconnect()
            self.rec = None
        self._stop_web()
        self.serving = False


# --------------------------------------------------------------------------------------
# The set of sinks a writer feeds
# --------------------------------------------------------------------------------------


class _SinkSet:
    def __init__(self, cfg: dict, mcap_stream: BinaryIO | None, warn):
        self.info = RunInfo.from_json(cfg["info"])
        self.layout: RecordLayout | None = None
        self.warn = warn
        self.mcap: _McapSink | None = None
        self.rerun: _RerunSink | None = None
        out = mcap_stream if mcap_stream is not None else cfg.get("mcap")
        if out is not None:
            self.mcap = _McapSink(
                out,
                self.info,
                recording_id=cfg["recording_id"],
                flush_interval=cfg["flush_interval"],
                flush_wall_interval=cfg["flush_wall_interval"],
                chunk_bytes=cfg["chunk_bytes"],
            )
        self._rr_thread: threading.Thread | None = None
        if cfg.get("serve") or cfg.get("connect"):  # before "ready": the URL, or a missing viewer, first
            self._start_rerun(cfg)
        elif cfg.get("rrd"):  # a .rrd file only: Rerun (a 0.7 s import) comes up while the MCAP is written
            self._rr_thread = threading.Thread(target=self._start_rerun, args=(cfg,), name="qchain-rerun-start",
                                               daemon=True)
            self._rr_thread.start()
        self.n_records = 0
        self.last_t: float | None = None
        rate = cfg.get("rerun_rate")
        self._rr_dt = 0.0 if not rate else 1.0 / float(rate)
        self._rr_next = -math.inf
        # Rerun costs ~4 ms a send_columns batch whatever its size, so its records gather
        # here for up to rerun_latency s of wall time (the MCAP gets them at once)
        self._rr_latency = float(cfg.get("rerun_latency", DEFAULT_RERUN_LATENCY))
        self._rr_pending: list[_Batch] = []
        self._rr_count = 0
        self._rr_wall0 = 0.0

    def _start_rerun(self, cfg: dict) -> None:
        try:
            self.rerun = _RerunSink(
                self.info,
                serve=bool(cfg.get("serve")),
                connect=cfg.get("connect"),
                rrd=cfg.get("rrd"),
                bind=cfg.get("bind", DEFAULT_BIND),
                grpc_port=cfg.get("grpc_port"),
                web_port=cfg.get("web_port"),
                recording_id=cfg["recording_id"],
                server_memory_limit=cfg.get("server_memory_limit", "1GiB"),
                warn=lambda m: self.warn(m),
            )
        except Exception as exc:  # no viewer or .rrd: say so, keep the MCAP
            self.warn(f"Rerun could not start ({type(exc).__name__}: {exc}); the run goes on and the MCAP "
                      "log is still written")
            self.rerun = None

    def _rerun_started(self, wait: bool) -> bool:
        """Whether Rerun's start (in the background for a .rrd file) is over; ``wait`` for it."""
        th = self._rr_thread
        if th is not None:
            if not wait and th.is_alive():
                return False
            th.join()
            self._rr_thread = None
        return True

    @property
    def viewer_url(self) -> str | None:
        return None if self.rerun is None else self.rerun.viewer_url

    @property
    def serving(self) -> bool:
        return self.rerun is not None and self.rerun.serving

    def write_payloads(self, payloads: list[bytes]) -> None:
        if payloads:
            self.write_batch(_Batch.from_payloads(payloads, self.layout))

    def write_batch(self, b: _Batch) -> None:
        self.n_records += len(b)
        self.last_t = float(b.t[-1])
        if self.mcap is not None:
            self.mcap.write_batch(b)
        if self._rr_thread is not None or (self.rerun is not None and self.rerun.rec is not None):
            if self._rr_dt > 0.0:  # a display rate: one record every rerun_rate-th of a second
                keep = []
                nxt, dt = self._rr_next, self._rr_dt
                for i, t in enumerate(b.t.tolist()):
                    if t >= nxt - 1e-6 * dt:  # (rounding of t = k dt must not skip a sample)
                        keep.append(i)
                        nxt = t + dt
                self._rr_next = nxt
                if len(keep) < len(b):
                    b = _Batch(*(getattr(b, f)[keep] for f in _Batch.__dataclass_fields__))
            if len(b):
                if not self._rr_pending:
                    self._rr_wall0 = time.monotonic()
                self._rr_pending.append(b)
                self._rr_count += len(b)
                if self._rr_count >= 4096:
                    self._send_rerun()

    def _send_rerun(self, wait: bool = False) -> None:
        """Send the records gathered for Rerun as one batch (once Rerun has started, or
        after waiting for it)."""
        if not self._rerun_started(wait):
            return
        pending, self._rr_pending, self._rr_count = self._rr_pending, [], 0
        if not pending or self.rerun is None or self.rerun.rec is None:
            return
        b = pending[0] if len(pending) == 1 else _Batch.concatenate(pending)
        try:
            self.rerun.write_batch(b)
        except Exception as exc:  # a viewer problem never stops the MCAP
            self.warn(f"Rerun logging failed and is switched off ({type(exc).__name__}: {exc})")
            self.rerun.close()
            self.rerun = None

    def tick(self) -> None:
        if self.mcap is not None:
            self.mcap.tick()
        if self._rr_pending and (time.monotonic() - self._rr_wall0 >= self._rr_latency or self._rerun_fresh()):
            self._send_rerun()

    def _rerun_fresh(self) -> bool:
        """Rerun is up but has had no batch yet. Its first batch goes at once, not after
        ``rerun_latency``: it carries Rerun's start (blueprint, static geometry, ~40 ms of
        the writer's time), which then overlaps the simulation instead of delaying the end
        of a short run, and a live viewer shows the arm as soon as it can."""
        th = self._rr_thread
        return ((th is None or not th.is_alive()) and self.rerun is not None and self.rerun.rec is not None
                and not self.rerun._started)

    def flush(self) -> dict:
        """Everything so far into the files (MCAP chunk closed) and out to the viewer."""
        self._send_rerun(wait=True)
        if self.mcap is not None:
            self.mcap._flush()
        if self.rerun is not None and self.rerun.rec is not None:
            try:
                self.rerun.rec.flush(timeout_sec=10.0)
            except Exception as exc:  # pragma: no cover - best effort
                self.warn(f"Rerun flush failed ({type(exc).__name__}: {exc})")
        return {"n_records": self.n_records, "last_t": self.last_t}

    def finish(self, outcome: dict) -> dict:
        self._send_rerun(wait=True)
        if self.mcap is not None:
            self.mcap.finish(outcome)
        if self.rerun is not None:
            try:
                self.rerun.finish()
            except Exception as exc:  # pragma: no cover - best effort
                self.warn(f"Rerun flush failed ({type(exc).__name__}: {exc})")
        return {"n_records": self.n_records, "last_t": self.last_t}

    def close(self) -> None:
        self._rerun_started(wait=True)
        if self.rerun is not None:
            self.rerun.close()


# --------------------------------------------------------------------------------------
# Writer process
# --------------------------------------------------------------------------------------


class _FrameReader:
    """Splits a byte stream into (kind, payload) frames."""

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> None:
        self._buf += data

    def frames(self):
        buf, pos, size = self._buf, 0, _FRAME.size
        out = []
        while len(buf) - pos >= size:
            kind, length = _FRAME.unpack_from(buf, pos)
            if len(buf) - pos - size < length:
                break
            out.append((kind, bytes(buf[pos + size : pos + size + length])))
            pos += size + length
        del buf[:pos]
        return out


def _read_frame_blocking(fd: int, reader: _FrameReader):
    while True:
        frames = reader.frames()
        if frames:
            return frames
        data = os.read(fd, 1 << 16)
        if not data:
            return []
        reader.feed(data)


#: The writer's nice value: a CFS share of about a tenth of a competitor's. Not ``SCHED_IDLE``:
#: on a machine whose cores are all busy an idle-class writer gets no CPU time at all, never
#: starts, and the recording is lost; at nice 10 it still progresses there, and on a quiet
#: machine it runs on the other core as before.
WRITER_NICE = 10


def _yield_to_the_simulation(pid: int) -> None:
    """Run process ``pid`` (and the threads it starts: Rerun's too) at a low CPU share
    (:data:`WRITER_NICE`): the simulation does not wait for the writer, which catches up on
    the other core or while the simulation waits for it, and still gets some time on a busy
    machine."""
    try:
        os.setpriority(os.PRIO_PROCESS, pid, WRITER_NICE)
    except (AttributeError, OSError):  # pragma: no cover - not POSIX
        pass


def _normal_priority() -> None:
    """Undo :func:`_yield_to_the_simulation` (for the web viewer a writer starts)."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, 0)
    except (AttributeError, OSError):  # pragma: no cover - not allowed
        pass


def _import_quietly(*names: str) -> None:
    """Import modules ahead of their use (a missing one is reported where it is used)."""
    import importlib

    for name in names:
        try:
            importlib.import_module(name)
        except ImportError:
            pass


def _worker_main(rerun: bool, bell: int) -> int:
    """Entry point of the writer process: frames on stdin, JSON status lines on stdout.
    ``rerun``: import rerun-sdk at once, before the configuration comes. ``bell``: the
    read end of the doorbell pipe (:func:`_launch_writer`): a byte on it ends the pause
    between two reads of stdin, so that a flush or the end of the run is served at once."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the simulating process decides when to stop
    # the imports first: they take most of the start-up, and the configuration may come later;
    # rerun-sdk's (0.7 s) on a thread, so that an MCAP can be ready before it is done
    if rerun:
        threading.Thread(target=_import_quietly, args=("rerun", "rerun.blueprint"), daemon=True).start()
    _import_quietly("mcap.records", "orjson", "zstandard")
    status_fd = os.dup(1)
    os.dup2(2, 1)  # anything a library prints goes to stderr, not into the status channel
    status = os.fdopen(status_fd, "w", buffering=1)

    def send(event: str, **kw) -> None:
        try:
            status.write(json.dumps({"event": event, **kw}) + "\n")
            status.flush()
        except OSError:  # nobody listens any more (the simulating process is gone)
            pass

    def warn_live(msg: str) -> None:
        print(f"qchain.logging: warning: {msg}", file=sys.stderr, flush=True)

    reader = _FrameReader()
    first = _read_frame_blocking(0, reader)
    if not first or first[0][0] != _FRAME_CONFIG:
        send("error", message="the log writer got no configuration")
        return 2
    cfg = json.loads(first[0][1])
    startup_warnings: list[str] = []
    try:
        sinks = _SinkSet(cfg, None, startup_warnings.append)
    except Exception as exc:
        send("error", message=f"{type(exc).__name__}: {exc}")
        return 2
    sinks.warn = warn_live
    send("ready", viewer_url=sinks.viewer_url, grpc_url=sinks.rerun.grpc_url if sinks.rerun else None,
         warnings=startup_warnings, pid=os.getpid(),
         web_pid=sinks.rerun._web.pid if sinks.rerun is not None and sinks.rerun._web is not None else None)

    pending: list[bytes] = []
    first_pending = 0.0
    outcome = None
    eof = False
    backlog = first[1:]
    max_batch = int(cfg.get("max_batch", 1024))
    batch_wall = float(cfg.get("batch_wall", 0.05))
    half_interval = 0.5 * float(cfg["flush_interval"])  # sim time a record may wait here
    poll = float(cfg["poll"])  # s between reads of the pipe (RunLogger sends _WRITER_POLL)
    last_read = 0.0
    os.set_blocking(0, False)
    os.set_blocking(bell, False)
    try:
        while outcome is None and not eof:
            frames = backlog
            backlog = []
            ready = True
            if not frames:
                # Poll instead of waking on every write: the simulating process then writes
                # into a pipe nobody reads at that moment, which costs it far less. No pause
                # when the last round of work took longer than one (the writer is behind).
                # A flush or the end rings the bell (bell), which ends the pause at once.
                if time.monotonic() - last_read < poll:
                    if bell is None:
                        time.sleep(poll)
                    elif select.select([bell], [], [], poll)[0]:
                        try:
                            if not os.read(bell, 4096):  # the simulating process is gone
                                os.close(bell)
                                bell = None
                        except BlockingIOError:
                            pass
                last_read = time.monotonic()
                ready = False
                got = 0
                while got < (4 << 20):  # at most 4 MiB a round: memory stays bounded
                    try:
                        data = os.read(0, 1 << 20)
                    except BlockingIOError:
                        break
                    if not data:
                        eof = True
                        break
                    reader.feed(data)
                    got += len(data)
                    ready = True
                if ready:
                    frames = reader.frames()
            for kind, payload in frames:
                if kind == _FRAME_RECORD:
                    if not pending:
                        first_pending = time.monotonic()
                    pending.append(payload)
                    if len(pending) >= max_batch:
                        sinks.write_payloads(pending)
                        pending = []
                elif kind == _FRAME_LAYOUT:
                    sinks.write_payloads(pending)
                    pending = []
                    sinks.layout = RecordLayout.from_json(json.loads(payload))
                elif kind == _FRAME_FLUSH:
                    sinks.write_payloads(pending)
                    pending = []
                    send("flushed", **sinks.flush())
                elif kind == _FRAME_END:
                    outcome = json.loads(payload)
                    break
            if pending and (
                not ready
                or eof
                or outcome is not None
                or time.monotonic() - first_pending >= batch_wall
                or _T.unpack_from(pending[-1])[0] - _T.unpack_from(pending[0])[0] >= half_interval
            ):
                sinks.write_payloads(pending)
                pending = []
            sinks.tick()
        sinks.write_payloads(pending)
        pending = []
    except Exception as exc:  # keep what was written: finish the file with the reason
        outcome = {"success": False, "status": -1, "message": f"log writer error: {type(exc).__name__}: {exc}"}
        warn_live(outcome["message"])
        eof = True
    if outcome is None:
        outcome = {
            "success": False,
            "status": -1,
            "message": "the simulating process ended without closing its log (killed?)",
        }
    summary = sinks.finish(outcome)
    send("finished", **summary)
    os.set_blocking(0, True)
    while not eof:  # a served viewer stays up until the simulating process lets go
        try:
            if not os.read(0, 1 << 16):
                break
        except OSError:
            break
    sinks.close()
    return 0


_WORKER_CODE = (
    "import sys, types\n"
    "pkg = types.ModuleType('qchain'); pkg.__path__ = [sys.argv[1]]; pkg.__version__ = sys.argv[2]\n"
    "sys.modules['qchain'] = pkg\n"
    "from qchain.logging import _worker_main\n"
    "sys.exit(_worker_main(sys.argv[3] == 'rerun', int(sys.argv[4])))\n"
)

_SPARE_WRITERS: list[tuple[bool, subprocess.Popen]] = []


def _launch_writer(rerun: bool) -> subprocess.Popen:
    """A new writer process; it imports what it needs at once and then waits for its
    configuration on stdin. Records go to its stdin, which it reads every ``poll`` seconds
    (so a write does not wake it); ``proc.bell`` is the write end of a second pipe, rung
    with one byte (:meth:`RunLogger._ring`) after a frame that needs an answer at once."""
    pkg_dir = str(Path(__file__).resolve().parent)
    # one BLAS thread: the writer does no linear algebra, and idle BLAS threads spinning at
    # start-up would take CPU time from the simulation
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    # this module's bytecode is cached beside it (as numba's kernels are) rather than
    # compiled again by every writer (60 ms)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    bell_r, bell_w = os.pipe()
    try:
        proc = subprocess.Popen(
            [sys.executable, "-c", _WORKER_CODE, pkg_dir, __version__, "rerun" if rerun else "mcap", str(bell_r)],
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            bufsize=0,
            process_group=0,  # Ctrl-C in a terminal reaches the simulation, not the writer
            close_fds=True,
            pass_fds=(bell_r,),
        )
    except BaseException:
        os.close(bell_w)
        raise
    finally:
        os.close(bell_r)
    # low priority from its start on (Popen returns once the exec is done; the writer's
    # first thread, OpenBLAS's, comes with numpy 30+ ms later and inherits it), not once the
    # writer has imported numpy: its 0.2 s start-up runs while the model is built, and the
    # simulating process's own threads (OpenBLAS's) must keep the other core then
    _yield_to_the_simulation(proc.pid)
    os.set_blocking(bell_w, False)
    proc.bell = bell_w
    return proc


def _close_bell(proc: subprocess.Popen) -> None:
    fd = getattr(proc, "bell", None)
    if fd is not None:
        proc.bell = None
        os.close(fd)


def prepare_writer(rerun: bool = False) -> None:
    """Start a writer process now, for the next :class:`RunLogger` of this process to use.

    A writer takes 0.2 s (MCAP) to 1 s (with ``rerun``: rerun-sdk is a large import) of CPU
    time to start. Called before the model is built (as ``qchain run`` does), that start-up
    runs on the other core while the model is built, and the logger of a short run waits for
    nothing. Without a later logger the process exits with this one.

    Parameters
    ----------
    rerun : bool
        The logger will have a Rerun target (``serve``, ``connect`` or ``rrd``).
    """
    if not any(r == bool(rerun) and p.poll() is None for r, p in _SPARE_WRITERS):
        _SPARE_WRITERS.append((bool(rerun), _launch_writer(bool(rerun))))


def _take_spare_writer(rerun: bool) -> subprocess.Popen | None:
    """A prepared writer still waiting, preferably one that imported Rerun iff ``rerun``."""
    _SPARE_WRITERS[:] = [(r, p) for r, p in _SPARE_WRITERS if p.poll() is None]
    if not _SPARE_WRITERS:
        return None
    best = min(_SPARE_WRITERS, key=lambda rp: rp[0] != rerun)
    _SPARE_WRITERS.remove(best)
    return best[1]


@atexit.register
def _stop_spare_writers() -> None:  # pragma: no cover - interpreter shutdown
    for _, p in _SPARE_WRITERS:
        p.kill()
        p.wait()
        p.stdin.close()
        p.stdout.close()
        _close_bell(p)
    _SPARE_WRITERS.clear()


# --------------------------------------------------------------------------------------
# RunLogger
# --------------------------------------------------------------------------------------

_OPEN_LOGGERS: weakref.WeakSet = weakref.WeakSet()


@atexit.register
def _close_open_loggers() -> None:  # pragma: no cover - interpreter shutdown
    for lg in list(_OPEN_LOGGERS):
        try:
            lg.linger = False
            lg.close(success=False, status=-1, message="the process exited without closing its log")
        except Exception:
            pass


class RunLogger:
    """Fans step records out to an MCAP file and Rerun, away from the simulation.

    Parameters
    ----------
    info : RunInfo
        Static information, recorded once.
    mcap : path, binary stream or None
        Where to write the MCAP recording. A path (parent folders are created) is written
        by a separate writer process; a binary stream (e.g. ``io.BytesIO``) by a thread of
        this process, and it is left open. ``None`` writes no MCAP.
    serve : bool
        Host a live Rerun gRPC server and web viewer on ``bind`` and print the URL.
    connect : str or None
        URL of a running Rerun viewer, e.g. ``rerun+http://127.0.0.1:9876/proxy``.
    rrd : path or None
        Also write a Rerun ``.rrd`` file.
    bind : str
        Address the servers listen on; ``127.0.0.1`` (this machine only) by default.
    grpc_port, web_port : int or None
        Ports of the gRPC server and the web viewer; by default 9876 and 9090 when free,
        else free ports.
    worker : {"auto", "process", "thread"}
        Where the writing happens; ``"auto"`` takes a process for file outputs and a
        thread for a stream.
    flush_interval : float, s
        Simulation time between MCAP chunk flushes (bounds what a SIGKILL loses).
    flush_wall_interval : float, s
        Wall time between MCAP chunk flushes.
    max_queue : int
        Records the thread worker's queue holds before ``log()`` waits (the process
        worker's bound is its pipe, 1 MiB, plus a 64 KiB buffer).
    linger : bool
        When serving, keep the viewer served after the run until Ctrl-C (for the CLI).
    recording_id : str or None
        Rerun recording id (default: a new UUID), also stored in the MCAP.
    server_memory_limit : str
        What the served gRPC server keeps for viewers that connect late (oldest data go
        first), e.g. ``"1GiB"``.
    rerun_rate : float or None, 1/s
        A display rate: send Rerun at most this many records a simulated second (None:
        every record). The MCAP always gets every record.
    rerun_latency : float, s
        Wall time records gather before they go to Rerun in one ``send_columns`` batch (a
        batch costs the writer ~2-4 ms whatever its size, so this bounds the viewer's cost;
        the live view updates this often). The first batch goes at once.
    quiet : bool
        Do not print the viewer URL.

    Notes
    -----
    Use it as a context manager. Leaving the block normally records success; an exception
    (KeyboardInterrupt included) records a failure with the exception's text, and the file
    is finished in every case. Call :meth:`set_outcome` before leaving to record a
    simulation's own status and message. Call ``log()`` from one thread.

    Starting the process worker takes 0.2 to 1 s of CPU time (a fresh interpreter importing
    numpy, mcap and, for Rerun targets, rerun-sdk). The constructor waits only for the
    process to exist (every record is then crash-safe: the writer drains its pipe even
    after a SIGKILL of this process) and, when serving or connecting to a viewer, for the
    viewer's URL; for files only the writer's answer is read at the next :meth:`flush` or
    at :meth:`close`. Call :func:`prepare_writer` earlier (before building the model, as
    ``qchain run`` does) and that start-up runs on the other core meanwhile.

    Examples
    --------
    ::

        info = RunInfo(n_segments=3, radii=[0.015] * 3, scene=text, params=params)
        with RunLogger(info, "runs/arm.mcap", serve=True) as log:
            for k in range(n_steps):
                ...  # advance the simulation
                log.log(StepRecord(t=k * dt, step=k, q=q, v=v, p=p, kinetic=T, potential=U,
                                   total=T + U, backbone=points, tip_frames=frames))
    """

    def __init__(
        self,
        info: RunInfo,
        mcap: str | os.PathLike | BinaryIO | None = None,
        *,
        serve: bool = False,
        connect: str | None = None,
        rrd: str | os.PathLike | None = None,
        bind: str = DEFAULT_BIND,
        grpc_port: int | None = None,
        web_port: int | None = None,
        worker: str = "auto",
        flush_interval: float = DEFAULT_FLUSH_INTERVAL,
        flush_wall_interval: float = DEFAULT_FLUSH_WALL_INTERVAL,
        chunk_bytes: int = DEFAULT_CHUNK_BYTES,
        max_queue: int = DEFAULT_MAX_QUEUE,
        linger: bool = False,
        recording_id: str | None = None,
        server_memory_limit: str = "1GiB",
        rerun_rate: float | None = None,
        rerun_latency: float = DEFAULT_RERUN_LATENCY,
        quiet: bool = False,
        startup_timeout: float = 60.0,
    ):
        if not isinstance(info, RunInfo):
            raise TypeError(f"info must be a RunInfo, got {type(info).__name__}")
        for name, value in (("flush_interval", flush_interval), ("flush_wall_interval", flush_wall_interval),
                            ("rerun_latency", rerun_latency)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number of seconds > 0, got {value!r}")
        if not (isinstance(max_queue, int) and max_queue >= 1):
            raise ValueError(f"max_queue must be an int >= 1, got {max_queue!r}")
        if rerun_rate is not None and not (isinstance(rerun_rate, (int, float)) and rerun_rate > 0):
            raise ValueError(f"rerun_rate must be None or > 0 records a simulated second, got {rerun_rate!r}")
        if worker not in ("auto", "process", "thread"):
            raise ValueError(f"worker must be 'auto', 'process' or 'thread', got {worker!r}")
        if serve and connect:
            raise ValueError("serve and connect exclude each other: serve hosts a viewer, connect uses one")
        stream = None
        mcap_path = None
        if mcap is not None:
            if isinstance(mcap, (str, os.PathLike)):
                mcap_path = Path(mcap)
                if mcap_path.is_dir():
                    raise ValueError(f"mcap must be a file path, got the folder {mcap_path}")
                mcap_path.parent.mkdir(parents=True, exist_ok=True)
                open(mcap_path, "wb").close()  # can it be written? Here, where the path comes in
            elif hasattr(mcap, "write"):
                stream = mcap
            else:
                raise ValueError(f"mcap must be a path, a binary stream or None, got {type(mcap).__name__}")
        if rrd is not None:
            rrd = Path(rrd)
            rrd.parent.mkdir(parents=True, exist_ok=True)
        if worker == "auto":
            worker = "thread" if stream is not None else "process"
        if worker == "process" and stream is not None:
            raise ValueError("worker='process' cannot write into an in-memory stream; use worker='thread'")
        self.info = info
        self.mcap_path = mcap_path
        self.rrd_path = rrd
        self.worker = worker
        self.linger = bool(linger)
        self.quiet = bool(quiet)
        self.flush_interval = float(flush_interval)
        self.recording_id = recording_id or str(uuid.uuid4())
        self.viewer_url: str | None = None
        self.grpc_url: str | None = None
        self.worker_pid: int | None = None
        self.web_pid: int | None = None
        self.n_logged = 0
        self._layout: RecordLayout | None = None
        self._closed = False
        self._broken: str | None = None
        self._warned_broken = False
        self._ready_pending = False  # the writer's answer to its configuration not read yet
        self._outcome: dict | None = None
        self._max_queue = int(max_queue)
        self._summary: dict | None = None
        self._final: dict | None = None
        cfg = {
            "info": info.to_json(),
            "mcap": None if mcap_path is None else str(mcap_path),
            "serve": bool(serve),
            "connect": connect,
            "rrd": None if rrd is None else str(rrd),
            "bind": bind,
            "grpc_port": grpc_port,
            "web_port": web_port,
            "recording_id": self.recording_id,
            "flush_interval": float(flush_interval),
            "flush_wall_interval": float(flush_wall_interval),
            "chunk_bytes": int(chunk_bytes),
            "server_memory_limit": server_memory_limit,
            "rerun_rate": rerun_rate,
            "rerun_latency": float(rerun_latency),
            "poll": _WRITER_POLL,
        }
        if worker == "thread":
            self._start_thread(cfg, stream)
        else:
            self._start_process(cfg, startup_timeout)
        if self.viewer_url and not self.quiet:
            print(f"qchain: live Rerun viewer at {self.viewer_url}  (open it in a browser)",
                  file=sys.stderr, flush=True)
        _OPEN_LOGGERS.add(self)

    # -- workers -----------------------------------------------------------------------------

    def _start_thread(self, cfg: dict, stream) -> None:
        warned: list[str] = []
        self._sinks = _SinkSet(cfg, stream, warned.append)
        self._sinks.warn = lambda m: warnings.warn(f"qchain.logging: {m}", LoggingWarning, stacklevel=2)
        for m in warned:
            warnings.warn(f"qchain.logging: {m}", LoggingWarning, stacklevel=4)
        self.viewer_url = self._sinks.viewer_url
        self.grpc_url = self._sinks.rerun.grpc_url if self._sinks.rerun else None
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._thread_loop, name="qchain-log-writer", daemon=True)
        self._thread.start()
        self._put = self._put_thread

    def _put_thread(self, payload: bytes, t: float) -> None:
        q = self._q
        if q.qsize() >= self._max_queue:  # bounded: wait for the writer rather than grow
            while q.qsize() >= self._max_queue and self._thread.is_alive():
                time.sleep(0.0005)
        q.put(payload)

    def _thread_loop(self) -> None:
        q, sinks = self._q, self._sinks
        outcome = None
        try:
            while outcome is None:
                try:
                    items = [q.get(timeout=0.25)]
                except queue.Empty:
                    sinks.tick()
                    continue
                while len(items) < 1024:
                    try:
                        items.append(q.get_nowait())
                    except queue.Empty:
                        break
                payloads: list[bytes] = []
                for item in items:
                    if type(item) is bytes:
                        payloads.append(item)
                    elif item[0] == "L":
                        sinks.write_payloads(payloads)
                        payloads = []
                        sinks.layout = item[1]
                    elif item[0] == "F":
                        sinks.write_payloads(payloads)
                        payloads = []
                        item[1].append(sinks.flush())
                        item[2].set()
                    elif item[0] == "E":
                        outcome = item[1]
                        break
                sinks.write_payloads(payloads)
                sinks.tick()
        except Exception as exc:
            self._broken = f"the log writer failed ({type(exc).__name__}: {exc})"
            outcome = {"success": False, "status": -1, "message": self._broken}
        try:
            self._summary = sinks.finish(outcome)
        except Exception as exc:  # pragma: no cover - disk full and the like
            self._broken = f"the log writer could not finish ({type(exc).__name__}: {exc})"

    def _start_process(self, cfg: dict, timeout: float) -> None:
        rerun = bool(cfg["serve"] or cfg["connect"] or cfg["rrd"])
        self._proc = _take_spare_writer(rerun) or _launch_writer(rerun)
        self.worker_pid = self._proc.pid
        self._wfd = self._proc.stdin.fileno()
        try:
            import fcntl

            fcntl.fcntl(self._wfd, 1031, 1 << 20)  # F_SETPIPE_SZ: a 1 MiB pipe
        except (ImportError, OSError):
            pass
        os.set_blocking(self._wfd, False)
        self._status_buf = b""
        self._wbuf: list[bytes] = []
        self._wbuf_bytes = 0
        self._wbuf_t0: float | None = None
        self._wbuf_wall = 0.0
        self._pipe_sim = 0.5 * cfg["flush_interval"]  # sim time a record may wait in this process
        payload = json.dumps(cfg).encode()
        self._write_all(_FRAME.pack(_FRAME_CONFIG, len(payload)) + payload)
        self._put = self._put_pipe
        self._ready_pending = True
        if cfg["serve"] or cfg["connect"]:  # the viewer's URL, or that it is missing, comes first
            self._take_ready(timeout, starting=True)
        # Files only: the writer's answer is read at the next flush or at close. Records are
        # crash-safe already (the writer process exists and drains its pipe even after a
        # SIGKILL of this one), the MCAP path was checked in __init__, and a writer still
        # importing rerun-sdk (prepare_writer shortly before) answers only after 10-30 ms.

    def _take_ready(self, timeout: float, starting: bool = False) -> None:
        """Read the writer's answer to its configuration ("ready", with the viewer's URL and
        start-up warnings) if not read yet. A writer that could not start raises
        :class:`LoggingError` when ``starting`` (the constructor waits), else it leaves the
        logger broken with the reason."""
        if not self._ready_pending:
            return
        self._ready_pending = False
        msg = self._read_status(timeout)
        if msg is None or msg.get("event") != "ready":
            why = (msg or {}).get("message", "it did not answer in time or exited")
            why = f"the log writer could not start ({why}); MCAP path: {self.mcap_path}"
            if starting:
                self._proc.kill()
                self._proc.wait()
                _close_bell(self._proc)
                raise LoggingError(why)
            self._broken = self._broken or why
            return
        for m in msg.get("warnings", []):
            warnings.warn(f"qchain.logging: {m}", LoggingWarning, stacklevel=5 if starting else 4)
        self.viewer_url = msg.get("viewer_url")
        self.grpc_url = msg.get("grpc_url")
        self.web_pid = msg.get("web_pid")

    def _put_pipe(self, payload: bytes, t: float) -> None:
        frame = _FRAME.pack(_FRAME_RECORD, len(payload)) + payload
        self._wbuf.append(frame)
        self._wbuf_bytes += len(frame)
        if self._wbuf_t0 is None:
            self._wbuf_t0 = t
            self._wbuf_wall = time.monotonic()
        if (
            self._wbuf_bytes >= 65536
            or t - self._wbuf_t0 >= self._pipe_sim
            or time.monotonic() - self._wbuf_wall >= 0.05
        ):
            self._flush_pipe()

    def _flush_pipe(self) -> None:
        if not self._wbuf or self._broken is not None:
            return
        data = b"".join(self._wbuf)
        self._wbuf.clear()
        self._wbuf_bytes = 0
        self._wbuf_t0 = None
        try:
            self._write_all(data)
        except OSError as exc:
            code = self._proc.poll()
            self._broken = f"the log writer process exited (code {code}; {exc.strerror or exc})"

    def _write_all(self, data: bytes) -> None:
        """Write all of ``data`` to the writer's pipe, with SIGINT held back meanwhile so a
        Ctrl-C never cuts a frame in half (it is delivered right after)."""
        old = None if _sigmask is None else _sigmask(signal.SIG_BLOCK, _SIGINT_SET)
        try:
            view = memoryview(data)
            while view:
                try:
                    n = os.write(self._wfd, view)
                    view = view[n:]
                except BlockingIOError:  # pipe full: the writer is behind; wait for room
                    select.select([], [self._wfd], [], 0.5)
                    if self._proc.poll() is not None:
                        raise BrokenPipeError(32, "the log writer process is gone") from None
        finally:
            if old is not None:
                _sigmask(signal.SIG_SETMASK, old)

    def _ring(self) -> None:
        """Wake the writer from its pause between reads (a frame waits that needs an answer)."""
        try:
            os.write(self._proc.bell, b"!")
        except (BlockingIOError, BrokenPipeError):  # already rung / the writer is gone
            pass

    def _read_status(self, timeout: float) -> dict | None:
        deadline = time.monotonic() + timeout
        fd = self._proc.stdout.fileno()
        while b"\n" not in self._status_buf:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            if select.select([fd], [], [], min(left, 0.5))[0]:
                data = os.read(fd, 65536)
                if not data:
                    return None
                self._status_buf += data
            elif self._proc.poll() is not None and b"\n" not in self._status_buf:
                return None
        line, _, self._status_buf = self._status_buf.partition(b"\n")
        return json.loads(line)

    # -- logging -----------------------------------------------------------------------------

    def _init_layout(self, r: StepRecord) -> RecordLayout:
        n = self.info.n_segments
        shapes = {f: np.shape(getattr(r, f)) for f in ("q", "v", "p", "backbone", "tip_frames")}
        for f in ("q", "v", "p"):
            if len(shapes[f]) != 1:
                raise ValueError(f"record.{f} must be a vector, got shape {shapes[f]}")
        bb = shapes["backbone"]
        if len(bb) != 3 or bb[0] != n or bb[2] != 3 or bb[1] < 1:
            raise ValueError(f"record.backbone must have shape ({n}, P, 3) with P >= 1, got {bb}")
        if shapes["tip_frames"] != (n, 7):
            raise ValueError(f"record.tip_frames must have shape ({n}, 7), got {shapes['tip_frames']}")
        return self._set_layout(RecordLayout(shapes["q"][0], shapes["v"][0], shapes["p"][0], n, bb[1]))

    def _set_layout(self, lay: RecordLayout) -> RecordLayout:
        """The run's record layout (fixed by its first record); sent to the writer."""
        self._shapes = {"q": (lay.nq,), "v": (lay.nv,), "p": (lay.n_p,), "backbone": (lay.n, lay.P, 3),
                        "tip_frames": (lay.n, 7)}
        self._layout = lay
        self._payload_size = 8 * lay.row_width
        if self.worker == "thread":
            self._q.put(("L", lay))
        else:
            p = json.dumps(lay.to_json()).encode()
            self._wbuf.append(_FRAME.pack(_FRAME_LAYOUT, len(p)) + p)
            self._wbuf_bytes += len(p)
        return lay

    def _shape_error(self, r: StepRecord) -> ValueError:
        for f, expected in self._shapes.items():
            got = np.shape(getattr(r, f))
            if got != expected:
                return ValueError(f"record.{f} has shape {got} at step {r.step}; the first record had {expected}")
        return ValueError(f"record at step {r.step} does not match the first record's shapes {self._shapes}")

    def _warn_broken(self, step) -> None:
        if not self._warned_broken:
            self._warned_broken = True
            warnings.warn(f"qchain.logging: {self._broken}; records from step {step} on are not logged",
                          LoggingWarning, stacklevel=3)

    def log(self, record: StepRecord) -> None:
        """Queue one record (copied); waits only when the writer is far behind.

        Raises
        ------
        ValueError
            Shapes that differ from the first record's, or a time that is not finite and
            >= 0.
        LoggingError
            The logger is closed.
        """
        if self._closed:
            raise LoggingError("log() on a closed RunLogger")
        if self._broken is not None:
            self._warn_broken(record.step)
            return
        lay = self._layout
        if lay is None:
            lay = self._init_layout(record)
        t = record.t
        if not (t >= 0.0 and t < math.inf):
            raise ValueError(f"record.t must be finite and >= 0 s, got {t!r} at step {record.step}")
        q, v, p, bb, tf = record.q, record.v, record.p, record.backbone, record.tip_frames
        try:
            fast = q.dtype is _F8 and v.dtype is _F8 and p.dtype is _F8 and bb.dtype is _F8 and tf.dtype is _F8
        except AttributeError:
            fast = False
        if not fast:
            q, v, p, bb, tf = (np.asarray(x, dtype=np.float64) for x in (q, v, p, bb, tf))
        payload = b"".join(
            (_HEAD.pack(t, record.step), q.tobytes(), v.tobytes(), p.tobytes(),
             _ENERGY.pack(record.kinetic, record.potential, record.total), bb.tobytes(), tf.tobytes())
        )
        shapes = self._shapes
        if len(payload) != self._payload_size or bb.shape != shapes["backbone"] or tf.shape != shapes["tip_frames"]:
            raise self._shape_error(record)
        self._put(payload, t)
        self.n_logged += 1

    def log_rows(self, rows: np.ndarray, layout: RecordLayout) -> None:
        """Queue ``K`` records given as rows of ``layout``: the cheapest way in (one copy and
        one write to the writer for all of them, no further buffering here).

        Parameters
        ----------
        rows : (K, layout.row_width) float64
            One record a row (see :class:`RecordLayout`).
        layout : RecordLayout
            Must be the run's: that of its first record.

        Raises
        ------
        ValueError
            A layout or shape that differs from the run's, or a time that is not finite and
            >= 0.
        LoggingError
            The logger is closed.
        """
        if self._closed:
            raise LoggingError("log_rows() on a closed RunLogger")
        if not isinstance(layout, RecordLayout):
            raise TypeError(f"layout must be a RecordLayout, got {type(layout).__name__}")
        if not (isinstance(rows, np.ndarray) and rows.dtype == np.float64 and rows.ndim == 2
                and rows.shape[1] == layout.row_width):
            raise ValueError(f"rows must be a float64 array of shape (K, {layout.row_width}), got "
                             f"{getattr(rows, 'dtype', type(rows).__name__)} {np.shape(rows)}")
        K = rows.shape[0]
        if K == 0:
            return
        if self._broken is not None:
            self._warn_broken(int(rows[0, 1]))
            return
        if self._layout is None:
            if layout.n != self.info.n_segments:
                raise ValueError(f"layout.n = {layout.n} segments, but the run's RunInfo has {self.info.n_segments}")
            self._set_layout(layout)
        elif layout != self._layout:
            raise ValueError(f"layout {layout} differs from the run's {self._layout} (fixed by its first record)")
        t = rows[:, 0].tolist()  # checked as Python floats: cheaper than numpy for a few rows
        for i, ti in enumerate(t):
            if not 0.0 <= ti < math.inf:
                raise ValueError(f"t must be finite and >= 0 s, got {ti!r} at step {int(rows[i, 1])}")
        data = rows.tobytes()
        if self.worker == "thread":
            self._put_thread(data, t[-1])
        else:
            self._wbuf.append(_FRAME.pack(_FRAME_RECORD, len(data)) + data)
            self._wbuf_bytes += len(data)
            self._flush_pipe()
        self.n_logged += K

    def log_columns(self, t, step, q, v, p, kinetic, potential, total, backbone, tip_frames) -> None:
        """Queue ``K`` records given as columns: the batch form of :meth:`log`.

        Parameters
        ----------
        t : (K,) s
        step : (K,) int
        q : (K, nq)
        v : (K, nv)
        p : (K, 3 n) Pa
        kinetic, potential, total : (K,) J
        backbone : (K, n, P, 3) m
        tip_frames : (K, n, 7)
            As the fields of :class:`StepRecord`, one row a record.

        Raises
        ------
        ValueError
            Columns of different lengths, shapes that differ from the first record's, or a time
            that is not finite and >= 0.
        LoggingError
            The logger is closed.
        """
        if self._closed:
            raise LoggingError("log_columns() on a closed RunLogger")
        t = np.asarray(t, dtype=np.float64)
        if t.ndim != 1:
            raise ValueError(f"t must have shape (K,), got {t.shape}")
        K = t.shape[0]
        cols = [np.asarray(x, dtype=np.float64) for x in (step, q, v, p, kinetic, potential, total, backbone,
                                                          tip_frames)]
        for name, x in zip(_COLUMNS, cols):
            if x.ndim < 1 or x.shape[0] != K:
                raise ValueError(f"{name} must have a leading axis of K = {K} (the length of t), got shape {x.shape}")
        if K == 0:
            return
        if self._layout is None:
            self._init_layout(StepRecord(float(t[0]), int(cols[0][0]), *(x[0] for x in cols[1:])))
        step, q, v, p, kinetic, potential, total, backbone, tip_frames = cols
        for f, x in (("q", q), ("v", v), ("p", p), ("backbone", backbone), ("tip_frames", tip_frames)):
            if x.shape[1:] != self._shapes[f]:
                raise ValueError(f"{f} has rows of shape {x.shape[1:]}; the first record had {self._shapes[f]}")
        rows = np.concatenate(
            (t[:, None], step[:, None], q, v, p, kinetic[:, None], potential[:, None], total[:, None],
             backbone.reshape(K, -1), tip_frames.reshape(K, -1)),
            axis=1,
        )
        self.log_rows(rows, self._layout)

    def set_outcome(self, success: bool = True, message: str = "", status: int | None = None, nfev: int = 0) -> None:
        """Record how the run ended (written when the logger closes).

        Parameters
        ----------
        success : bool
        message : str
            Why the run ended.
        status : int or None
            0 finished, 1 stopped by an event, -1 failed; default 0 if success else -1.
        nfev : int
            Number of forward-dynamics evaluations.
        """
        if status is None:
            status = 0 if success else -1
        self._outcome = {"success": bool(success), "message": str(message), "status": int(status), "nfev": int(nfev)}

    def flush(self, timeout: float = 60.0) -> dict:
        """Wait until every record logged so far is in the MCAP file (its chunk closed and
        handed to the operating system) and sent to Rerun.

        Returns ``{"n_records": written so far, "last_t": s}``; raises :class:`LoggingError`
        if the writer does not answer within ``timeout`` seconds.
        """
        if self._closed:
            raise LoggingError("flush() on a closed RunLogger")
        if self._broken is not None:
            raise LoggingError(self._broken)
        if self.worker == "thread":
            box: list = []
            done = threading.Event()
            self._q.put(("F", box, done))
            if not done.wait(timeout):
                raise LoggingError(f"the log writer did not flush within {timeout} s")
            return box[0]
        self._wbuf.append(_FRAME.pack(_FRAME_FLUSH, 0))
        self._flush_pipe()
        self._ring()
        self._take_ready(timeout)
        if self._broken is not None:
            raise LoggingError(self._broken)
        msg = self._read_status(timeout)
        if msg is None or msg.get("event") != "flushed":
            raise LoggingError(f"the log writer did not flush within {timeout} s ({self._broken or msg})")
        return {"n_records": msg["n_records"], "last_t": msg["last_t"]}

    # -- closing -----------------------------------------------------------------------------

    def close(self, success: bool | None = None, message: str | None = None, status: int | None = None) -> dict:
        """Finish the recording (MCAP summary written) and stop the writer.

        Parameters are as for :meth:`set_outcome` and override it when given. Returns a
        summary dict: ``n_records`` (written), ``last_t``, ``mcap``, ``rrd``,
        ``viewer_url``. With ``linger`` and a served viewer, waits for Ctrl-C first.
        """
        if self._closed:
            return self._final or {}
        self._closed = True
        _OPEN_LOGGERS.discard(self)
        outcome = dict(self._outcome or {"success": True, "message": "finished", "status": 0, "nfev": 0})
        if success is not None:
            outcome["success"] = bool(success)
            outcome["status"] = int(status) if status is not None else (0 if success else -1)
        elif status is not None:
            outcome["status"] = int(status)
        if message is not None:
            outcome["message"] = str(message)
        outcome["n_logged"] = self.n_logged
        if self.worker == "thread":
            self._q.put(("E", outcome))
            self._join(self._thread)
            summary = self._summary or {}
            try:
                if self.linger and self.viewer_url:
                    self._wait_while_serving(lambda: True)
            finally:
                self._sinks.close()
        else:
            summary = self._close_process(outcome)
        self._final = {
            "n_records": summary.get("n_records", 0),
            "last_t": summary.get("last_t"),
            "mcap": None if self.mcap_path is None else str(self.mcap_path),
            "rrd": None if self.rrd_path is None else str(self.rrd_path),
            "viewer_url": self.viewer_url,
        }
        if self._broken is not None:
            warnings.warn(f"qchain.logging: {self._broken}", LoggingWarning, stacklevel=2)
        return self._final

    def _wait_while_serving(self, alive) -> None:
        print(f"qchain: the run is over; still serving the viewer at {self.viewer_url} - press Ctrl-C to stop",
              file=sys.stderr, flush=True)
        try:
            while alive():
                time.sleep(0.5)
        except KeyboardInterrupt:
            pass

    @staticmethod
    def _join(thread: threading.Thread) -> None:
        while thread.is_alive():
            thread.join(0.2)

    def _close_process(self, outcome: dict) -> dict:
        proc = self._proc
        summary: dict = {}
        if self._broken is None:
            p = json.dumps(outcome).encode()
            self._wbuf.append(_FRAME.pack(_FRAME_END, len(p)) + p)
            self._flush_pipe()
            self._ring()
        self._take_ready(120.0)
        if self._broken is None:
            msg = self._read_status(120.0)
            if msg is not None and msg.get("event") == "finished":
                summary = msg
            else:
                self._broken = "the log writer did not confirm the end of the recording"
        try:
            if self.linger and self.viewer_url and proc.poll() is None:
                self._wait_while_serving(lambda: proc.poll() is None)
        finally:
            try:
                proc.stdin.close()
            except OSError:
                pass
            proc.stdout.close()
            _close_bell(proc)
            if summary:
                # the files are complete; the writer's own exit (interpreter and Rerun
                # teardown, 50-200 ms) need not hold up the caller: reap it in the background
                threading.Thread(target=self._reap, args=(proc,), name="qchain-log-reaper", daemon=True).start()
            else:
                self._reap(proc)
        return summary

    @staticmethod
    def _reap(proc: subprocess.Popen) -> None:
        try:
            proc.wait(30.0)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()

    def __enter__(self) -> RunLogger:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        elif issubclass(exc_type, KeyboardInterrupt):
            self.linger = False
            self.close(success=False, status=-1, message="interrupted (KeyboardInterrupt)")
        else:
            self.linger = False
            self.close(success=False, status=-1, message=f"the simulation raised {exc_type.__name__}: {exc}")


# --------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------


@dataclass
class Recording:
    """Everything a qchain MCAP holds (the reading side of :class:`RunLogger`).

    Attributes
    ----------
    path : str
    info : RunInfo
    t : (N,) s
    step : (N,) int
    q, v, p : (N, nq), (N, nv), (N, 3 n)
    energy : (N, 3) J
        (kinetic, potential, total).
    backbone : (N, n, P, 3) m
    tip_frames : (N, n, 7)
    outcome : dict or None
        The ``qchain.outcome`` metadata (None when the run never closed its log).
    truncated : bool
        The file ends before its summary (a killed run); the data are those up to the last
        complete chunk.
    stop_reason : str
        Why reading stopped early ("" when the file is complete).
    metadata : dict
        The raw ``qchain`` metadata record.
    """

    path: str
    info: RunInfo
    t: np.ndarray
    step: np.ndarray
    q: np.ndarray
    v: np.ndarray
    p: np.ndarray
    energy: np.ndarray
    backbone: np.ndarray
    tip_frames: np.ndarray
    outcome: dict | None
    truncated: bool
    stop_reason: str
    metadata: dict

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def batch(self) -> _Batch:
        return _Batch(self.t, self.step, self.q, self.v, self.p, self.energy, self.backbone, self.tip_frames)

    def to_trajectory(self) -> Trajectory:
        """The recording as a :class:`~qchain.trajectory.Trajectory`; ``meta`` keeps the
        rest (``step``, ``backbone``, ``tip_frames``, ``total_energy``, ``info``, ``path``,
        ``truncated``, ``stopped_at``, ``outcome``)."""
        out = self.outcome
        if self.truncated:
            end = "no samples" if len(self) == 0 else f"t = {self.t[-1]:.6g} s"
            success, status = False, -1
            message = f"recording truncated after its last complete chunk ({end}): {self.stop_reason}"
        elif out is None:
            success, status, message = False, -1, "the run did not record how it ended"
        else:
            success = out.get("success") == "true"
            status = int(out.get("status", 0 if success else -1))
            message = out.get("message", "")
        return Trajectory(
            t=self.t,
            q=self.q,
            v=self.v,
            p=self.p,
            kinetic_energy=self.energy[:, 0],
            potential_energy=self.energy[:, 1],
            success=success,
            message=message,
            nfev=int(out.get("nfev", 0)) if out else 0,
            status=status,
            meta={
                "path": self.path,
                "step": self.step,
                "backbone": self.backbone,
                "tip_frames": self.tip_frames,
                "total_energy": self.energy[:, 2],
                "info": self.info,
                "truncated": self.truncated,
                "stopped_at": float(self.t[-1]) if (self.truncated and len(self)) else None,
                "outcome": out,
                "qchain_version": self.info.qchain_version,
                "scene": self.info.scene,
                "params": self.info.params,
            },
        )


def _floats(values: list) -> np.ndarray:
    return np.array(values, dtype=float)  # JSON null (a non-finite number) -> NaN


def read_recording(source: str | os.PathLike | BinaryIO) -> Recording:
    """Read a qchain MCAP recording, complete or truncated.

    Parameters
    ----------
    source : path or binary stream

    Raises
    ------
    RecordingFormatError
        The file is not an MCAP file, not a qchain recording, or cut before its header
        records; the message names the file.
    FileNotFoundError
    """
    import orjson
    from mcap.records import Channel, Footer, Message, Metadata
    from mcap.stream_reader import StreamReader

    if isinstance(source, (str, os.PathLike)):
        name = os.fspath(source)
        stream: BinaryIO = open(name, "rb")
        owns = True
    else:
        name = getattr(source, "name", None) or f"<{type(source).__name__}>"
        stream = source
        owns = False
    try:
        head = stream.read(len(_MCAP_MAGIC))
        if len(head) == 0:
            raise RecordingFormatError(f"{name}: the file is empty, not a qchain MCAP recording")
        if head != _MCAP_MAGIC:
            raise RecordingFormatError(
                f"{name}: not an MCAP file (it starts with {head!r}, an MCAP file with {_MCAP_MAGIC!r})"
            )
        stream.seek(stream.tell() - len(head))
        topics_by_channel: dict[int, str] = {}
        wanted = {v: k for k, v in TOPICS.items()}
        data: dict[str, list[bytes]] = {k: [] for k in TOPICS}
        meta = None
        outcome = None
        complete = False
        stop_reason = ""
        reader = StreamReader(stream, validate_crcs=True, record_size_limit=1 << 32)
        try:
            for rec in reader.records:
                if isinstance(rec, Message):
                    if meta is None:  # qchain writes its metadata before any message
                        break
                    key = topics_by_channel.get(rec.channel_id)
                    if key is not None:
                        data[key].append(rec.data)
                elif isinstance(rec, Channel):
                    if rec.topic in wanted:
                        topics_by_channel[rec.id] = wanted[rec.topic]
                elif isinstance(rec, Metadata):
                    if rec.name == "qchain" and meta is None:
                        meta = dict(rec.metadata)
                    elif rec.name == "qchain.outcome":
                        outcome = dict(rec.metadata)
                elif isinstance(rec, Footer):
                    complete = True
        except Exception as exc:  # a cut or damaged tail: keep what came before
            stop_reason = f"{type(exc).__name__}: {exc}" if str(exc) else type(exc).__name__
        if not complete and not stop_reason and meta is not None:
            stop_reason = "the file ends before its footer"
        complete = complete and not stop_reason  # a damaged closing magic counts as a cut too
    finally:
        if owns:
            stream.close()
    if meta is None or meta.get("format") != FORMAT_NAME:
        if stop_reason:
            raise RecordingFormatError(
                f"{name}: an MCAP file without a qchain header record (cut before it, or written by "
                f"another program; reading stopped: {stop_reason})"
            )
        raise RecordingFormatError(
            f"{name}: an MCAP file, but not a qchain recording (no 'qchain' metadata record with "
            f"format {FORMAT_NAME!r})"
        )
    try:
        version = int(meta.get("format_version", "0"))
    except ValueError:
        version = -1
    if version != FORMAT_VERSION:
        raise RecordingFormatError(
            f"{name}: qchain recording format version {meta.get('format_version')!r}; this qchain reads "
            f"version {FORMAT_VERSION}"
        )
    try:
        info = RunInfo.from_json(json.loads(meta["info"]))
    except (KeyError, ValueError, TypeError) as exc:
        raise RecordingFormatError(f"{name}: its qchain metadata record is damaged ({exc})") from None

    try:
        return _decode(name, info, data, meta, outcome, complete, stop_reason, orjson.loads)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise RecordingFormatError(f"{name}: a qchain message does not have the expected form ({exc!r})") from None


def _decode(name, info, data, meta, outcome, complete, stop_reason, loads) -> Recording:
    n = info.n_segments
    by_step: dict[str, dict[int, dict]] = {}
    for key, blobs in data.items():
        d = {}
        for blob in blobs:
            msg = loads(blob)
            if key in ("tip_frames", "backbone"):
                d[len(d)] = msg  # no step field: position in the channel
            else:
                d[int(msg["step"])] = msg
        by_step[key] = d
    steps_q = list(by_step["q"].keys())
    # steps present on every per-step channel (a truncated file may cut between chunks)
    count = min(len(by_step["tip_frames"]), len(by_step["backbone"]))
    common = [s for s in steps_q[:count] if s in by_step["v"] and s in by_step["p"] and s in by_step["energy"]]
    if len(common) != len(steps_q) and complete:
        raise RecordingFormatError(f"{name}: the channels hold different steps; the file is damaged")
    N = len(common)
    pos = {s: i for i, s in enumerate(steps_q[:count])}
    t = np.array([by_step["q"][s]["t"] for s in common], dtype=float)
    step = np.array(common, dtype=np.int64)
    q = _floats([by_step["q"][s]["q"] for s in common])
    v = _floats([by_step["v"][s]["v"] for s in common])
    p = _floats([by_step["p"][s]["p"] for s in common])
    energy = _floats(
        [[by_step["energy"][s][k] for k in ("kinetic", "potential", "total")] for s in common]
    ).reshape(N, 3)
    tip = np.full((N, n, 7), np.nan)
    backbone_rows = []
    for r, s in enumerate(common):
        i = pos[s]
        tf = by_step["tip_frames"][i]["transforms"]
        for j, fr in enumerate(tf[:n]):
            tr, ro = fr["translation"], fr["rotation"]
            tip[r, j] = [tr["x"], tr["y"], tr["z"], ro["x"], ro["y"], ro["z"], ro["w"]]
        ents = by_step["backbone"][i]["entities"]
        backbone_rows.append([[(pt["x"], pt["y"], pt["z"]) for pt in e["lines"][0]["points"]] for e in ents[:n]])
    if N:
        backbone = _floats(backbone_rows)
    else:
        backbone = np.zeros((0, n, 0, 3))
    if N == 0:
        q = q.reshape(0, 0)
        v = v.reshape(0, 0)
        p = p.reshape(0, 3 * n)
    return Recording(
        path=name,
        info=info,
        t=t,
        step=step,
        q=q,
        v=v,
        p=p,
        energy=energy,
        backbone=backbone,
        tip_frames=tip.astype(float),
        outcome=outcome,
        truncated=not complete,
        stop_reason=stop_reason,
        metadata=meta,
    )


def read_mcap(path: str | os.PathLike | BinaryIO) -> Trajectory:
    """Read a qchain MCAP recording as a :class:`~qchain.trajectory.Trajectory`.

    A truncated recording (a killed run) reads up to its last complete chunk; the
    trajectory then has ``success=False``, a message saying where it stopped, and
    ``meta["truncated"] = True``, ``meta["stopped_at"]`` (s). ``meta`` also holds the
    step numbers, backbone points (N, n, P, 3), tip frames (N, n, 7), logged total
    energy, scene text, model parameters and qchain version.

    Raises
    ------
    RecordingFormatError
        Not a qchain MCAP recording (message names the file and what is wrong).
    """
    return read_recording(path).to_trajectory()


# --------------------------------------------------------------------------------------
# Replay
# --------------------------------------------------------------------------------------


@dataclass
class ReplaySession:
    """What :func:`replay` did; ``close()`` stops a served viewer.

    Attributes
    ----------
    recording : Recording
    viewer_url : str or None
        Web viewer URL while serving.
    grpc_url : str or None
    """

    recording: Recording
    viewer_url: str | None = None
    grpc_url: str | None = None
    _sink: Any = None

    @property
    def trajectory(self) -> Trajectory:
        return self.recording.to_trajectory()

    def close(self) -> None:
        if self._sink is not None:
            self._sink.close()
            self._sink = None

    def __enter__(self) -> ReplaySession:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def replay(
    path: str | os.PathLike,
    serve: bool = False,
    connect: str | None = None,
    rrd: str | os.PathLike | None = None,
    *,
    bind: str = DEFAULT_BIND,
    grpc_port: int | None = None,
    web_port: int | None = None,
    batch: int = 2000,
    quiet: bool = False,
) -> ReplaySession:
    """Re-log a qchain MCAP recording into Rerun with its original simulation times.

    Parameters
    ----------
    path : path
        The recording.
    serve, connect, rrd
        As for :class:`RunLogger`: host a viewer on ``bind`` (loopback by default), send
        to a running viewer, write a ``.rrd`` file. At least one must be given.
    batch : int
        Records a ``send_columns`` batch.

    Returns
    -------
    ReplaySession
        Keep it (and the process) alive while a served viewer is used; ``close()`` it
        after. A truncated recording warns (:class:`LoggingWarning`) where it stopped.

    Raises
    ------
    RecordingFormatError
        Not a qchain MCAP recording.
    ValueError
        No target given, or both ``serve`` and ``connect``.
    """
    if not (serve or connect or rrd):
        raise ValueError("replay needs a target: serve=True, connect=URL or rrd=PATH")
    if serve and connect:
        raise ValueError("serve and connect exclude each other")
    recording = read_recording(path)
    if recording.truncated:
        where = f"t = {recording.t[-1]:.6g} s (step {int(recording.step[-1])})" if len(recording) else "its start"
        warnings.warn(
            f"qchain.logging: {recording.path} is truncated; replaying up to its last complete chunk, "
            f"{where} ({recording.stop_reason})",
            LoggingWarning,
            stacklevel=2,
        )
    if rrd is not None:
        Path(rrd).parent.mkdir(parents=True, exist_ok=True)
    sink = _RerunSink(
        recording.info,
        serve=serve,
        connect=connect,
        rrd=rrd,
        bind=bind,
        grpc_port=grpc_port,
        web_port=web_port,
        recording_id=recording.metadata.get("recording_id") or str(uuid.uuid4()),
        warn=lambda m: warnings.warn(f"qchain.logging: {m}", LoggingWarning, stacklevel=3),
    )
    b = recording.batch()
    for a in range(0, len(recording), max(1, int(batch))):
        sink.write_batch(b.slice(a, a + batch))
    sink.finish()
    session = ReplaySession(recording, sink.viewer_url, sink.grpc_url, sink if sink.serving else None)
    if not sink.serving:
        sink.close()
    elif session.viewer_url and not quiet:
        print(f"qchain: replay served at {session.viewer_url}  (open it in a browser)", file=sys.stderr, flush=True)
    return session


def replay_main(argv: Sequence[str] | None = None) -> int:
    """``qchain replay LOG.mcap [--serve | --connect URL | --rrd OUT]``; returns the exit code.

    Without a target the replay is served on 127.0.0.1 (``--serve``) until Ctrl-C.
    Exit codes: 0 done, 2 not a (readable) qchain recording or bad arguments.
    """
    parser = argparse.ArgumentParser(
        prog="qchain replay",
        description="Re-log a qchain MCAP recording into Rerun with its original simulation times.",
    )
    parser.add_argument("log", type=Path, help="the .mcap recording")
    target = parser.add_mutually_exclusive_group()
    target.add_argument("--serve", action="store_true", help="serve a web viewer on 127.0.0.1 (the default)")
    target.add_argument("--connect", metavar="URL", help="send to a running Rerun viewer (rerun+http://HOST:PORT/proxy)")
    target.add_argument("--rrd", metavar="OUT", type=Path, help="write a Rerun .rrd file")
    parser.add_argument("--bind", default=DEFAULT_BIND,
                        help="address to serve on (default 127.0.0.1: this machine only)")
    args = parser.parse_args(argv)
    serve = args.serve or not (args.connect or args.rrd)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", LoggingWarning)
            session = replay(args.log, serve=serve, connect=args.connect, rrd=args.rrd, bind=args.bind, quiet=True)
    except (RecordingFormatError, FileNotFoundError, IsADirectoryError) as exc:
        print(f"qchain replay: error: {exc}", file=sys.stderr)
        return 2
    rec = session.recording
    if len(rec):
        print(f"replayed {len(rec)} steps of {rec.path}, t = {rec.t[0]:.6g} .. {rec.t[-1]:.6g} s")
    else:
        print(f"{rec.path} holds no complete step")
    if rec.truncated:
        where = f"t = {rec.t[-1]:.6g} s" if len(rec) else "its start"
        print(f"the recording is truncated: it stops at {where} (last complete chunk; {rec.stop_reason})")
    elif rec.outcome is not None:
        print(f"the run ended: {rec.outcome.get('message', '')}")
    if args.rrd:
        print(f"wrote {args.rrd}")
    if serve:
        if session.viewer_url:
            print(f"open {session.viewer_url}  - Ctrl-C to stop", flush=True)
        elif session.grpc_url:
            print(f"connect a Rerun viewer to {session.grpc_url}  - Ctrl-C to stop", flush=True)
        else:
            print("no viewer could be served", file=sys.stderr)
            return 1
        try:
            while True:
                time.sleep(1.0)
        except KeyboardInterrupt:
            pass
        finally:
            session.close()
    return 0


# --------------------------------------------------------------------------------------
# Command line support
# --------------------------------------------------------------------------------------


def default_mcap_path(scene_path: str | os.PathLike | None = None, runs_dir: str | os.PathLike = "runs",
                      now: _dt.datetime | None = None) -> Path:
    """``runs/<scene-stem>-<YYYYmmdd-HHMMSS>.mcap`` (local time), made unique with a suffix.

    Parameters
    ----------
    scene_path : path or None
        The scene file; its stem names the recording (``run`` without one).
    runs_dir : path
        Folder of the recordings, relative to the working directory by default.
    now : datetime or None
        The time stamp (default: now).
    """
    stem = Path(scene_path).stem if scene_path else "run"
    stamp = (now or _dt.datetime.now()).strftime("%Y%m%d-%H%M%S")
    base = Path(runs_dir) / f"{stem}-{stamp}"
    path = base.with_suffix(".mcap")
    k = 1
    while path.exists():
        path = Path(f"{base}-{k}.mcap")
        k += 1
    return path


_default_mcap_path = default_mcap_path  # reachable where a parameter has the same name


def add_logging_arguments(parser: argparse.ArgumentParser) -> argparse._ArgumentGroup:
    """Add ``--mcap OUT``, ``--serve``, ``--connect URL``, ``--rrd OUT``, ``--bind HOST``
    and ``--rerun-rate HZ`` to ``parser`` (as one argument group, which is returned)."""
    g = parser.add_argument_group(
        "recording and viewing",
        "Every run is recorded to an MCAP file (default runs/<scene>-<timestamp>.mcap); "
        "replay it with `qchain replay FILE`, or open it in Foxglove.",
    )
    g.add_argument("--mcap", metavar="OUT", type=Path, default=None,
                   help="MCAP recording path (default: runs/<scene-stem>-<YYYYmmdd-HHMMSS>.mcap)")
    g.add_argument("--serve", action="store_true",
                   help="serve a live Rerun web viewer on 127.0.0.1 and print its URL")
    g.add_argument("--connect", metavar="URL", default=None,
                   help="stream to a running Rerun viewer, e.g. rerun+http://127.0.0.1:9876/proxy")
    g.add_argument("--rrd", metavar="OUT", type=Path, default=None, help="also write a Rerun .rrd file")
    g.add_argument("--bind", default=DEFAULT_BIND,
                   help="address --serve listens on (default 127.0.0.1: this machine only)")
    g.add_argument("--rerun-rate", metavar="HZ", type=float, default=None,
                   help="send the viewer/.rrd at most HZ samples a simulated second (default: all; "
                        "the MCAP always gets all)")
    return g


def logger_from_args(
    args: argparse.Namespace, info: RunInfo, default_mcap_path: str | os.PathLike | None = None, **kwargs
) -> RunLogger:
    """Build the :class:`RunLogger` the flags of :func:`add_logging_arguments` ask for.

    Parameters
    ----------
    args : argparse.Namespace
    info : RunInfo
    default_mcap_path : path or None
        The recording path when ``--mcap`` is not given; ``None`` takes
        :func:`default_mcap_path` of ``info.scene_path``.
    **kwargs
        Passed on to :class:`RunLogger`. With ``--serve`` the logger lingers (keeps the
        viewer served after the run until Ctrl-C) unless ``linger=False`` is passed.

    Raises
    ------
    ValueError
        ``--serve`` together with ``--connect``.
    """
    serve = bool(getattr(args, "serve", False))
    connect = getattr(args, "connect", None)
    if serve and connect:
        raise ValueError("--serve and --connect exclude each other")
    path = getattr(args, "mcap", None)
    if path is None:
        path = default_mcap_path if default_mcap_path is not None else _default_mcap_path(info.scene_path)
    kwargs.setdefault("linger", serve)
    kwargs.setdefault("rerun_rate", getattr(args, "rerun_rate", None))
    return RunLogger(
        info,
        path,
        serve=serve,
        connect=connect,
        rrd=getattr(args, "rrd", None),
        bind=getattr(args, "bind", DEFAULT_BIND),
        **kwargs,
    )
