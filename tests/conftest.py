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
