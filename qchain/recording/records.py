"""What a recording holds: step records, the run's static information, the row layout.

Imported by both sides: the simulating process packs records into rows of float64 numbers
(:class:`RecordLayout`); the writer, the reader and the sinks unpack them into
:class:`Batch` columns. Numpy only: the writer process imports nothing heavier.
"""

from __future__ import annotations

import json
import math
import os
import zlib
from collections.abc import Sequence
from contextlib import suppress
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from .. import __version__
from ..errors import LoggingError, LoggingWarning, RecordingFormatError
from .scenery import motion_law

__all__ = [
    "StepRecord",
    "RunInfo",
    "RecordLayout",
    "Batch",
    "LoggingError",
    "RecordingFormatError",
    "LoggingWarning",
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "TOPICS",
    "CONTACT_TOPICS",
    "CONTACT_WIDTH",
    "ContactSet",
    "pack_contacts",
    "SEGMENT_COLORS",
    "DEFAULT_FLUSH_INTERVAL",
    "DEFAULT_FLUSH_WALL_INTERVAL",
    "seal",
    "unseal",
    "ns",
]

FORMAT_NAME = "qchain-mcap"
#: 2: one JSON state channel, Foxglove messages in protobuf, checksummed metadata.
FORMAT_VERSION = 2

#: MCAP topic of each channel of a recording.
TOPICS = {
    "state": "/qchain/state",  # qchain.State, JSON: every field of a step record
    "tf": "/qchain/tf",  # foxglove.FrameTransforms: world -> base -> segment tips
    "arm": "/qchain/arm",  # foxglove.SceneUpdate: the backbone as line strips
    "points": "/qchain/backbone_points",  # foxglove.PointCloud: the backbone points
}

#: MCAP topics of a run with an environment (``RunInfo.obstacles`` or ``max_contacts``):
#: written only then, so a recording without contact is what it was before.
CONTACT_TOPICS = {
    "contacts": "/qchain/contacts",  # qchain.Contacts, JSON: each sample's active contacts
    "forces": "/qchain/contact_forces",  # foxglove.SceneUpdate: arrows (forces) at the contact points
    # foxglove.SceneUpdate: the obstacles (lifetime: the whole run), once; a record each if one moves
    "obstacles": "/qchain/obstacles",
}

#: Most contacts a sample can record (a row of 11 x this many numbers at most)
MAX_CONTACTS = 1 << 16

#: Numbers a contact takes in a row: point (3, m), normal (3), force (3, N), segment, obstacle.
CONTACT_WIDTH = 11

#: Seconds of simulation time a record may wait before it is on disk (the journal's
#: batches and the recording's chunks are cut at least this often).
DEFAULT_FLUSH_INTERVAL = 0.4
#: Seconds of wall time between forced MCAP chunk flushes in the writer.
DEFAULT_FLUSH_WALL_INTERVAL = 0.5

#: Segment colours (RGB) of the arm in Rerun and Foxglove, cycled along the chain.
SEGMENT_COLORS = ((255, 140, 0), (230, 95, 0), (255, 185, 50))



#: The latest time a recording holds (s): its messages carry Foxglove timestamps, whose
#: seconds are a 32-bit unsigned number (and their nanoseconds a 64-bit MCAP log time)
T_MAX = float(2**32 - 1)
T_MAX_WHY = "Foxglove timestamps count whole seconds in 32 bits"


def ns(t: float) -> int:
    """Simulation time ``t`` (s) as the MCAP's ``log_time`` (ns)."""
    return int(round(t * 1e9))


# --------------------------------------------------------------------------------------
# Checksummed metadata
# --------------------------------------------------------------------------------------


def _canonical(entries: dict[str, str]) -> bytes:
    return json.dumps(sorted(entries.items()), ensure_ascii=False, separators=(",", ":")).encode()


def seal(entries: dict[str, str]) -> dict[str, str]:
    """``entries`` with a ``crc32`` key over all of them: MCAP metadata records carry no
    CRC of their own, and a flipped bit must not change a scene silently."""
    if "crc32" in entries:
        raise ValueError("metadata entries must not have a 'crc32' key (it is the seal)")
    return {**entries, "crc32": "%08x" % zlib.crc32(_canonical(entries))}


