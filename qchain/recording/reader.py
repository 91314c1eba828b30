"""Reading a recording back: every intact chunk, what is missing said, a killed run's journal.

See docs/recording.md, "Damage" and "Files from anywhere": a damaged chunk loses only its
own steps (:attr:`Recording.gaps`), sealed metadata is checked, a journal's records are read
too (:attr:`Recording.recovered`), and reading is bounded by :class:`ReadLimits`. Reading
parses JSON only: nothing in a file is executed."""

from __future__ import annotations

import errno
import math
import os
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np
from mcap.records import Channel, Message

from ..checks.convert import as_bool
from ..sim.trajectory import Trajectory
from .bounded import DEFAULT_LIMITS, LimitExceeded, ReadBudget, ReadLimits, loads, open_source
from .journal import JournalReader, journal_owner, journal_path
from .records import (
    CONTACT_TOPICS,
    FORMAT_NAME,
    FORMAT_VERSION,
    TOPICS,
    Batch,
    LoggingError,
    RecordingFormatError,
    T_MAX,
    RecordLayout,
    RunInfo,
    unseal,
)
from .scan import MAGIC, scan, summary_records
from .states import STEP_MAX, _decode_contacts, _decode_states, _series_max

__all__ = ["Recording", "Gap", "read_recording", "read_mcap", "T_MAX", "STEP_MAX"]


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
        where = f"bytes {self.offset}..{self.end}: " if self.end > self.offset else ""
        return f"records between {a} and {b} are missing ({where}{self.reason})"


@dataclass
class Recording(Batch):
    """Everything a qchain MCAP holds (the reading side of :class:`RunLogger`): its records, a
    :class:`Batch` (with ``contacts`` (K, max_contacts, 11) when the run recorded contacts,
    NaN-padded; :meth:`~Batch.contact_set` gives record ``k``'s; a record whose contact
    message was lost reads as having none; with ``tension`` (K, nt) N when the run had
    tendons; ``tendons``, their paths, only from records recovered from a journal: the file's
    state messages hold the tensions, not the paths), and

    Attributes
    ----------
    path : str
    info : RunInfo
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
    nonfinite : list of str
        Fields holding non-finite values (``null`` in the file, read as NaN): how many, in
        how many records, the first time. Empty for a run that stayed finite.
    disorder : str
        Where records are out of order (a time before the previous record's, or a step not
        after it: chunks duplicated or swapped), "" when they follow one another.
    journal_unread : str
        Why a journal beside the file (a killed run's) could not be read, or some of its
        records were not ("" when there is none, or it was read whole): ``recover`` then
        leaves it where it is.
    """

    path: str
    info: RunInfo
    outcome: dict | None
    truncated: bool
    stop_reason: str
    metadata: dict
    gaps: list = field(default_factory=list)
    damage: list = field(default_factory=list)
    recovered: int = 0
    nonfinite: list = field(default_factory=list)
    journal_unread: str = ""
    disorder: str = ""

    def batch(self) -> Batch:
        return Batch(*(getattr(self, f) for f in Batch.__dataclass_fields__
                       if f not in ("contacts", "tension", "tendons")),
                     contacts=self.contacts, tension=self.tension, tendons=self.tendons)

    @property
    def complete(self) -> bool:
        """Nothing missing: not truncated, no gap."""
        return not self.truncated and not self.gaps

    def to_trajectory(self) -> Trajectory:
        """The recording as a :class:`~qchain.sim.trajectory.Trajectory`; ``meta`` keeps the
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
        success = success and not self.gaps
        nonfinite = f"non-finite values recorded (null in the file, read as NaN): {'; '.join(self.nonfinite)}" \
            if self.nonfinite else ""
        message = "; ".join(filter(None, [message, *(g.describe() for g in self.gaps), nonfinite, self.disorder]))
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
                "nonfinite": self.nonfinite,
                "disorder": self.disorder,
                "outcome": out,
                "qchain_version": self.info.qchain_version,
                "scene": self.info.scene,
                "params": self.info.params,
            },
        )


# --------------------------------------------------------------------------------------
# Checking what a file says
# --------------------------------------------------------------------------------------


def _check_rows(rows: np.ndarray, lay, info: RunInfo, where: str) -> str | None:
    """Why the journal's rows (K, width) of layout ``lay`` do not fit, or None."""
    n = info.n_segments
    if lay.n != n:
        return f"its rows are of {lay.n} segment(s), the recording's {n}"
    top = _series_max(n)
    for key, size in (("q", lay.nq), ("v", lay.nv), ("p", lay.n_p)):
        if size > top:
            return f"its rows have {size} entries of {key}; {n} segment(s) have at most {top}"
    t, step = rows[:, 0], rows[:, 1]
    bad = ~((t >= 0.0) & (t <= T_MAX))
    if bad.any():
        return f"row {int(np.argmax(bad))} has the time {float(t[bad][0])!r} (expected 0 .. {T_MAX:g} s)"
    bad = ~((step >= 0.0) & (step <= STEP_MAX) & (step == np.floor(step)))
    if bad.any():
        return f"row {int(np.argmax(bad))} has the step {float(step[bad][0])!r} (expected a whole number 0 .. 2**53)"
    return None


