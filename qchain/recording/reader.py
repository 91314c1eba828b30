"""Reading a recording back: every intact chunk, what is missing said, a killed run's journal.

:func:`read_recording` scans the file with :func:`qchain.recording.scan.scan`: a damaged
chunk loses only its own steps, the reader goes on with the chunks after it, and
:attr:`Recording.gaps` says which time range is missing. The ``qchain`` metadata must
match its CRC32 seal (its second copy is used when the first is damaged); a damaged
metadata record is reported, never used. If the run that wrote the file was killed, its
journal (``run.mcap.journal``) still holds the records the file lacks: they are read too
(:attr:`Recording.recovered`). Reading parses JSON only: nothing in a file is executed.
"""

from __future__ import annotations

import json
import mmap
import os
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np
from mcap.records import Channel, Message

from ..trajectory import Trajectory
from .journal import JournalReader, journal_owner, journal_path
from .records import (
    FORMAT_NAME,
    FORMAT_VERSION,
    TOPICS,
    Batch,
    RecordingFormatError,
    RunInfo,
    unseal,
)
from .scan import MAGIC, scan, summary_chunks

__all__ = ["Recording", "Gap", "read_recording", "read_mcap"]


@dataclass
class Gap:
    """Records lost to damage between two intact parts of a recording.

    Attributes
    ----------
    after_t, before_t : float or None, s
        The last time read before the damage and the first after it (None: the damage is
        at the start or the end): the records strictly between are missing.
    after_step, before_step : int or None
        The same as steps.
    offset, end : int
        The damaged bytes.
    reason : str
    """

    after_t: float | None
    before_t: float | None
    after_step: int | None
    before_step: int | None
    offset: int
    end: int
    reason: str

    def describe(self) -> str:
        a = "the start" if self.after_t is None else f"t = {self.after_t:.6g} s (step {self.after_step})"
        b = "the end" if self.before_t is None else f"t = {self.before_t:.6g} s (step {self.before_step})"
        return f"records between {a} and {b} are missing (bytes {self.offset}..{self.end}: {self.reason})"


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
    base : (N, 7)
        World placement of the base (x, y, z, qx, qy, qz, qw).
    backbone : (N, n, P, 3) m
    tip_frames : (N, n, 7)
    outcome : dict or None
        The ``qchain.outcome`` metadata (None when the run never closed its log).
    truncated : bool
        The file ends before its summary (a killed run).
    stop_reason : str
        Why the file ends early ("" when it is complete).
    metadata : dict
        The ``qchain`` metadata record (its seal checked).
    gaps : list of Gap
        Damaged parts and the records lost with them.
    damage : list of str
        Everything found damaged (gaps, metadata that failed its checksum).
    recovered : int
        Records read from the run's journal (a killed run), after those of the file.
    """

    path: str
    info: RunInfo
    t: np.ndarray
    step: np.ndarray
    q: np.ndarray
    v: np.ndarray
    p: np.ndarray
    energy: np.ndarray
    base: np.ndarray
    backbone: np.ndarray
    tip_frames: np.ndarray
    outcome: dict | None
    truncated: bool
    stop_reason: str
    metadata: dict
    gaps: list = field(default_factory=list)
    damage: list = field(default_factory=list)
    recovered: int = 0

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def batch(self) -> Batch:
        return Batch(self.t, self.step, self.q, self.v, self.p, self.energy, self.base, self.backbone,
                     self.tip_frames)

    @property
    def complete(self) -> bool:
        """Nothing missing: not truncated, no gap."""
        return not self.truncated and not self.gaps

    def to_trajectory(self) -> Trajectory:
        """The recording as a :class:`~qchain.trajectory.Trajectory`; ``meta`` keeps the
        rest (``step``, ``backbone``, ``tip_frames``, ``base``, ``total_energy``, ``info``,
        ``path``, ``truncated``, ``stopped_at``, ``gaps``, ``outcome``)."""
        out = self.outcome
        if self.truncated and out is None:
            end = "no samples" if len(self) == 0 else f"t = {self.t[-1]:.6g} s"
            success, status = False, -1
            message = f"recording truncated after its last complete chunk ({end}): {self.stop_reason}"
        elif out is None:
            success, status, message = False, -1, "the run did not record how it ended"
        else:
            success = out.get("success") == "true"
            status = int(out.get("status", 0 if success else -1))
            message = out.get("message", "")
        if self.gaps:
            success = False
            message = (message + "; " if message else "") + "; ".join(g.describe() for g in self.gaps)
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
                "base": self.base,
                "total_energy": self.energy[:, 2],
                "info": self.info,
                "truncated": self.truncated,
                "stopped_at": float(self.t[-1]) if (self.truncated and len(self)) else None,
                "gaps": self.gaps,
                "recovered": self.recovered,
                "outcome": out,
                "qchain_version": self.info.qchain_version,
                "scene": self.info.scene,
                "params": self.info.params,
            },
        )


def _open(source) -> tuple[str, object, callable]:
    """(name, bytes-like of the whole file, closer)."""
    if isinstance(source, (str, os.PathLike)):
        name = os.fspath(source)
        if not os.path.exists(name) and journal_path(name).exists():
            return name, b"", lambda: None  # the writer never started: the journal holds it all
        fh = open(name, "rb")
        size = os.fstat(fh.fileno()).st_size
        if size == 0:
            fh.close()
            return name, b"", lambda: None
        mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        return name, mm, lambda: (mm.close(), fh.close())
    name = getattr(source, "name", None) or f"<{type(source).__name__}>"
    if not isinstance(name, str):
        name = f"<{type(source).__name__}>"
    return name, source.read(), lambda: None


def _rows_of(states: list[dict], info: RunInfo) -> Batch:
    """Columns of decoded ``/qchain/state`` messages."""
    N = len(states)
    n = info.n_segments
    f = lambda key: np.array([s[key] for s in states], dtype=float)  # noqa: E731  (null -> NaN)
    if N == 0:
        return Batch(np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 0)), np.zeros((0, 0)), np.zeros((0, 3 * n)),
                     np.zeros((0, 3)), np.zeros((0, 7)), np.zeros((0, n, 0, 3)), np.zeros((0, n, 7)))
    energy = np.array([[s["kinetic"], s["potential"], s["total"]] for s in states], dtype=float)
    return Batch(
        t=f("t"), step=np.array([s["step"] for s in states], dtype=np.int64),
        q=f("q").reshape(N, -1), v=f("v").reshape(N, -1), p=f("p").reshape(N, -1), energy=energy,
        base=f("base").reshape(N, 7), backbone=f("backbone").reshape(N, n, -1, 3), tip_frames=f("tips").reshape(N, n, 7),
    )


def read_recording(source: str | os.PathLike | BinaryIO, journal: bool = True) -> Recording:
    """Read a qchain MCAP recording: complete, truncated or damaged.

    Parameters
    ----------
    source : path or binary stream
    journal : bool
        For a path: also read the records a killed run left in its journal
        (``PATH.journal``) and the file lacks.

    Raises
    ------
    RecordingFormatError
        The file is not an MCAP file, not a qchain recording, or its qchain metadata is
        damaged in both copies; the message names the file.
    FileNotFoundError
    """
    import orjson

    name, buf, close = _open(source)
    jpath = journal_path(name) if journal and isinstance(source, (str, os.PathLike)) else None
    has_journal = jpath is not None and jpath.exists()
    try:
        if len(buf) == 0 and not has_journal:
            raise RecordingFormatError(f"{name}: the file is empty, not a qchain MCAP recording")
        head = bytes(buf[: len(MAGIC)])
        if len(buf) and head != MAGIC[: len(head)]:
            raise RecordingFormatError(f"{name}: not an MCAP file (it starts with {head!r}, an MCAP file with "
                                       f"{MAGIC!r})")
        damage: list[str] = []
        meta = None
        outcome = None
        complete = False
        stop_reason = ""
        state_channels: set[int] = set()
        other_channels: set[int] = set()
        # in file order: ("m", channel id, message data) and ("d", damage item); messages are
        # kept until the end when their channel's record was lost (a damaged first chunk):
        # the sealed metadata names the channel ids too
        stream: list[tuple] = []
        for item in scan(buf) if len(buf) >= len(MAGIC) else ():
            if item.kind == "chunk":
                for rec in item.records:
                    if isinstance(rec, Channel):
                        (state_channels if rec.topic == TOPICS["state"] else other_channels).add(rec.id)
                    elif isinstance(rec, Message) and rec.channel_id not in other_channels:
                        stream.append(("m", rec.channel_id, rec.data))
            elif item.kind == "metadata":
                entries = unseal(item.record.metadata)
                if item.record.name == "qchain":
                    if entries is None:
                        damage.append(f"the qchain metadata record at byte {item.offset} fails its checksum: "
                                      "not used")
                    elif meta is None:
                        meta = entries
                elif item.record.name == "qchain.outcome":
                    if entries is None:
                        damage.append(f"the qchain.outcome metadata record at byte {item.offset} fails its "
                                      "checksum: not used")
                    else:
                        outcome = entries
            elif item.kind == "footer":
                complete = True
            elif item.kind == "damage":
                stream.append(("d", item))
                damage.append(item.reason)
            elif item.kind == "end":
                stop_reason = item.reason
        if meta is not None and "channels" in meta:
            state_channels |= {int(k) for k, v in json.loads(meta["channels"]).items() if v == TOPICS["state"]}
        states: list[dict] = []
        events: list[tuple[int, object]] = []  # (position in states, damage item)
        for entry in stream:
            if entry[0] == "m":
                if entry[1] in state_channels:
                    states.append(orjson.loads(entry[2]))
            else:
                events.append((len(states), entry[1]))
        del stream
        index = summary_chunks(buf) if events else None
        if len(buf) < len(MAGIC):
            stop_reason = "the file ends before its first record"
        elif not complete and not stop_reason:
            stop_reason = "the file ends before its footer"
    finally:
        del buf
        close()
    recovered = 0
    if has_journal:
        owner = journal_owner(jpath)
        if owner is None:  # a killed run's journal (a live run's is still being written)
            jr = JournalReader(jpath)
            try:
                blocks = jr.poll(final=True)
            finally:
                jr.close()
            if meta is None and jr.metadata is not None:
                meta = jr.metadata
            if jr.layout is not None and blocks:
                last = states[-1]["step"] if states else None
                last_t = states[-1]["t"] if states else None
                rows = np.concatenate(blocks)
                keep = rows if last is None else rows[(rows[:, 1] > last) & (rows[:, 0] >= last_t)]
                recovered = len(keep)
                journal_rows = keep
            else:
                journal_rows = None
            if outcome is None and jr.outcome is not None:
                outcome = jr.outcome
            damage.extend(f"journal: {d}" for d in jr.damage)
        else:
            journal_rows = None
    else:
        journal_rows = None
    if meta is None or meta.get("format") != FORMAT_NAME:
        if any("qchain metadata" in d for d in damage):
            raise RecordingFormatError(f"{name}: its qchain metadata record is damaged (checksum mismatch) and "
                                       "no intact copy was found")
        if stop_reason or damage:
            raise RecordingFormatError(
                f"{name}: an MCAP file without a qchain header record (cut before it, or written by another "
                f"program; reading stopped: {stop_reason or damage[0]})")
        raise RecordingFormatError(
            f"{name}: an MCAP file, but not a qchain recording (no 'qchain' metadata record with format "
            f"{FORMAT_NAME!r})")
    try:
        version = int(meta.get("format_version", "0"))
    except ValueError:
        version = -1
    if version != FORMAT_VERSION:
        raise RecordingFormatError(f"{name}: qchain recording format version {meta.get('format_version')!r}; this "
                                   f"qchain reads version {FORMAT_VERSION}")
    try:
        info = RunInfo.from_json(json.loads(meta["info"]))
    except (KeyError, ValueError, TypeError) as exc:
        raise RecordingFormatError(f"{name}: its qchain metadata record does not have the expected form ({exc})") \
            from None
    try:
        b = _rows_of(states, info)
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise RecordingFormatError(f"{name}: a qchain state message does not have the expected form ({exc!r})") \
            from None
    gaps = []
    for pos, item in events:
        if index is not None and not any(item.offset <= c.chunk_start_offset < item.end for c in index):
            damage[damage.index(item.reason)] = item.reason + " (no chunk there, per the summary: no record lost)"
            continue  # an index record, say: the summary shows no chunk was in the damaged bytes
        before = b.t[pos] if pos < len(b) else None
        after = b.t[pos - 1] if pos > 0 else None
        gaps.append(Gap(None if after is None else float(after), None if before is None else float(before),
                        None if pos == 0 else int(b.step[pos - 1]), None if pos >= len(b) else int(b.step[pos]),
                        item.offset, item.end, item.reason))
    if journal_rows is not None and len(journal_rows):
        jb = Batch.from_rows(journal_rows, jr.layout)
        if len(b) == 0:
            b = jb
        else:
            b = Batch.concatenate([b, jb])
        if not complete:
            stop_reason = (stop_reason + "; " if stop_reason else "") + \
                f"{recovered} records after it read from the run's journal {jpath}"
    return Recording(
        path=name, info=info, t=b.t, step=b.step, q=b.q, v=b.v, p=b.p, energy=b.energy, base=b.base,
        backbone=b.backbone, tip_frames=b.tip_frames, outcome=outcome, truncated=not complete,
        stop_reason="" if complete else stop_reason, metadata=meta, gaps=gaps, damage=damage, recovered=recovered,
    )


def read_mcap(path: str | os.PathLike | BinaryIO) -> Trajectory:
    """Read a qchain MCAP recording as a :class:`~qchain.trajectory.Trajectory`.

    A truncated recording (a killed run) reads up to its last complete chunk and on from
    its journal if the run left one; the trajectory then has ``success=False``, a message
    saying where it stopped, and ``meta["truncated"] = True``, ``meta["stopped_at"]`` (s).
    A damaged chunk loses only its own records: ``meta["gaps"]`` says which. ``meta`` also
    holds the step numbers, backbone points (N, n, P, 3), tip frames (N, n, 7), base frames
    (N, 7), logged total energy, scene text, model parameters and qchain version.

    Raises
    ------
    RecordingFormatError
        Not a qchain MCAP recording (message names the file and what is wrong).
    """
    return read_recording(path).to_trajectory()

