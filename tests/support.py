"""Shared test parameters, sample arms and builders (plain functions, not fixtures): the one
segment-parameter dict ``SEGMENT`` and what the tests build from it, crafted scenes and
recordings. Fixtures shared by several modules are in conftest.py."""

import io
import json
import math
import re
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from mcap.writer import CompressionType, Writer

from helpers import SEGMENTS_TOML, deadline
from logging_fixtures import arm_info, arm_records
from qchain import Chain, Segment
from qchain.checks import bounds as B
from qchain.cli.main import main
from qchain.logging import TOPICS, RecordingFormatError, read_recording
from qchain.recording.journal import JournalWriter, journal_path
from qchain.recording.mcap_sink import info_metadata
from qchain.recording.records import seal
from qchain.recording.scan import scan

#: the repository's root folder
ROOT = Path(__file__).resolve().parents[1]
#: the examples' folder
EXAMPLES = ROOT / "examples"


def is_png(path) -> bool:
    """A PNG file of more than 10 kB (a drawn figure, not an empty canvas)."""
    path = Path(path)
    return path.is_file() and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and path.stat().st_size > 10_000

#: one short soft segment (SI units: m, kg, m^2, Pa, s): the arm of most bad-input tests
SEGMENT = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5,
               damping=0.01)


# -- sample arms and the bad values the Python API refuses

S = Segment(**SEGMENT)
CH1 = Chain([S])
CH2 = Chain([S, S])
CHF = Chain([S], base="floating")
QB = np.array([0.105, 8.0, -2.0])  # a bent configuration of one segment


def soft_segment(**kw):
    return Segment(**dict(SEGMENT, **kw))


def soft_arm(n=3, **kw):
    return Chain([Segment(**SEGMENT) for _ in range(n)], **kw)


def pressure_arm():
    return Chain([soft_segment(), soft_segment()])  # 6 pressures, 6 generalised forces


FEW = settings(max_examples=60, deadline=None, derandomize=True, database=None,
               suppress_health_check=[HealthCheck.too_slow])


class RaisingFloat:
    def __float__(self):
        raise RuntimeError("boom from __float__")


def value_id(value) -> str:
    """A parametrized value's test id: its ``repr`` without memory addresses, so that every
    collection (each pytest-xdist worker's) names the same tests."""
    return re.sub(r" at 0x[0-9a-fA-F]+", "", repr(value))


def refused(call, name, exc=(TypeError, ValueError)):
    """``call()`` raises ``exc`` (a qchain error or TypeError/ValueError) whose message names
    ``name``; returns the message."""
    with pytest.raises(exc) as info:
        call()
    err = info.value
    assert not isinstance(err, np.linalg.LinAlgError) and type(err).__module__.split(".")[0] != "numba", repr(err)
    msg = str(err)
    assert name in msg and "could not convert" not in msg, msg
    return msg


# -- numbers inside and outside the declared ranges (qchain.checks.bounds)

def outside(rng: B.Range):
    """Numbers outside ``rng`` (or not finite)."""
    floats = st.floats(allow_nan=True, allow_infinity=True, width=64)
    if rng.integer:
        ints = st.integers(min_value=-(10**30), max_value=10**30)
        return ints.filter(lambda x: not rng.contains(x)) | floats
    return floats.filter(lambda x: not (math.isfinite(x) and rng.contains(x)))


NOT_NUMBERS = st.one_of(st.booleans(), st.text(max_size=8), st.just([]), st.just({"a": 1}),
                        st.integers(min_value=10**309, max_value=10**320))


def in_range(rng: B.Range, low=None, high=None):
    """Log-uniform numbers inside ``rng`` (and ``[low, high]``)."""
    lo = max(rng.low, low) if low is not None else rng.low
    hi = min(rng.high, high) if high is not None else rng.high
    lo = max(lo, 1e-300)
    return st.floats(math.log10(lo), math.log10(hi)).map(lambda e: min(max(10.0 ** e, lo), hi))


