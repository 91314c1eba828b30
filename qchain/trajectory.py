"""The result of a simulation or of reading a recording: a time-major trajectory."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Trajectory"]


@dataclass
class Trajectory:
    """A run, time-major, in the manner of scipy's ``OdeResult``.

    Attributes
    ----------
    t : (N,) s
        Sample times, increasing.
    q : (N, nq)
        Configurations (the chain's layout; floating base first as
        ``(x, y, z, qx, qy, qz, qw)``).
    v : (N, nv)
        Velocities.
    p : (N, 3 n) Pa
        Chamber pressures, segment by segment, chambers 1..3.
    kinetic_energy, potential_energy : (N,) J
        Potential = gravity + elastic.
    success : bool
        False when the run stopped early (domain exit, non-finite state, solver failure,
        interruption); the samples up to that point are kept.
    message : str
        Why the run ended.
    nfev : int
        Number of forward-dynamics evaluations.
    status : int
        0 finished, 1 stopped by an event, -1 failed.
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    p: np.ndarray
    kinetic_energy: np.ndarray
    potential_energy: np.ndarray
    success: bool = True
    message: str = ""
    nfev: int = 0
    status: int = 0
    meta: dict = field(default_factory=dict)

    @property
    def total_energy(self) -> np.ndarray:
        """``kinetic_energy + potential_energy`` (N,) J."""
        return self.kinetic_energy + self.potential_energy

    def __len__(self) -> int:
        return int(np.shape(self.t)[0])