def unseal(entries: dict[str, str]) -> dict[str, str] | None:
    """The entries without their seal, or None when the seal is missing or does not match."""
    got = entries.get("crc32")
    rest = {k: v for k, v in entries.items() if k != "crc32"}
    if got is None or got != "%08x" % zlib.crc32(_canonical(rest)):
        return None
    return rest


# --------------------------------------------------------------------------------------
# Records and run information
# --------------------------------------------------------------------------------------


class ContactSet(NamedTuple):
    """The active contacts of one sample as a recording holds them (``c`` of them).

    Attributes
    ----------
    point : (c, 3) float, m        the contact point on the arm's surface, world frame.
    normal : (c, 3) float          the obstacle's outward unit normal there, world frame.
    force : (c, 3) float, N        the force on the arm, world frame.
    segment : (c,) int             the segment touching (0-based).
    obstacle : (c,) int            index into ``RunInfo.obstacles``; ``-1 - k`` for self-contact
                                   with segment ``k`` (as :class:`qchain.contact.Contacts`).
    """

    point: np.ndarray
    normal: np.ndarray
    force: np.ndarray
    segment: np.ndarray
    obstacle: np.ndarray

    @classmethod
    def from_block(cls, block: np.ndarray) -> ContactSet:
        """From a row's contact block (C, CONTACT_WIDTH): the rows whose segment is not NaN
        (the padding)."""
        used = block[np.isfinite(block[:, 9])]
        return cls(used[:, 0:3].copy(), used[:, 3:6].copy(), used[:, 6:9].copy(), used[:, 9].astype(np.int64),
                   used[:, 10].astype(np.int64))


def pack_contacts(contacts, capacity: int, info: RunInfo | None = None) -> tuple[np.ndarray, int]:
    """``contacts`` (anything with ``.point`` (c, 3), ``.normal`` (c, 3), ``.force`` (c, 3),
    ``.segment`` (c,), ``.obstacle`` (c,), e.g. :class:`qchain.contact.Contacts`, or None: no
    contact) as a row's block (capacity, CONTACT_WIDTH), NaN-padded, and how many contacts
    did not fit: the block keeps the ``capacity`` largest forces (a recording's rows all
    have one width). With the run's ``info``, a segment or obstacle it does not have is a
    ``ValueError`` (a reader would refuse the recording)."""
    block = np.full((capacity, CONTACT_WIDTH), np.nan)
    if contacts is None:
        return block, 0
    try:
        point = np.asarray(contacts.point, dtype=np.float64).reshape(-1, 3)
        c = point.shape[0]
        cols = (point, np.asarray(contacts.normal, dtype=np.float64).reshape(c, 3),
                np.asarray(contacts.force, dtype=np.float64).reshape(c, 3),
                np.asarray(contacts.segment, dtype=np.float64).reshape(c, 1),
                np.asarray(contacts.obstacle, dtype=np.float64).reshape(c, 1))
    except AttributeError as exc:
        raise TypeError(f"contacts must have .point, .normal, .force, .segment and .obstacle (a "
                        f"qchain.contact.Contacts), got {type(contacts).__name__} ({exc})") from None
    except ValueError as exc:
        raise ValueError(f"contacts: point, normal, force must be (c, 3) and segment, obstacle (c,) for the "
                         f"same c ({exc})") from None
    full = np.concatenate(cols, axis=1)
    seg, obs = full[:, 9], full[:, 10]
    n = np.inf if info is None else info.n_segments
    m = np.inf if info is None else len(info.obstacles or ())
    if not (np.isfinite(seg).all() and (seg == np.floor(seg)).all() and (seg >= 0).all() and (seg < n).all()):
        raise ValueError(f"contacts.segment must be segment indices 0 .. {n - 1}, got {seg.tolist()}")
    if not (np.isfinite(obs).all() and (obs == np.floor(obs)).all() and (obs >= -n).all() and (obs < m).all()):
        raise ValueError(f"contacts.obstacle must be indices into RunInfo.obstacles ({m} of them) or -1 - k for "
                         f"self-contact with segment k, got {obs.tolist()}")
    dropped = max(0, c - capacity)
    if dropped:
        keep = np.sort(np.argsort(-np.linalg.norm(full[:, 6:9], axis=1), kind="stable")[:capacity])
        full = full[keep]
    block[: full.shape[0]] = full
    return block, dropped



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
    base_frame : (7,) array or None
        World placement of the base frame (the root of segment 1) in the same form;
        ``None``: at the first backbone point, aligned with the world.
    contacts : Contacts-like or None
        The active contacts at this sample (``.point``, ``.normal``, ``.force`` (c, 3) world
        frame, m and N; ``.segment``, ``.obstacle`` (c,)), e.g. ``chain.contacts(q, v, env,
        t)``; recorded when the run's ``RunInfo.max_contacts`` > 0 (at most that many a
        sample, the largest forces), None: none.
    tension : (nt,) array or None, N
        The tendons' tensions (a chain with tendons, docs/tendons.md), None: no tendons.
    tendons : (nt, M, 3) array or None, m
        World points along each tendon from the base to its end (``Chain.tendon_paths``), a
        path of fewer than ``M`` points padded with NaN rows; None: no tendons. Recorded when
        ``tension`` is.

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
    base_frame: np.ndarray | None = None
    contacts: Any = None
    tension: np.ndarray | None = None
    tendons: np.ndarray | None = None


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