def _nonfinite(b: Batch) -> list[str]:
    """Fields of ``b`` that hold non-finite values, in words."""
    out = []
    K = len(b)
    for key, label in (("q", "q"), ("v", "v"), ("p", "p"), ("energy", "energies"), ("base", "base"),
                       ("backbone", "backbone"), ("tip_frames", "tip frames"), ("tension", "tensions")):
        arr = getattr(b, key)
        if arr is None or K == 0 or arr.size == 0:
            continue
        bad = ~np.isfinite(arr.reshape(K, -1))
        if bad.any():
            rows = np.flatnonzero(bad.any(axis=1))
            k = int(rows[0])
            out.append(f"{label}: {int(bad.sum())} value(s) in {len(rows)} record(s), the first at t = {b.t[k]:.6g} s "
                       f"(step {int(b.step[k])})")
    return out


def _outcome_problem(e: dict[str, str]) -> str | None:
    """Why the entries of a ``qchain.outcome`` record cannot be used, or None."""
    if e.get("success", "false") not in ("true", "false"):
        return f"success is {e.get('success')!r}"
    for key, low in (("status", -(1 << 31)), ("nfev", 0), ("n_records", 0)):
        v = e.get(key)
        if v is None or (key == "n_records" and v == ""):
            continue
        try:
            x = int(v) if len(v) < 20 else None
        except ValueError:
            x = None
        if x is None or not low <= x < (1 << 62):
            return f"{key} is {v[:40]!r}, not a whole number"
    last_t = e.get("last_t", "")
    if last_t:
        try:
            ok = len(last_t) < 40 and math.isfinite(float(last_t))
        except ValueError:
            ok = False
        if not ok:
            return f"last_t is {last_t[:40]!r}"
    return None


def _info_of(meta: dict[str, str], where: str, limits: ReadLimits) -> RunInfo:
    """The :class:`RunInfo` of the ``qchain`` metadata (``where``: its record, as messages
    name it), checked."""
    try:
        data = loads(meta["info"], "the run information", limits)
    except KeyError:
        raise RecordingFormatError(f"{where} has no run information ('info')") from None
    except ValueError as exc:
        raise RecordingFormatError(f"{where}: {exc}") from None
    if not isinstance(data, dict):
        raise RecordingFormatError(f"{where}: the run information is a JSON {type(data).__name__}, not an object")
    n = data.get("n_segments")
    if isinstance(n, int) and not isinstance(n, bool) and n > limits.max_segments:
        raise RecordingFormatError(f"{where} declares {n} segments, more than {limits.max_segments} "
                                   "(ReadLimits.max_segments, or --max-segments of qchain replay, recover and layout, allows more)")
    segs = data.get("params", {}).get("segments") if isinstance(data.get("params"), dict) else None
    if segs is not None:
        good = isinstance(segs, list) and all(
            isinstance(s, dict) and ("length" not in s or (type(s["length"]) in (int, float) and s["length"] > 0))
            for s in segs)
        if not good:
            raise RecordingFormatError(f"{where}: params.segments must be a list of objects whose length is a "
                                       "number > 0 m")
    try:
        return RunInfo.from_json(data)
    except (KeyError, ValueError, TypeError) as exc:
        raise RecordingFormatError(f"{where} does not have the expected form ({exc})") from None


