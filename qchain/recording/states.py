"""A recording's state messages (``/qchain/state``, one JSON object a step) decoded into
checked columns: every field a number or a list of numbers of the shape of the first
record's, times finite and within :data:`~qchain.recording.records.T_MAX`, steps whole and
within :data:`STEP_MAX`, shapes that fit the run's segments; their numbers charged to the
reading budget before they are parsed. :mod:`qchain.recording.reader` reads files with it.
"""

from __future__ import annotations

import numpy as np

from .bounded import ReadBudget
from .records import CONTACT_WIDTH, T_MAX, Batch, RecordingFormatError, RunInfo

#: Largest step number (a journal row holds it as a float64, exact up to 2**53).
STEP_MAX = 1 << 53

_STATE_KEYS = ("t", "step", "q", "v", "p", "kinetic", "potential", "total", "base", "tips", "backbone")
_STATE_KEYSET = frozenset(_STATE_KEYS)
#: The keys of a state of a run with tendons: ``tension`` too.
_TENDON_KEYSET = _STATE_KEYSET | {"tension"}
_BLOCK = 4096  # state messages decoded at once (the dicts of a block only are held)
#: Levels of list nesting of each field of a state (0: a number).
_NDIM = {"q": 1, "v": 1, "p": 1, "kinetic": 0, "potential": 0, "total": 0, "base": 1, "tips": 2, "backbone": 3,
         "tension": 1}


def _series_max(n: int) -> int:
    """Most entries q, v or p may have for n segments: 3 a segment and a floating base's 7."""
    return 3 * n + 7


def _state_error(name: str, offset: int, what: str) -> RecordingFormatError:
    return RecordingFormatError(f"{name}: the state message in the chunk at byte {offset}: {what}")


def _parse_state(data: bytes, offset: int, name: str) -> dict:
    import orjson

    try:
        s = orjson.loads(data)
    except orjson.JSONDecodeError as exc:
        raise _state_error(name, offset, f"not valid JSON ({exc})") from None
    if type(s) is not dict or (s.keys() != _STATE_KEYSET and s.keys() != _TENDON_KEYSET):
        found = ", ".join(sorted(s)) if isinstance(s, dict) else f"a JSON {type(s).__name__}"
        raise _state_error(name, offset, f"expected the fields {', '.join(_STATE_KEYS)} (and tension, with tendons); "
                                         f"found {found}")
    if data.count(b'"') != 2 * len(s) or b"true" in data or b"false" in data:  # no string but its keys
        raise _state_error(name, offset, "a value that is not a number, a list of numbers or null")
    step = s["step"]
    if type(step) is not int or not 0 <= step <= STEP_MAX:
        raise _state_error(name, offset, f"step must be a whole number from 0 to 2**53, found {step!r}")
    t = s["t"]
    if type(t) not in (int, float) or not 0.0 <= t <= T_MAX:
        raise _state_error(name, offset, f"t must be a time from 0 to {T_MAX:g} s, found {t!r}")
    return s


def _column(states: list[dict], offsets: list[int], key: str, shape: tuple | None, name: str) -> np.ndarray:
    """The field ``key`` of every state as one array (N, *shape); ``shape`` None: the first
    state's, if it has the field's nesting."""
    ndim = _NDIM[key]
    try:
        arr = np.array([s[key] for s in states], dtype=float)
    except (ValueError, TypeError):
        arr = None
    if arr is not None and arr.ndim == ndim + 1 and (shape is None or arr.shape[1:] == shape):
        return arr
    for s, off in zip(states, offsets):  # the first state at fault
        try:
            x = np.array(s[key], dtype=float)
        except (ValueError, TypeError) as exc:
            raise _state_error(name, off, f"{key} is not {'a number' if ndim == 0 else 'a list of numbers'} "
                                          f"(or lists of them, {ndim} deep) ({exc})") from None
        if x.ndim != ndim:
            raise _state_error(name, off, f"{key} is nested {x.ndim} deep, expected {ndim}")
        if shape is None:
            shape = x.shape
        elif x.shape != shape:
            raise _state_error(name, off, f"{key} has the shape {x.shape}, the others {shape}")
    raise _state_error(name, offsets[0], f"{key}: shapes that disagree")  # not reached


def _dims_error(name: str, offset: int, dims: dict, n: int) -> str | None:
    """Why the shapes of a record do not fit a recording of n segments, or None."""
    top = _series_max(n)
    for key in ("q", "v", "p"):
        if dims[key][0] > top:
            return f"{key} has {dims[key][0]} entries; {n} segment(s) have at most {top}"
    if dims["base"] != (7,):
        return f"base has the shape {dims['base']}, expected (7,)"
    if dims["tips"] != (n, 7):
        return f"tips has the shape {dims['tips']}, expected ({n}, 7) for {n} segment(s)"
    if "tension" in dims and (len(dims["tension"]) != 1 or dims["tension"][0] < 1):
        return f"tension has the shape {dims['tension']}, expected (nt,) with nt >= 1"
    bb = dims["backbone"]
    if bb[0] != n or bb[2] != 3 or bb[1] < 1:
        return f"backbone has the shape {bb}, expected ({n}, P, 3) with P >= 1 for {n} segment(s)"
    return None


#: Bytes of Python objects a parsed JSON number costs (a float and its list slot, with the
#: lists around; measured with tracemalloc on orjson): charged to the reading budget before a
#: message is parsed, so a few KiB of "[0.0,0.0,0.0]," compressed never grow into gigabytes
PARSED_NUMBER_BYTES = 56