def _utf8(name: str, text: str) -> str:
    """``text``, or ``ValueError`` naming ``name`` if it is not UTF-8 text (lone surrogates)."""
    try:
        text.encode("utf-8")
    except UnicodeEncodeError as exc:
        raise ValueError(f"{name} is not UTF-8 text ({exc.reason}: {text[exc.start:exc.end]!a} at character "
                         f"{exc.start}); a recording stores it as UTF-8") from None
    return text


def _escaped(path: str) -> str:
    """A path as UTF-8 text: bytes of its name that are not UTF-8 escaped as ``\\xNN``."""
    with suppress(UnicodeEncodeError):
        path.encode("utf-8")
        return path
    try:
        return os.fsencode(path).decode("utf-8", "backslashreplace")
    except UnicodeError:  # surrogates os.fsdecode does not make
        return path.encode("utf-8", "backslashreplace").decode("utf-8")


@dataclass(kw_only=True)
class RunInfo:
    """Static information about a run, recorded once (checksummed).

    Attributes
    ----------
    n_segments : int
        Number of segments ``n`` of the arm.
    radii : (n,) sequence of float, m
        Segment radii, used to draw the backbone as tubes.
    scene : str
        The scene text (e.g. the TOML file's content); may be empty.
    scene_path : str or None
        Where the scene came from, for the record, for default file names and so that the
        recording never overwrites it. A name that is not UTF-8 text (``bytes``, or a
        ``str`` with the lone surrogates ``os.fsdecode`` makes of such bytes) is recorded
        with those bytes escaped (``\\xff``); :attr:`scene_file` keeps the path itself.
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
    q_names, v_names : sequence of str or None
        Names of the coordinates and velocities with their units, e.g.
        ``"segment 2 ux [1/m]"`` (plots and layouts); ``None``: ``q[0]``, ``v[0]``, ...
    duration : float or None, s
        The simulated time the run is meant to reach (the live plots' time axis).
    obstacles : list of dict or None
        The environment's obstacles at ``t = 0``, world frame, as plain JSON-like data
        (:meth:`qchain.contact.Environment.describe`): each a dict with ``"type"`` (one of
        ``"halfspace"``, ``"sphere"``, ``"capsule"``, ``"cylinder"``, ``"box"``), its
        parameters in m (halfspace ``point``, ``normal``; sphere ``center``, ``radius``;
        capsule and cylinder ``a``, ``b``, ``radius``; box ``center``, ``half_extents``,
        ``rotation`` (3 x 3)) and ``"motion"`` (None for a fixed obstacle, else ``velocity``
        (3,) m/s, ``amplitude`` (3,) m, ``frequency`` Hz, ``phase`` rad, all finite: the
        viewers move it by ``u(t) = velocity t + amplitude sin(2 pi frequency t + phase)``);
        the viewers draw them. ``None``: the run has no environment (a recording from before
        contact reads back so).
    force_ref : float, N
        Contact force drawn as an arrow a quarter of the arm's reach long (e.g. the arm's
        weight).
    max_contacts : int
        Contacts a sample can record (the rows' contact capacity; the largest forces are
        kept when a sample has more); 0 records none. ``chain.n * env.nodes *
        len(env.obstacles)`` holds every contact with the obstacles.

    ``scene``, ``name``, ``qchain_version``, ``q_names`` and ``v_names`` must be UTF-8
    text (a recording stores them as such): a ``ValueError`` names the field otherwise,
    before anything is written.
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
    q_names: Sequence[str] | None = None
    v_names: Sequence[str] | None = None
    duration: float | None = None
    obstacles: list | None = None
    max_contacts: int = 0
    force_ref: float = 1.0

    def __post_init__(self) -> None:
        if isinstance(self.n_segments, bool) or not isinstance(self.n_segments, (int, np.integer)):
            raise ValueError(f"n_segments must be an int >= 1, got {self.n_segments!r}")
        if self.n_segments < 1:
            raise ValueError(f"n_segments must be >= 1, got {self.n_segments}")
        self.n_segments = int(self.n_segments)
        self.radii = self._vector("radii", self.radii, self.n_segments)
        if self.chamber_radii is not None:
            self.chamber_radii = self._vector("chamber_radii", self.chamber_radii, self.n_segments)
        angles = np.asarray(self.chamber_angles, dtype=float)
        if angles.shape != (3,) or not np.all(np.isfinite(angles)):
            raise ValueError(f"chamber_angles must be 3 finite angles (rad), got {self.chamber_angles!r}")
        self.chamber_angles = [float(a) for a in angles]
        if not (math.isfinite(float(self.pressure_ref)) and float(self.pressure_ref) > 0.0):
            raise ValueError(f"pressure_ref must be > 0 Pa, got {self.pressure_ref!r}")
        self.pressure_ref = float(self.pressure_ref)
        if not isinstance(self.scene, str):
            raise ValueError(f"scene must be a str (the scene text), got {type(self.scene).__name__}")
        _utf8("scene", self.scene)
        self._scene_file = None
        if self.scene_path is not None:
            path = os.fsdecode(self.scene_path)  # undecodable bytes become lone surrogates
            self._scene_file = path
            self.scene_path = _escaped(path)
        if not isinstance(self.params, dict):
            raise ValueError(f"params must be a dict, got {type(self.params).__name__}")
        self.params = _jsonable(self.params, "params")
        self.qchain_version = _utf8("qchain_version", str(self.qchain_version))
        self.name = _utf8("name", str(self.name))
        for key in ("q_names", "v_names"):
            names = getattr(self, key)
            if names is not None:
                if isinstance(names, str) or not all(isinstance(s, str) for s in names):
                    raise ValueError(f"{key} must be a sequence of str, got {names!r}")
                for i, name in enumerate(names):
                    _utf8(f"{key}[{i}]", name)
                setattr(self, key, list(names))
        if self.duration is not None:
            d = float(self.duration)
            if not (math.isfinite(d) and 0 < d <= T_MAX):
                raise ValueError(f"duration must be None or a time > 0 s and <= {T_MAX:.10g} s (a recording's "
                                 f"times: {T_MAX_WHY}), got {self.duration!r}")
            self.duration = d
        if self.obstacles is not None:
            if isinstance(self.obstacles, (str, dict)) or not isinstance(self.obstacles, Sequence):
                raise ValueError(f"obstacles must be None or a list of dicts, got {type(self.obstacles).__name__}")
            obstacles = _jsonable(list(self.obstacles), "obstacles")
            for i, ob in enumerate(obstacles):
                if not isinstance(ob, dict) or not isinstance(ob.get("type"), str):
                    raise ValueError(f"obstacles[{i}] must be a dict with a 'type' string, got {ob!r}")
                _utf8(f"obstacles[{i}]['type']", ob["type"])
                motion_law(ob.get("motion"), f"obstacles[{i}]['motion']")  # the viewers move it by this law
            self.obstacles = obstacles
        mc = self.max_contacts
        if isinstance(mc, bool) or not isinstance(mc, (int, np.integer)) or not 0 <= mc <= MAX_CONTACTS:
            raise ValueError(f"max_contacts must be a whole number from 0 to {MAX_CONTACTS}, got {mc!r}")
        self.max_contacts = int(mc)
        if not (math.isfinite(float(self.force_ref)) and float(self.force_ref) > 0.0):
            raise ValueError(f"force_ref must be > 0 N, got {self.force_ref!r}")
        self.force_ref = float(self.force_ref)

    @property
    def records_contacts(self) -> bool:
        """Whether the run's recording has the contact channels (:data:`CONTACT_TOPICS`): an
        environment was declared (``obstacles`` or ``max_contacts``)."""
        return self.obstacles is not None or self.max_contacts > 0

    @property
    def scene_file(self) -> str | None:
        """The scene's path as given (for the file system), ``scene_path`` as recorded."""
        return self._scene_file if getattr(self, "_scene_file", None) is not None else self.scene_path

    @staticmethod
    def _vector(name: str, value, n: int) -> list[float]:
        arr = np.asarray(value, dtype=float)
        if arr.shape != (n,):
            raise ValueError(f"{name} must have shape ({n},) (one a segment), got shape {arr.shape}")
        if not np.all(np.isfinite(arr)) or np.any(arr <= 0.0):
            raise ValueError(f"{name} must be finite and > 0 m, got {arr.tolist()}")
        return [float(r) for r in arr]

    def names(self, kind: str, count: int) -> list[str]:
        """Series names of ``q``, ``v`` (with units when known), ``p`` or ``energy``."""
        if kind in ("q", "v"):
            given = self.q_names if kind == "q" else self.v_names
            if given is not None and len(given) == count:
                return list(given)
            return [f"{kind}[{i}]" for i in range(count)]
        if kind == "p":
            out = [f"segment {i // 3 + 1} chamber {i % 3 + 1} [Pa]" for i in range(3 * self.n_segments)]
            return (out + [f"p[{i}]" for i in range(len(out), count)])[:count]
        if kind == "energy":
            return ["kinetic [J]", "potential [J]", "total [J]"]
        raise ValueError(f"kind must be 'q', 'v', 'p' or 'energy', got {kind!r}")

    def to_json(self) -> dict:
        """The information as a JSON-ready dict (inverse of :meth:`from_json`): every field,
        its sequences as lists of their own."""
        out = {f: getattr(self, f) for f in self.__dataclass_fields__}
        return {k: list(v) if isinstance(v, (list, tuple)) else v for k, v in out.items()}

    @classmethod
    def from_json(cls, data: dict) -> RunInfo:
        """Rebuild from :meth:`to_json` output; unknown keys are ignored."""
        known = {k: data[k] for k in cls.__dataclass_fields__ if k in data}
        return cls(**known)