# --------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------


def read_recording(source: str | os.PathLike | BinaryIO, journal: bool = True, *,
                   limits: ReadLimits | None = None) -> Recording:
    """Read a qchain MCAP recording: complete, truncated or damaged, from anywhere.

    Parameters
    ----------
    source : path or binary stream
        A path must name a regular file (a FIFO or a device is refused, never waited on);
        a stream is read up to ``limits.max_stream_bytes``.
    journal : bool
        For a path: also read the records a killed run left in its journal
        (``PATH.journal``) and the file lacks. A journal whose ``recording_id`` is not
        the file's (another run's), or one holding records after a complete file's last
        (its outcome and summary are there), is not merged: ``journal_unread`` says so.
    limits : ReadLimits or None
        What reading may cost (default :class:`~qchain.recording.bounded.ReadLimits`()).

    Raises
    ------
    TypeError
        ``source`` is neither a path nor a binary stream (a text stream is refused: open
        the file with ``'rb'``), or ``journal`` is not True or False.
    RecordingFormatError
        The file is not an MCAP file, not a qchain recording, its qchain metadata is
        damaged in both copies, a value in it is not what the format allows, reading it
        would exceed ``limits``, or it cannot be read (not a regular file, no
        permission); the message names the file and, where there is one, the byte.
    FileNotFoundError
        No such file (and no journal of a run writing it).
    """
    journal = as_bool("read_recording: journal", journal)
    if limits is None:
        limits = DEFAULT_LIMITS
    elif not isinstance(limits, ReadLimits):
        raise TypeError(f"read_recording: limits must be a ReadLimits, got {type(limits).__name__}")
    name, buf, is_path = open_source(source, "source", "read_recording", limits)
    jpath = journal_path(name) if journal and is_path else None
    has_journal = jpath is not None and os.path.lexists(jpath)
    if buf is None:
        if not has_journal:
            raise FileNotFoundError(errno.ENOENT, "no such recording", name)
        buf = bytearray()  # the writer never started: the journal holds it all
    try:
        return _read(name, buf, jpath if has_journal else None, limits)
    except LimitExceeded as exc:
        raise RecordingFormatError(f"{name}: {exc}") from None


@dataclass
class _Found:
    """What reading found (:func:`_scan_file`, :func:`_read_journal`, :func:`_run_info`), for :func:`_read`.

    ``stream`` holds, in file order, ("m", channel id, data, chunk offset) and ("d", damage item):
    messages wait until the end in case their channel's record was lost (the sealed metadata names
    the channel ids too); ``chunk_times`` are (start, end) ns of every chunk read."""

    damage: list = field(default_factory=list)
    meta: dict | None = None
    meta_offset: int | None = None
    outcome: dict | None = None
    complete: bool = False
    stop_reason: str = ""
    state_channels: set = field(default_factory=set)
    contact_channels: set = field(default_factory=set)
    other_channels: set = field(default_factory=set)
    declared: dict = field(default_factory=dict)
    redeclared: set = field(default_factory=set)
    chunk_times: list = field(default_factory=list)
    stream: list = field(default_factory=list)
    journal_rows: np.ndarray | None = None
    journal_layout: RecordLayout | None = None
    journal_unread: str = ""


def _read(name: str, buf: bytearray, jpath, limits: ReadLimits) -> Recording:
    """The work of :func:`read_recording` (``buf`` empty: the journal holds it all); raises
    :class:`LimitExceeded` for the caller to name the file."""
    if len(buf) == 0 and jpath is None:
        raise RecordingFormatError(f"{name}: the file is empty, not a qchain MCAP recording")
    head = bytes(buf[: len(MAGIC)])
    if len(buf) and head != MAGIC[: len(head)]:
        raise RecordingFormatError(f"{name}: not an MCAP file (it starts with {head!r}, an MCAP file with "
                                   f"{MAGIC!r})")
    budget = ReadBudget(len(buf), limits)
    found = _scan_file(buf, budget)
    file_complete = found.complete and found.outcome is not None  # footer, summary and outcome: nothing to add
    _read_journal(found, name, jpath, limits)
    info = _run_info(found, name, jpath, len(buf), limits)
    b, gaps, index, stats = _assemble(found, info, name, buf, budget)
    b, gaps, recovered = _merge_journal(found, b, gaps, info, name, jpath, file_complete)
    if not gaps and not recovered:
        gap = _missing(b, name, found.outcome, stats, found.state_channels, index, found.chunk_times)
        if gap is not None:
            gaps.append(gap)
            found.damage.append(gap.reason)
    return Recording(
        path=name, info=info, t=b.t, step=b.step, q=b.q, v=b.v, p=b.p, energy=b.energy, base=b.base,
        backbone=b.backbone, tip_frames=b.tip_frames, contacts=b.contacts, tension=b.tension, tendons=b.tendons,
        outcome=found.outcome, truncated=not found.complete,
        stop_reason="" if found.complete else found.stop_reason, metadata=found.meta, gaps=gaps,
        damage=found.damage, recovered=recovered, nonfinite=_nonfinite(b), journal_unread=found.journal_unread,
        disorder=_disorder(b),
    )


