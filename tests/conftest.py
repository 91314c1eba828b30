import io
import json
import signal
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

# the tests' own modules, importable now (pytest's importlib mode does not add this folder)
from logging_fixtures import arm_info, arm_records  # noqa: E402
from qchain.logging import TOPICS, RunLogger, read_recording  # noqa: E402
from qchain.recording.records import Batch  # noqa: E402
from qchain.recording.scan import scan  # noqa: E402
from support import N_LOGGED, N_SEG, N_WHOLE, POINTS, SCENE, SEGMENT, chunk_record, crc_of_repeated, zstd_rle  # noqa: E402

# Tests stop child runs with Ctrl-C (SIGINT) and check what they leave. A shell starts a
# command put in the background (`cmd &`, `nohup cmd &`) with SIGINT ignored, and children
# inherit that: the child would then never see the Ctrl-C. Take SIGINT back for this
# process, so its children start with the default disposition (Python's KeyboardInterrupt).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture(scope="module")
def examples():
    """``examples(name)`` imports ``examples/<name>.py`` (the examples' folder on the path)."""
    import importlib

    from support import EXAMPLES

    sys.path.insert(0, str(EXAMPLES))
    try:
        yield lambda name: importlib.import_module(name)
    finally:
        sys.path.remove(str(EXAMPLES))


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def pytest_sessionstart(session):
    """Compile (or load) the simulation engine of every compiled method once, before any test
    runs: tests that start ``qchain`` processes then find numba's cache warm instead of each
    compiling it against their own timeouts on a busy machine."""
    from qchain import Chain, Segment
    from qchain import compile_all
    from qchain.sim.simulation import COMPILED, FIXED_STEP, simulate

    compile_all(COMPILED)  # every part, cold ones in parallel worker processes
    ch = Chain([Segment(**SEGMENT)])
    for method in COMPILED:
        kw = dict(dt=1e-3) if method in FIXED_STEP else {}
        tr = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, 2e-3), method=method, **kw)
        assert tr.success and tr.meta["engine"] == "compiled", tr.message


@pytest.fixture(scope="module")
def whole(tmp_path_factory):
    """A recording of N records in several chunks, its rows and its qchain metadata."""
    path = tmp_path_factory.mktemp("whole") / "run.mcap"
    with RunLogger(arm_info(), path, flush_interval=0.05, quiet=True, worker="thread") as log:
        for r in arm_records(N_WHOLE, dt=1e-3):
            log.log(r)
    rec = read_recording(path)
    assert len(rec) == N_WHOLE and not rec.gaps
    b = rec.batch()
    return path.read_bytes(), b.rows(), Batch.layout.fget(b), rec.metadata


@pytest.fixture(scope="module")
def logged():
    """A recording written by RunLogger (four channels, 11 chunks) and its chunks:
    (offset, end, state records inside)."""
    buf = io.BytesIO()
    with RunLogger(arm_info(N_SEG), buf, flush_interval=0.05, quiet=True) as log:
        for r in arm_records(N_LOGGED, dt=1e-2, n=N_SEG, P=POINTS):
            log.log(r)
    data = buf.getvalue()
    rec = read_recording(io.BytesIO(data))
    state = {int(k) for k, v in json.loads(rec.metadata["channels"]).items() if v == TOPICS["state"]}
    chunks = [(it.offset, it.end, sum(1 for r in it.records if type(r).__name__ == "Message"
                                      and r.channel_id in state))
              for it in scan(data) if it.kind == "chunk"]
    assert sum(n for _, _, n in chunks) == N_LOGGED and len(chunks) >= 8
    return data, chunks


@pytest.fixture
def scene(tmp_path, monkeypatch):
    """``support.SCENE`` as ``scene.toml`` in a fresh working folder (the test runs there)."""
    monkeypatch.chdir(tmp_path)
    p = tmp_path / "scene.toml"
    p.write_text(SCENE)
    return p


@pytest.fixture(scope="module")
def gib_bomb():
    """A 32 KiB zstd chunk that expands to 1 GiB of zeros, its CRC correct."""
    total = 1 << 30
    frame = zstd_rle(total)
    assert len(frame) < 33 * 1024
    return chunk_record("zstd", frame, total, crc_of_repeated(0, total))
