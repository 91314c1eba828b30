"""Shared test parameters and assertions (not fixtures), and fake viewer peers."""

import contextlib
import faulthandler
import os
import signal
import socket
import struct
import threading
import time

import numpy as np

SEGMENT_KW = dict(
    length=0.2,
    radius=0.02,
    mass=0.3,
    chamber_area=2e-5,
    chamber_radius=0.01,
    youngs_modulus=1e5,
)

#: two short soft segments in a scene file's form: the arm of the command-line, sweep and
#: viewer tests' scenes
SEGMENTS_TOML = """[[segments]]
count = 2
length = 0.1
radius = 0.015
mass = 0.05
chamber_area = 4.5e-5
chamber_radius = 0.0085
youngs_modulus = 1e5
damping = 0.02
"""

#: a 0.1 s rk4 run of those segments under a pressure ramp (the command-line tests' scene)
SHORT_SCENE = f"""
name = "short"
gravity = [0.0, 0.0, -9.81]
[model]
node_tolerance = 1e-8
{SEGMENTS_TOML}[pressure]
type = "ramp"
t0 = 0.0
t1 = 0.05
end = [3e4, 0.0, 0.0,  0.0, 2e4, 0.0]
[simulation]
duration = 0.1
method = "rk4"
dt = 1e-3
[output]
sample_rate = 100.0
"""


def bent(coords, theta, psi=0.7, l=0.22):
    """A configuration of bending angle ``theta`` (rad), azimuth ``psi``, length ``l`` (m)."""
    kappa = theta / l
    if coords == "paper":
        return np.array([l, psi, kappa])
    return np.array([l, kappa * np.cos(psi), kappa * np.sin(psi)])


def rel(a, b):
    """Relative difference ``|a - b| / |b|`` (Frobenius / 2-norm)."""
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)) / np.linalg.norm(b))


def assert_regular_at_straight_pose(f, length, direction=(0.6, 0.8), rtol=1e-12):
    """``f(q_c)`` at curvature ``kappa`` in 1e-12, 1e-8 along ``direction`` is finite and equals
    ``f(0) + kappa f'(0)`` to ``rtol`` relative (``f'`` by central differences at kappa = +-1e-4,
    whose own error, O(1e-8) f''', contributes O(1e-16) at these kappa)."""
    d = np.array([0.0, *direction])
    q0 = np.array([length, 0.0, 0.0])
    f0 = np.asarray(f(q0))
    assert np.all(np.isfinite(f0))
    h = 1e-4
    slope = (np.asarray(f(q0 + h * d)) - np.asarray(f(q0 - h * d))) / (2 * h)
    for k in [1e-12, 1e-8]:
        fk = np.asarray(f(q0 + k * d))
        assert np.all(np.isfinite(fk))
        assert np.linalg.norm(fk - f0 - k * slope) <= rtol * np.linalg.norm(f0), k


class Hang(Exception):
    """A block ran longer than its :func:`deadline`."""


@contextlib.contextmanager
def deadline(seconds: float, what: str = "the block"):
    """Fail, not hang, when the block runs longer than ``seconds``: SIGALRM interrupts the
    main thread's wait and raises :class:`Hang`, after printing every thread's stack
    (where it hung)."""
    def expired(signum, frame):
        faulthandler.dump_traceback(all_threads=True)
        raise Hang(f"{what} still running after {seconds} s: a hang (every thread's stack is above)")

    old = signal.signal(signal.SIGALRM, expired)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


#: The answer of an HTTP/2 server to a connection: an empty SETTINGS frame.
SETTINGS = b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"


class Peer:
    """A fake Rerun viewer: a TCP server on 127.0.0.1 that accepts connections and then
    behaves as ``mode`` says:

    * ``"silent"`` (or ``answer=False``): says nothing, reads nothing;
    * ``"stall"`` (or ``answer=True``): sends an HTTP/2 SETTINGS frame (what the probe asks
      for), then reads nothing;
    * ``"garbage"``: sends bytes that are not HTTP/2;
    * ``"reset"``: resets the connection at once (SO_LINGER 0);
    * ``"settings-then-reset"``: answers, reads a little of the stream, then resets.

    ``url`` is its ``rerun+http`` URL; ``close()`` ends it (and its connections)."""

    def __init__(self, answer: bool | None = None, mode: str | None = None):
        self.mode = mode or ("stall" if answer else "silent")
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.conns: list[socket.socket] = []
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def _serve(self):
        while not self.stop.is_set():
            try:
                c, _ = self.sock.accept()
            except socket.timeout:
                continue
            except OSError:
                return
            self.conns.append(c)
            try:
                self._answer(c)
            except OSError:
                pass

    def _answer(self, c: socket.socket) -> None:
        if self.mode == "stall":
            c.sendall(SETTINGS)
        elif self.mode == "garbage":
            c.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n" + bytes(range(256)))
        elif self.mode == "reset":
            c.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            c.close()
        elif self.mode == "settings-then-reset":
            c.sendall(SETTINGS)
            c.settimeout(2.0)
            end = time.monotonic() + 2.0
            got = 0
            while got < 2000 and time.monotonic() < end:
                try:
                    piece = c.recv(65536)
                except socket.timeout:
                    break
                if not piece:
                    break
                got += len(piece)
            c.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
            c.close()

    @property
    def url(self) -> str:
        return f"rerun+http://127.0.0.1:{self.port}/proxy"

    def close(self):
        self.stop.set()
        self.thread.join(5)
        self.sock.close()
        for c in self.conns:
            try:
                c.close()
            except OSError:
                pass


def closed_port_url() -> str:
    """A ``rerun+http`` URL of a loopback port nothing listens on."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"rerun+http://127.0.0.1:{s.getsockname()[1]}/proxy"


# --------------------------------------------------------------------------------------
# processes a test started, and whether they are gone


def _live(procs) -> set[int]:
    import psutil

    out = set()
    for p in procs:
        try:
            if p.status() != psutil.STATUS_ZOMBIE:
                out.add(p.pid)
        except psutil.Error:  # gone meanwhile
            pass
    return out


def children(pid: int | None = None) -> set[int]:
    """Live (not zombie) processes whose parent is ``pid`` (this process by default)."""
    import psutil

    try:
        return _live(psutil.Process(pid).children())
    except psutil.NoSuchProcess:
        return set()


def descendants(pid: int | None = None) -> set[int]:
    """Live (not zombie) processes descended from ``pid`` (this process by default)."""
    import psutil

    try:
        return _live(psutil.Process(pid).children(recursive=True))
    except psutil.NoSuchProcess:
        return set()


def session_members(sid: int) -> set[int]:
    """Live processes of the session ``sid`` (a command started with start_new_session)."""
    import psutil

    members = []
    for p in psutil.process_iter():
        try:
            if os.getsid(p.pid) == sid:
                members.append(p)
        except OSError:  # gone meanwhile
            pass
    return _live(members)