def _scan_file(buf: bytearray, budget: ReadBudget) -> _Found:
    """Scan the file's records (:func:`qchain.recording.scan.scan`) into a new :class:`_Found`."""
    found = _Found()
    damage = found.damage
    for item in scan(buf, budget=budget) if len(buf) >= len(MAGIC) else ():
        if item.kind == "chunk":
            found.chunk_times.append((item.chunk.message_start_time, item.chunk.message_end_time))
            if item.reason:
                damage.append(item.reason)
            for rec in item.records:
                if isinstance(rec, Channel):
                    first = found.declared.setdefault(rec.id, rec.topic)
                    if first == rec.topic:
                        (found.state_channels if rec.topic == TOPICS["state"] else found.contact_channels
                         if rec.topic == CONTACT_TOPICS["contacts"] else found.other_channels).add(rec.id)
                    elif rec.id not in found.redeclared:
                        found.redeclared.add(rec.id)
                        damage.append(f"the chunk at byte {item.offset} declares channel {rec.id} again as "
                                      f"{rec.topic[:80]!r}, first declared as {first[:80]!r}: the first declaration "
                                      "is used")
                elif isinstance(rec, Message) and rec.channel_id not in found.other_channels:
                    found.stream.append(("m", rec.channel_id, rec.data, item.offset))
        elif item.kind == "metadata":
            entries = unseal(item.record.metadata)
            if item.record.name == "qchain":
                if entries is None:
                    damage.append(f"the qchain metadata record at byte {item.offset} fails its checksum: not used")
                elif found.meta is None:
                    found.meta, found.meta_offset = entries, item.offset
            elif item.record.name == "qchain.outcome":
                why = None if entries is None else _outcome_problem(entries)
                if entries is None:
                    damage.append(f"the qchain.outcome metadata record at byte {item.offset} fails its checksum: "
                                  "not used")
                elif why:
                    damage.append(f"the qchain.outcome metadata record at byte {item.offset} is not usable ({why}): "
                                  "not used")
                else:
                    found.outcome = entries
        elif item.kind == "footer":
            found.complete = True
        elif item.kind == "damage":
            found.stream.append(("d", item))
            damage.append(item.reason)
        elif item.kind == "end":
            found.stop_reason = item.reason
    if len(buf) < len(MAGIC):
        found.stop_reason = "the file ends before its first record"
    elif not found.complete and not found.stop_reason:
        found.stop_reason = "the file ends before its footer"
    return found