# --------------------------------------------------------------------------------------
# Row layout: how a record is packed into one float64 row
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RecordLayout:
    """A step record as one row of float64 numbers, the form records travel in.

    The row holds, in this order, ``t`` (s), ``step`` (an integer value), ``q`` (nq),
    ``v`` (nv), ``p`` (n_p, Pa), ``kinetic``, ``potential``, ``total`` (J), the base frame
    (7: x, y, z, qx, qy, qz, qw), the backbone (n x P x 3, m, row-major), the tip frames
    (n x 7), when ``C`` > 0 the contacts (C x CONTACT_WIDTH: point, normal, force,
    segment, obstacle; unused rows NaN) and, when ``nt`` > 0, the tensions (nt, N) and the
    tendons' paths (nt x M x 3, m, NaN-padded): the fields of :class:`StepRecord` flattened.
    :attr:`slices` says where each field is.

    Attributes
    ----------
    nq, nv, n_p : int
        Lengths of q, v and p.
    n : int
        Segments.
    P : int
        Backbone points a segment.
    C : int
        Contacts a row holds (``RunInfo.max_contacts``); 0: none (the layout of a run
        without contact, as before).
    nt, M : int
        Tendons, and points of each tendon's path (0 with tendons: tensions without paths);
        ``nt = 0``: no tendons (the layout of a run without tendons, as before).
    """

    nq: int
    nv: int
    n_p: int
    n: int
    P: int
    C: int = 0
    nt: int = 0
    M: int = 0

    @property
    def row_width(self) -> int:
        """Numbers in a row."""
        return (2 + self.nq + self.nv + self.n_p + 3 + 7 + self.n * self.P * 3 + self.n * 7 + self.C * CONTACT_WIDTH
                + self.nt + self.nt * self.M * 3)

    @property
    def slices(self) -> dict[str, slice]:
        """Field name -> its columns in a row (``t``, ``step``, ``q``, ``v``, ``p``,
        ``energy`` (kinetic, potential, total), ``base``, ``backbone``, ``tip_frames``,
        ``contacts``, ``tension``, ``tendons``)."""
        sizes = (("t", 1), ("step", 1), ("q", self.nq), ("v", self.nv), ("p", self.n_p), ("energy", 3),
                 ("base", 7), ("backbone", self.n * self.P * 3), ("tip_frames", self.n * 7),
                 ("contacts", self.C * CONTACT_WIDTH), ("tension", self.nt), ("tendons", self.nt * self.M * 3))
        out, a = {}, 0
        for name, size in sizes:
            out[name] = slice(a, a + size)
            a += size
        return out

    def to_json(self) -> dict:
        out = {"nq": self.nq, "nv": self.nv, "np": self.n_p, "n": self.n, "P": self.P}
        if self.C:  # (a layout without contacts is written as before)
            out["C"] = self.C
        if self.nt:  # (and one without tendons)
            out["nt"], out["M"] = self.nt, self.M
        return out

    @classmethod
    def from_json(cls, d: dict) -> RecordLayout:
        """From :meth:`to_json` output; ``ValueError`` for anything but whole numbers
        (``n`` and ``P`` >= 1, the others >= 0, a row of at most 2**24 numbers); ``C``
        may be missing (0: a layout from before contact), and so may ``nt`` and ``M`` (0: no
        tendons)."""
        if not isinstance(d, dict):
            raise ValueError(f"a record layout must be a JSON object, got {type(d).__name__}")
        vals = {}
        for key in ("nq", "nv", "np", "n", "P", "C", "nt", "M"):
            v = d.get(key, 0 if key in ("C", "nt", "M") else None)
            if isinstance(v, bool) or not isinstance(v, int) or not (0 <= v <= 1 << 24):
                raise ValueError(f"record layout: {key} must be a whole number >= 0, got {v!r}")
            vals[key] = v
        if vals["n"] < 1 or vals["P"] < 1:
            raise ValueError(f"record layout: n and P must be >= 1, got n = {vals['n']}, P = {vals['P']}")
        if vals["M"] and not vals["nt"]:
            raise ValueError(f"record layout: M = {vals['M']} tendon points without tendons (nt = 0)")
        lay = cls(vals["nq"], vals["nv"], vals["np"], vals["n"], vals["P"], vals["C"], vals["nt"], vals["M"])
        if lay.row_width > 1 << 24:
            raise ValueError(f"record layout: a row of {lay.row_width} numbers (more than 2**24)")
        return lay


