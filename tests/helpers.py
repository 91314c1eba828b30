"""Shared test parameters and assertions (not fixtures)."""

import contextlib
import faulthandler
import signal

import numpy as np

SEGMENT_KW = dict(
    length=0.2,
    radius=0.02,
    mass=0.3,
    chamber_area=2e-5,
    chamber_radius=0.01,
    youngs_modulus=1e5,
)


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