def _read_journal(found: _Found, name: str, jpath, limits: ReadLimits) -> None:
    """Read a killed run's journal into ``found`` (a live run's is not read)."""
    if jpath is None or journal_owner(jpath) is not None:
        return
    try:
        jr = JournalReader(jpath, limits)
        try:
            blocks = jr.poll(final=True)
        finally:
            jr.close()
    except FileNotFoundError:
        return
    except LimitExceeded as exc:
        raise RecordingFormatError(f"{jpath} (the journal of {name}): {exc}") from None
    except LoggingError as exc:  # not a regular file, not a journal, too big
        found.damage.append(f"journal: {exc}; not read")
        found.journal_unread = str(exc)
        return
    # a journal is merged only into its own run's file: the recording_id both carry (in
    # their qchain metadata) must agree; a journal without one (an older run's) is taken
    # only beside a file that is not complete (see _merge_journal)
    file_id = (found.meta or {}).get("recording_id", "")
    journal_id = (jr.metadata or {}).get("recording_id", "")
    if file_id and journal_id and file_id != journal_id:
        found.journal_unread = (f"the journal {jpath} is another run's (its recording_id {journal_id[:40]!r}, the "
                                f"file's {file_id[:40]!r}): not merged")
        return
    if found.meta is None and jr.metadata is not None:
        found.meta = jr.metadata
    if jr.layout is not None and blocks:
        found.journal_rows, found.journal_layout = np.concatenate(blocks), jr.layout
    if found.outcome is None and jr.outcome is not None and _outcome_problem(jr.outcome) is None:
        found.outcome = jr.outcome
    found.damage.extend(f"journal: {d}" for d in jr.damage)
    if jr.lost:  # what it holds is read, but it is not whole: recover keeps it
        found.journal_unread = "; ".join(jr.lost[:3]) + (f" (and {len(jr.lost) - 3} more)" if len(jr.lost) > 3
                                                         else "")


def _run_info(found: _Found, name: str, jpath, size: int, limits: ReadLimits) -> RunInfo:
    """The run's :class:`RunInfo` from the ``qchain`` metadata found, its format and version
    checked; the state channels it names are added to ``found``."""
    meta, damage = found.meta, found.damage
    if meta is None and size == 0:
        raise RecordingFormatError(f"{name}: no recording file, and its journal {jpath} holds no qchain recording ("
                                   f"{'; '.join(damage) or 'no qchain metadata'})")
    if meta is None or meta.get("format") != FORMAT_NAME:
        if any("qchain metadata" in d for d in damage):
            raise RecordingFormatError(f"{name}: its qchain metadata record is damaged (checksum mismatch) and "
                                       "no intact copy was found")
        if found.stop_reason or damage:
            raise RecordingFormatError(
                f"{name}: an MCAP file without a qchain header record (cut before it, or written by another "
                f"program; reading stopped: {found.stop_reason or damage[0]})")
        raise RecordingFormatError(
            f"{name}: an MCAP file, but not a qchain recording (no 'qchain' metadata record with format "
            f"{FORMAT_NAME!r})")
    where = f"{name}: its qchain metadata record" + (f" at byte {found.meta_offset}" if found.meta_offset is not None
                                                      else "")
    version = meta.get("format_version", "0")
    if version != str(FORMAT_VERSION):
        raise RecordingFormatError(f"{name}: qchain recording format version {version[:40]!r}; this qchain reads "
                                   f"version {FORMAT_VERSION}")
    info = _info_of(meta, where, limits)
    if "channels" in meta:
        try:
            channels = loads(meta["channels"], "its channel list", limits)
            if not isinstance(channels, dict):
                raise ValueError("its channel list is not a JSON object")
            ids = {int(k) for k, v in channels.items() if v == TOPICS["state"] and k.isascii() and k.isdigit()
                   and len(k) < 6}
            named = {int(k) for k in channels if k.isascii() and k.isdigit() and len(k) < 6}
            contact_ids = {int(k) for k, v in channels.items() if v == CONTACT_TOPICS["contacts"] and k.isascii()
                           and k.isdigit() and len(k) < 6}
        except ValueError as exc:
            raise RecordingFormatError(f"{where}: {exc}") from None
        found.state_channels |= ids - found.other_channels
        found.contact_channels |= contact_ids - found.other_channels - found.state_channels
        for k in named:
            found.declared.setdefault(k, "")
    return info


