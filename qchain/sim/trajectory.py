"""The result of a simulation or of reading a recording: a time-major trajectory."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

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
        Potential = gravity + elastic; maybe computed at their first use (:meth:`with_energies`).
    success : bool
        False when the run stopped early (domain exit, non-finite state, solver failure,
        interruption); the samples up to that point are kept.
    message : str
        Why the run ended.
    nfev : int
        Number of forward-dynamics evaluations.
    status : int
        0 finished, 1 stopped by an event, -1 failed.
    tension : (N, nt) N or None
        The tendons' tensions at the samples (a chain with tendons; docs/tendons.md), else None.
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
    tension: np.ndarray | None = None

    def with_energies(self, source: Callable[[], tuple[np.ndarray, np.ndarray]]) -> "Trajectory":
        """Compute ``kinetic_energy`` and ``potential_energy`` by ``source() -> (KE, PE)`` at
        their first use instead of now; returns ``self``."""
        self.__dict__["_energy_source"] = source
        self.__dict__["_kinetic_energy"] = self.__dict__["_potential_energy"] = None
        return self

    def _energy(self, name: str) -> np.ndarray:
        d = self.__dict__
        if d.get("_" + name) is None and d.get("_energy_source") is not None:
            d["_kinetic_energy"], d["_potential_energy"] = d.pop("_energy_source")()
        return d.get("_" + name)

    def __getstate__(self) -> dict:  # pickled with its energies (a deferred source is not picklable)
        self._energy("kinetic_energy")
        return {k: v for k, v in self.__dict__.items() if k != "_energy_source"}

    @property
    def total_energy(self) -> np.ndarray:
        """``kinetic_energy + potential_energy`` (N,) J."""
        return self.kinetic_energy + self.potential_energy

    def __len__(self) -> int:
        return int(np.shape(self.t)[0])


# the energies as properties over the dataclass fields (the generated __init__ assigns them
# through the setters), so that a run can defer them (Trajectory.with_energies)
for _name in ("kinetic_energy", "potential_energy"):
    def _get(self, _n=_name):
        return self._energy(_n)

    def _set(self, value, _n=_name):
        self.__dict__.pop("_energy_source", None)
        self.__dict__["_" + _n] = value

    setattr(Trajectory, _name, property(_get, _set, doc=f"({_name.split('_')[0]} energy, (N,) J)"))
del _name, _get, _set