def _decode_states(msgs: list[tuple[int, bytes]], info: RunInfo, name: str, budget: ReadBudget | None = None) -> Batch:
    """The ``/qchain/state`` messages ``(chunk offset, JSON)`` as checked columns; each
    message's numbers (its commas) are charged to ``budget`` before it is parsed."""
    n = info.n_segments
    if not msgs:
        return Batch(np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 0)), np.zeros((0, 0)), np.zeros((0, 3 * n)),
                     np.zeros((0, 3)), np.zeros((0, 7)), np.zeros((0, n, 0, 3)), np.zeros((0, n, 7)))
    dims: dict | None = None
    parts = []
    for a in range(0, len(msgs), _BLOCK):
        block = msgs[a : a + _BLOCK]
        offsets = [off for off, _ in block]
        if budget is not None:
            for off, data in block:
                budget.spend(PARSED_NUMBER_BYTES * data.count(b","), off, "the numbers of its state messages")
        states = [_parse_state(data, off, name) for off, data in block]
        cols = {}
        tendons = "tension" in states[0]
        if any(("tension" in s) != tendons for s in states):
            k = next(i for i, s in enumerate(states) if ("tension" in s) != tendons)
            raise _state_error(name, offsets[k], "tension in some states and not in others (one run, one layout)")
        if dims is not None and tendons != ("tension" in dims):
            raise _state_error(name, offsets[0], "tension in some states and not in others (one run, one layout)")
        for key in _NDIM:
            if key == "tension" and not tendons:
                continue
            cols[key] = _column(states, offsets, key, None if dims is None else dims[key], name)
        if dims is None:
            dims = {key: col.shape[1:] for key, col in cols.items()}
            why = _dims_error(name, offsets[0], dims, n)
            if why:
                raise _state_error(name, offsets[0], why)
        N = len(states)
        parts.append(Batch(
            t=np.array([s["t"] for s in states], dtype=float),
            step=np.array([s["step"] for s in states], dtype=np.int64),
            q=cols["q"], v=cols["v"], p=cols["p"],
            energy=np.stack([cols["kinetic"], cols["potential"], cols["total"]], axis=1).reshape(N, 3),
            base=cols["base"], backbone=cols["backbone"], tip_frames=cols["tips"], tension=cols.get("tension")))
        del states, cols
    return parts[0] if len(parts) == 1 else Batch.concatenate(parts)


_CONTACT_KEYS = frozenset(("t", "step", "point", "normal", "force", "segment", "obstacle"))


def _decode_contacts(msgs: list[tuple[int, bytes]], b: Batch, info: RunInfo, name: str,
                     budget: ReadBudget | None = None) -> np.ndarray | None:
    """The ``/qchain/contacts`` messages ``(chunk offset, JSON)`` as the contact blocks (K,
    C, CONTACT_WIDTH) of the records of ``b`` (matched by step; NaN rows: no contact, also
    for a record whose contact message was lost with a damaged chunk), ``C`` =
    ``info.max_contacts``; None when the run recorded no contacts (``C`` = 0)."""
    C = info.max_contacts
    if C == 0:
        return None
    out = np.full((len(b), C, CONTACT_WIDTH), np.nan)
    where = {int(s): k for k, s in enumerate(b.step.tolist())}
    import orjson

    n = info.n_segments
    m = len(info.obstacles or ())
    for off, data in msgs:
        if budget is not None:
            budget.spend(PARSED_NUMBER_BYTES * data.count(b","), off, "the numbers of its contact messages")
        try:
            s = orjson.loads(data)
        except orjson.JSONDecodeError as exc:
            raise RecordingFormatError(f"{name}: the contact message in the chunk at byte {off}: not valid JSON "
                                       f"({exc})") from None
        bad = None
        if type(s) is not dict or s.keys() != _CONTACT_KEYS:
            bad = f"expected the fields {', '.join(sorted(_CONTACT_KEYS))}"
        else:
            try:
                cols = [np.array(s[key], dtype=float).reshape(-1, w) for key, w in
                        (("point", 3), ("normal", 3), ("force", 3), ("segment", 1), ("obstacle", 1))]
            except (ValueError, TypeError) as exc:
                bad = f"its arrays are not (c, 3) and (c,) numbers ({exc})"
            else:
                c = cols[0].shape[0]
                seg, obs = cols[3][:, 0], cols[4][:, 0]
                if any(x.shape[0] != c for x in cols):
                    bad = "point, normal, force, segment and obstacle differ in length"
                elif c > C:
                    bad = f"{c} contacts, more than the run's max_contacts = {C}"
                elif not (np.isfinite(seg).all() and (seg >= 0).all() and (seg < n).all() and (seg == np.floor(seg)).all()):
                    bad = f"a segment that is not one of the {n}"
                elif not (np.isfinite(obs).all() and (obs == np.floor(obs)).all() and (obs >= -n).all()
                          and (obs < m).all()):  # (-1 - k: self-contact with segment k)
                    bad = f"an obstacle index that is not one of the {m} obstacles nor -1 - k for a segment k"
        if bad is not None:
            raise RecordingFormatError(f"{name}: the contact message in the chunk at byte {off}: {bad}")
        k = where.get(s["step"]) if type(s["step"]) is int else None
        if k is not None:  # (a contact message whose state was lost is not read)
            out[k, :c] = np.concatenate(cols, axis=1)
    return out