def _assemble(found: _Found, info: RunInfo, name: str, buf: bytearray, budget: ReadBudget):
    """The file's state messages as a :class:`Batch`, its gaps, and the summary's chunk index
    and statistics (None, None: the file is not complete); empties ``found.stream``."""
    msgs: list[tuple[int, bytes]] = []
    contact_msgs: list[tuple[int, bytes]] = []
    events: list[tuple[int, object]] = []  # (position in msgs, damage item)
    undeclared: dict[int, int] = {}  # channel id -> messages on it, never declared
    for entry in found.stream:
        if entry[0] == "m":
            if entry[1] in found.state_channels:
                msgs.append((entry[3], entry[2]))
            elif entry[1] in found.contact_channels:
                contact_msgs.append((entry[3], entry[2]))
            elif entry[1] not in found.declared:
                undeclared[entry[1]] = undeclared.get(entry[1], 0) + 1
        else:
            events.append((len(msgs), entry[1]))
    found.stream = []
    damage = found.damage
    if undeclared:
        damage.append(f"{sum(undeclared.values())} message(s) on channel(s) "
                      f"{', '.join(map(str, sorted(undeclared)[:10]))} that no channel record declares: not read")
    summary = summary_records(buf, budget) if found.complete else None
    index, stats = summary if summary is not None else (None, None)
    b = _decode_states(msgs, info, name, budget)
    del msgs
    b.contacts = _decode_contacts(contact_msgs, b, info, name, budget)
    del contact_msgs
    gaps = []
    for pos, item in events:
        if index is not None and not any(item.offset <= c.chunk_start_offset < item.end for c in index):
            damage[damage.index(item.reason)] = item.reason + " (no chunk there, per the summary: no record lost)"
            continue  # an index record, say: the summary shows no chunk was in the damaged bytes
        gaps.append(_gap_before(b, pos, item.offset, item.end, item.reason))
    return b, gaps, index, stats


def _merge_journal(found: _Found, b: Batch, gaps: list, info: RunInfo, name: str, jpath, file_complete: bool):
    """Merge the journal's rows the file lacks (after its last record, inside its gaps): returns
    (batch, gaps, rows recovered); rows that do not fit are said in ``found`` and not merged."""
    rows, lay = found.journal_rows, found.journal_layout
    if rows is not None:
        why = _check_rows(rows, lay, info, str(jpath))
        if why is None and len(b):
            if (b.q.shape[1], b.v.shape[1], b.p.shape[1], b.backbone.shape[2]) != (lay.nq, lay.nv, lay.n_p, lay.P):
                why = f"its rows have the layout {lay.to_json()}, the recording's records another"
        if why is not None:  # the file's own records still read; the journal is said, kept, not merged
            if not len(b) and not found.complete:
                raise RecordingFormatError(f"{jpath} (the journal of {name}): {why}")
            found.journal_unread = f"{jpath} (the journal of {name}): {why}: not merged"
            found.damage.append(found.journal_unread)
            rows = None
    if rows is None:
        return b, gaps, 0
    inside = np.zeros(len(rows), dtype=bool)
    if len(b):  # records the file lacks: after its last, and inside it (a damaged chunk's)
        last, last_t = int(b.step[-1]), float(b.t[-1])
        after = (rows[:, 1] > last) & (rows[:, 0] >= last_t)
        have = np.isin(rows[:, 1], b.step)
        inside = ~after & (rows[:, 1] < last) & ~have
        odd = ~(after | inside | have)  # a later step at an earlier time: no place for it
        if odd.any():
            found.journal_unread = (f"{int(odd.sum())} rows of the journal {jpath} have steps after the file's last "
                                    f"({last}) but times before its last ({last_t:.6g} s): not merged")
        if file_complete and after.any():  # never appended to a complete file: said instead
            found.journal_unread = (f"the file is complete (its outcome and summary are there), yet its journal "
                                    f"{jpath} holds {int(after.sum())} records after its last: not merged")
            after[:] = False
        rows = rows[after | inside]
        inside = inside[after | inside]
    recovered = len(rows)
    if recovered:
        filled = int(inside.sum())
        jb = Batch.from_rows(rows, lay)
        b = jb if len(b) == 0 else Batch.concatenate([b, jb])
        if filled:  # the file's records and the journal's in step order
            b = b.take(np.argsort(b.step, kind="stable"))
        if gaps:  # a gap whose steps the journal holds is filled: said as damage, not as a gap
            gaps = _unfilled(gaps, b, found.damage, jpath)
        if recovered > filled and not found.complete:
            found.stop_reason = (found.stop_reason + "; " if found.stop_reason else "") + \
                f"{recovered - filled} records after it read from the run's journal {jpath}"
    return b, gaps, recovered


