import signal
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))

# Tests stop child runs with Ctrl-C (SIGINT) and check what they leave. A shell starts a
# command put in the background (`cmd &`, `nohup cmd &`) with SIGINT ignored, and children
# inherit that: the child would then never see the Ctrl-C. Take SIGINT back for this
# process, so its children start with the default disposition (Python's KeyboardInterrupt).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


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
    ch = Chain([Segment(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085,
                        youngs_modulus=1e5, damping=0.01)])
    for method in COMPILED:
        kw = dict(dt=1e-3) if method in FIXED_STEP else {}
        tr = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, 2e-3), method=method, **kw)
        assert tr.success and tr.meta["engine"] == "compiled", tr.message