@st.composite
def segments_in_range(draw, fit=st.floats(0.01, 1.0)):
    """Segment parameters inside the declared box; chambers that fit unless ``fit`` draws above 1."""
    r = draw(in_range(B.RADIUS))
    return dict(
        length=draw(in_range(B.LENGTH)), radius=r, mass=draw(in_range(B.MASS)),
        chamber_radius=0.5 * r * draw(st.floats(0.01, 1.0)),
        chamber_area=math.pi * (0.5 * r * draw(fit)) ** 2,
        youngs_modulus=draw(in_range(B.YOUNGS_MODULUS)), damping=draw(st.sampled_from([0.0, 1e-3, 1.0, 100.0])),
    )


# -- scene files: written from dicts, and the command line's scenes and sweeps

def toml_string(s: str) -> str:
    """A TOML basic string: quotes, backslashes and control characters escaped."""
    out = []
    for c in s:
        if c in '"\\':
            out.append("\\" + c)
        elif ord(c) < 0x20 or ord(c) == 0x7F:
            out.append(f"\\u{ord(c):04x}")
        else:
            out.append(c)
    return '"' + "".join(out) + '"'


def toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, str):
        return toml_string(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{toml_string(k)} = {toml_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(type(v))


def to_toml(d: dict) -> str:
    lines, tables = [], []
    for k, v in d.items():
        if isinstance(v, dict):
            tables.append((k, v))
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            tables.append((k, v))
        else:
            lines.append(f"{toml_string(k)} = {toml_value(v)}")
    for k, v in tables:
        if isinstance(v, dict):
            lines.append(f"[{k}]")
            lines += [f"{toml_string(kk)} = {toml_value(x)}" for kk, x in v.items()]
        else:
            for item in v:
                lines.append(f"[[{k}]]")
                lines += [f"{toml_string(kk)} = {toml_value(x)}" for kk, x in item.items()]
    return "\n".join(lines) + "\n"


def base_scene(kind: str = "constant", base: str = "fixed") -> dict:
    """A valid two-segment scene; ``kind`` the pressure type, ``base`` the base type."""
    pressure = {
        "constant": {"type": "constant", "value": [1e4, 0, 0, 0, 2e4, 2e4]},
        "step": {"type": "step", "time": 0.05, "after": [1e4] * 6},
        "ramp": {"type": "ramp", "t0": 0.0, "t1": 0.05, "end": [1e4] * 6},
        "sine": {"type": "sine", "amplitude": [1e4] * 6, "offset": [1e4] * 6, "frequency": 2.0},
        "table": {"type": "table", "times": [0.0, 0.05], "values": [[0] * 6, [1e4] * 6]},
    }[kind]
    d = {"name": "bad input", "segments": [dict(SEGMENT), dict(SEGMENT, length=0.08)], "pressure": pressure,
         "simulation": {"duration": 0.1}}
    if base == "floating":
        d["base"] = {"type": "floating"}
    elif base == "prescribed":
        d["base"] = {"type": "prescribed", "motion": {"type": "translation", "axis": [1.0, 0.0, 0.0],
                                                     "amplitude": 0.01, "frequency": 1.0}}
    return d


#: two segments, rk4 for 0.02 s, no plots: the command-line and sweep tests' scene
SCENE = """
name = "adversarial"
""" + SEGMENTS_TOML + """[pressure]
type = "constant"
value = [1e4, 0, 0, 0, 2e4, 2e4]
[simulation]
duration = 0.02
method = "rk4"
dt = 1e-3
[output]
sample_rate = 100.0
plots = []
"""

#: one segment under a constant pressure, radau5 for 0.05 s, the tip plot (replace NAME)
ONE_SEGMENT_SCENE = """
name = "NAME"
""" + SEGMENTS_TOML.replace("count = 2", "count = 1") + """[pressure]
type = "constant"
value = [2e4, 0.0, 0.0]
[simulation]
duration = 0.05
method = "radau5"
[output]
sample_rate = 200.0
plots = ["tip"]
"""

FAST = settings(max_examples=60, deadline=2000, derandomize=True, database=None)


def run(argv, capsys, seconds=30):
    with deadline(seconds, f"qchain {' '.join(map(str, argv))[:80]}"):
        code = main([str(a) for a in argv])
    got = capsys.readouterr()
    return code, got.out, got.err


def error_line(err: str) -> str:
    lines = [line for line in err.splitlines() if ": error: " in line]
    assert len(lines) == 1, err
    return lines[0]


SWEEP_HEAD = 'scene = "scene.toml"\nfolder = "res"\n'
AXIS = '[[axes]]\nkey = "segments[0].damping"\nvalues = [0.01, 0.02]\n'


def sweep_file(tmp_path, text):
    (tmp_path / "scene.toml").write_text(SCENE)
    p = tmp_path / "study.toml"
    p.write_text(text)
    return p


# -- crafted recordings: state messages, whole files, raw MCAP records

N_SEG, POINTS = 2, 4  # segments and backbone points a segment of the crafted recordings
N_LOGGED = 60  # records of the ``logged`` recording (conftest.py)


def state_dicts(k: int) -> list[dict]:
    out = []
    for r in arm_records(k, dt=1e-2, n=N_SEG, P=POINTS):
        out.append({"t": r.t, "step": r.step, "q": r.q.tolist(), "v": r.v.tolist(), "p": r.p.tolist(),
                    "kinetic": r.kinetic, "potential": r.potential, "total": r.total,
                    "base": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "tips": r.tip_frames.tolist(),
                    "backbone": r.backbone.tolist()})
    return out


def craft_chunks(states=None, *, info: dict | None = None, outcome: dict | None = None, chunks: int = 2,
          before=None) -> bytes:
    """A state-only qchain recording (sealed metadata, zstd chunks); ``before(writer, cid)``
    may add records ahead of the messages."""
    states = state_dicts(6) if states is None else states
    buf = io.BytesIO()
    w = Writer(buf, chunk_size=1 << 40, compression=CompressionType.ZSTD)
    w.start(profile="", library="crafted")
    sid = w.register_schema("qchain.State", "jsonschema", b"{}")
    cid = w.register_channel(TOPICS["state"], "json", sid)
    m = info_metadata(arm_info(N_SEG), "crafted")
    if info is not None:
        m["info"] = json.dumps(info)
    m["channels"] = json.dumps({str(cid): TOPICS["state"]})
    w.add_metadata("qchain", seal(m))
    if before is not None:
        before(w, cid)
    per = max(1, -(-len(states) // chunks))
    for k, s in enumerate(states):
        w.add_message(cid, k, json.dumps(s).encode(), k, k)
        if (k + 1) % per == 0:
            w.flush()
    w.add_metadata("qchain.outcome", seal(outcome or {"success": "true", "status": "0", "message": "ok",
                                                      "n_records": str(len(states))}))
    w.finish()
    return buf.getvalue()


def state_of(r) -> dict:
    """A step record as the ``/qchain/state`` message's JSON object."""
    return {"t": r.t, "step": r.step, "q": r.q.tolist(), "v": r.v.tolist(), "p": r.p.tolist(),
            "kinetic": r.kinetic, "potential": r.potential, "total": r.total,
            "base": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0], "tips": r.tip_frames.tolist(),
            "backbone": r.backbone.tolist()}


def good_states(k: int = 6) -> list[dict]:
    return [state_of(r) for r in arm_records(k, dt=1e-2, n=N_SEG, P=POINTS)]


def craft(states=None, info: dict | None = None, meta: dict | None = None, outcome: dict | None = None,
          chunks: int = 2) -> bytes:
    """A qchain recording: the state channel only, ``states`` (dicts, or raw bytes as the
    message data) in ``chunks`` zstd chunks, the ``qchain`` metadata built from ``info``
    (RunInfo JSON) with ``meta`` entries replaced, all sealed."""
    base_info = arm_info(N_SEG)
    states = good_states() if states is None else states
    buf = io.BytesIO()
    w = Writer(buf, chunk_size=1 << 40, compression=CompressionType.ZSTD)
    w.start(profile="", library="crafted")
    sid = w.register_schema("qchain.State", "jsonschema", b"{}")
    cid = w.register_channel(TOPICS["state"], "json", sid)
    m = info_metadata(base_info, "crafted")
    if info is not None:
        m["info"] = json.dumps(info)
    m["channels"] = json.dumps({str(cid): TOPICS["state"]})
    if meta:
        m.update(meta)
    w.add_metadata("qchain", seal(m))
    per = max(1, -(-len(states) // chunks))
    for k, s in enumerate(states):
        w.add_message(cid, k, s if isinstance(s, bytes) else json.dumps(s, allow_nan=False).encode(), k, k)
        if (k + 1) % per == 0:
            w.flush()
    w.add_metadata("qchain.outcome", seal(outcome or {"success": "true", "status": "0", "message": "ok",
                                                      "nfev": "1"}))
    w.finish()
    return buf.getvalue()


def info_json(**changes) -> dict:
    d = json.loads(json.dumps(arm_info(N_SEG).to_json()))
    d.update(changes)
    return d


def chunk_record(compression: str, data: bytes, usize: int, crc: int) -> bytes:
    """An MCAP chunk record holding ``data`` as it stands."""
    c = compression.encode()
    body = struct.pack("<QQQII", 0, 0, usize, crc, len(c)) + c + struct.pack("<Q", len(data)) + data
    return struct.pack("<BQ", 0x06, len(body)) + body


def splice(data: bytes, record: bytes) -> bytes:
    """``data`` with ``record`` inserted before its first chunk."""
    first = next(item.offset for item in scan(data) if item.kind == "chunk")
    return data[:first] + record + data[first:]


def zstd_rle(total: int, byte: int = 0) -> bytes:
    """A zstd frame of ``total`` bytes ``byte``: RLE blocks of 128 KiB, 4 bytes each (32 KiB
    a GiB), window 128 KiB, so any decoder takes it."""
    out = bytearray(b"\x28\xb5\x2f\xfd" + bytes([0xC0, 0x38]) + struct.pack("<Q", total))
    left = total
    while left:
        n = min(1 << 17, left)
        left -= n
        out += struct.pack("<I", (n << 3) | (1 << 1) | (left == 0))[:3] + bytes([byte])
    return bytes(out)


def crc_of_repeated(byte: int, total: int) -> int:
    piece = bytes([byte]) * (1 << 20)
    crc = 0
    for _ in range(total >> 20):
        crc = zlib.crc32(piece, crc)
    return zlib.crc32(piece[: total & ((1 << 20) - 1)], crc)


def write(tmp_path: Path, data: bytes, name: str = "crafted.mcap") -> Path:
    p = tmp_path / name
    p.write_bytes(data)
    return p


def refused_recording(path, match: str = "", **kw) -> RecordingFormatError:
    """The RecordingFormatError reading ``path`` raises; it names the file."""
    with pytest.raises(RecordingFormatError) as err:
        read_recording(path, **kw)
    msg = str(err.value)
    assert str(path) in msg, msg
    assert match in msg, msg
    return err.value


def assert_valid(rec) -> None:
    """A recording as the reader may hand it on: times and steps finite and in range, shapes
    consistent, and every non-finite value said in ``nonfinite``."""
    N = len(rec)
    assert rec.t.shape == (N,) and rec.step.shape == (N,) and rec.step.dtype == np.int64
    assert np.all(np.isfinite(rec.t)) and np.all((rec.t >= 0) & (rec.t <= 2**32 - 1))
    assert np.all((rec.step >= 0) & (rec.step <= 1 << 53))
    n = rec.info.n_segments
    assert rec.backbone.shape[:2] == (N, n) and rec.tip_frames.shape == (N, n, 7) and rec.base.shape == (N, 7)
    said = " ".join(rec.nonfinite)
    for key, label in (("q", "q"), ("v", "v"), ("p", "p"), ("energy", "energies"), ("base", "base"),
                       ("backbone", "backbone"), ("tip_frames", "tip frames")):
        arr = getattr(rec, key)
        assert np.all(np.isfinite(arr)) or f"{label}:" in said, (key, rec.nonfinite)
    if rec.nonfinite:
        assert "non-finite" in rec.to_trajectory().message


# -- a killed run's journal

N_WHOLE = 300  # records of the ``whole`` recording (conftest.py)


def write_journal(path: Path, rows: np.ndarray, layout, metadata: dict, blocks: int = 6) -> None:
    """The journal a run of ``rows`` leaves when it is killed: every row on disk, no end."""
    jw = JournalWriter(journal_path(path), metadata, str(path))
    jw.start(layout)
    for part in np.array_split(rows, blocks):
        jw.append(np.ascontiguousarray(part))
    jw.release(remove=False)