@dataclass
class Batch:
    """K records, stacked: t (K,), step (K,), q (K, nq), v (K, nv), p (K, 3n),
    energy (K, 3) = (kinetic, potential, total), base (K, 7), backbone (K, n, P, 3),
    tip_frames (K, n, 7), contacts (K, C, CONTACT_WIDTH) or None (a run without contact
    records): each row a contact (point, normal, force, segment, obstacle), NaN rows unused
    (:meth:`contact_set` gives one record's as a :class:`ContactSet`); tension (K, nt) N and
    tendons (K, nt, M, 3) m (each tendon's world path, NaN-padded) or None (a run without
    tendons; a recording read from its MCAP file has ``tension`` but not the paths)."""

    t: np.ndarray
    step: np.ndarray
    q: np.ndarray
    v: np.ndarray
    p: np.ndarray
    energy: np.ndarray
    base: np.ndarray
    backbone: np.ndarray
    tip_frames: np.ndarray
    contacts: np.ndarray | None = field(default=None, kw_only=True)
    tension: np.ndarray | None = field(default=None, kw_only=True)
    tendons: np.ndarray | None = field(default=None, kw_only=True)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def contact_set(self, k: int) -> ContactSet:
        """The active contacts of record ``k`` (none when the run recorded no contacts)."""
        if self.contacts is None:
            return ContactSet.from_block(np.zeros((0, CONTACT_WIDTH)))
        return ContactSet.from_block(self.contacts[k])

    @classmethod
    def from_rows(cls, rows: np.ndarray, lay: RecordLayout) -> Batch:
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
            base=col("base"),
            backbone=col("backbone").reshape(K, lay.n, lay.P, 3),
            tip_frames=col("tip_frames").reshape(K, lay.n, 7),
            contacts=col("contacts").reshape(K, lay.C, CONTACT_WIDTH) if lay.C else None,
            tension=col("tension") if lay.nt else None,
            tendons=col("tendons").reshape(K, lay.nt, lay.M, 3) if lay.nt else None,
        )

    def rows(self) -> np.ndarray:
        """The batch as rows of its layout (the inverse of :meth:`from_rows`)."""
        K = len(self)
        extra = () if self.contacts is None else (self.contacts.reshape(K, -1),)
        if self.tension is not None:
            paths = self.tendons if self.tendons is not None else np.zeros((K, self.tension.shape[1], 0, 3))
            extra += (self.tension, paths.reshape(K, -1))
        return np.concatenate(
            (self.t[:, None], self.step[:, None].astype(np.float64), self.q, self.v, self.p, self.energy,
             self.base, self.backbone.reshape(K, -1), self.tip_frames.reshape(K, -1)) + extra, axis=1)

    @property
    def layout(self) -> RecordLayout:
        nt = 0 if self.tension is None else self.tension.shape[1]
        M = 0 if not nt or self.tendons is None else self.tendons.shape[2]
        return RecordLayout(self.q.shape[1], self.v.shape[1], self.p.shape[1], self.backbone.shape[1],
                            self.backbone.shape[2], 0 if self.contacts is None else self.contacts.shape[1], nt, M)

    @classmethod
    def concatenate(cls, batches: Sequence[Batch]) -> Batch:
        """The batches one after another; contacts are kept when every batch has them (of
        one capacity)."""
        out = Batch(*(np.concatenate([getattr(x, f) for x in batches]) for f in _BATCH_COLUMNS))
        if all(x.contacts is not None for x in batches):
            out.contacts = np.concatenate([x.contacts for x in batches])
        if all(x.tension is not None for x in batches):  # (and the paths, when every batch has them)
            out.tension = np.concatenate([x.tension for x in batches])
            if all(x.tendons is not None for x in batches):
                out.tendons = np.concatenate([x.tendons for x in batches])
        return out

    def take(self, index) -> Batch:
        """The records at ``index`` (a slice, or integer positions)."""
        out = Batch(*(getattr(self, f)[index] for f in _BATCH_COLUMNS))
        if self.contacts is not None:
            out.contacts = self.contacts[index]
        if self.tension is not None:
            out.tension = self.tension[index]
        if self.tendons is not None:
            out.tendons = self.tendons[index]
        return out


#: The columns every batch has (``contacts`` is optional)
_BATCH_COLUMNS = ("t", "step", "q", "v", "p", "energy", "base", "backbone", "tip_frames")


def default_base(backbone: np.ndarray) -> np.ndarray:
    """The base frame a record without one gets: at the first backbone point, aligned with
    the world."""
    out = np.zeros(7)
    out[:3] = backbone[0, 0] if backbone.size else 0.0
    out[6] = 1.0
    return out