def _gap_before(b: Batch, k: int, offset: int, end: int, reason: str) -> Gap:
    """The gap between the records ``k - 1`` and ``k`` of ``b`` (``k`` 0: before the first;
    ``len(b)``: after the last) of the damaged bytes ``offset`` .. ``end``."""
    first, last = k == 0, k >= len(b)
    return Gap(None if first else float(b.t[k - 1]), None if last else float(b.t[k]),
               None if first else int(b.step[k - 1]), None if last else int(b.step[k]), offset, end, reason)


def _unfilled(gaps: list, b: Batch, damage: list, jpath) -> list:
    """The gaps the merged records ``b`` do not fill; a filled gap's ``damage`` entry names ``jpath``."""
    have = set(b.step.tolist())
    kept = []
    for g in gaps:
        lo = -1 if g.after_step is None else g.after_step
        hi = g.before_step if g.before_step is not None else (max(have) + 1 if lo + 1 in have else lo + 1)
        if hi > lo + 1 and all(k in have for k in range(lo + 1, hi)):
            damage[damage.index(g.reason)] = f"{g.reason} (its records read from the run's journal {jpath})"
        else:
            kept.append(g)
    return kept


def _missing(b: Batch, name: str, outcome, stats, state_channels: set, index, chunk_times) -> Gap | None:
    """A gap for records the file says it holds but does not: its outcome's ``n_records``
    or its summary's message count of the state channel more than were read (a chunk cut
    out cleanly leaves no damage to find). Where the summary's chunk index shows chunks
    whose times hold no record read, the gap is there; else it is the whole run."""
    counts = []
    if outcome is not None and outcome.get("n_records"):
        counts.append((int(outcome["n_records"]), "its qchain.outcome record"))
    if stats is not None and state_channels:
        n = sum(stats.channel_message_counts.get(c, 0) for c in state_channels)
        if n:
            counts.append((n, "its summary's statistics"))
    if not counts:
        return None
    expected, source = max(counts)
    if expected <= len(b):
        return None
    why = f"{source} counts {expected} records, {len(b)} were read: {expected - len(b)} missing"
    read_ns = np.rint(b.t * 1e9).astype(np.int64)
    have = set(chunk_times)
    for c in index or ():
        span = (c.message_start_time, c.message_end_time)
        if span in have or np.any((read_ns >= span[0]) & (read_ns <= span[1])):
            continue
        k = int(np.searchsorted(read_ns, span[0]))  # the first record read after the missing chunk
        return _gap_before(b, k, int(c.chunk_start_offset), int(c.chunk_start_offset + c.chunk_length),
                           f"{why} (the summary lists a chunk of t = {span[0] / 1e9:.6g} .. {span[1] / 1e9:.6g} s "
                           "that the file does not hold)")
    return Gap(None, None, None, None, 0, 0, f"{why}, where is not known")


def _disorder(b: Batch) -> str:
    """Where the records are out of order, in words ("" if they are not)."""
    if len(b) < 2:
        return ""
    back = (np.diff(b.t) < 0) | (np.diff(b.step) <= 0)
    if not back.any():
        return ""
    k = int(np.argmax(back)) + 1
    return (f"records out of order: {int(back.sum())} record(s) do not follow the one before (the first: step "
            f"{int(b.step[k])} at t = {b.t[k]:.6g} s after step {int(b.step[k - 1])} at t = {b.t[k - 1]:.6g} s)")


def read_mcap(path: str | os.PathLike | BinaryIO, *, limits: ReadLimits | None = None) -> Trajectory:
    """Read a qchain MCAP recording as a :class:`~qchain.sim.trajectory.Trajectory`:
    ``read_recording(path, limits=limits).to_trajectory()`` (truncation, gaps and non-finite
    values said in its message and ``meta``; backbone (N, n, P, 3) m, tip frames (N, n, 7), base
    (N, 7) in ``meta``).

    Raises
    ------
    TypeError
        ``path`` is neither a path nor a binary stream.
    RecordingFormatError
        Not a (readable) qchain MCAP recording (message names the file and what is wrong).
    FileNotFoundError
    """
    if not isinstance(path, (str, os.PathLike)) and not callable(getattr(path, "read", None)):
        raise TypeError(f"read_mcap: path must be a path (str or os.PathLike) or a binary stream with read(); got "
                        f"{'None' if path is None else type(path).__name__}")
    return read_recording(path, limits=limits).to_trajectory()
