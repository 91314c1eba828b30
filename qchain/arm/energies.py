"""The energies and momentum of a :class:`qchain.arm.chain.Chain` (:class:`ChainEnergies`, a base
class of ``Chain``): the paper's kinetic energy, eq. (4), summed over the segments, gravity and
elasticity (docs/model.md sections 3, 8 and 9), the world momentum."""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..model.arc import arc_nodes
from ..model.slices import segment_mass
from .checks import _finite
from .kinematics import _NO_POINTS

__all__ = ["ChainEnergies"]


class ChainEnergies:
    """The energy and momentum methods of :class:`~qchain.arm.chain.Chain`."""


    def _segment_masses_c(self, st) -> np.ndarray:
        M = np.empty((self.n, 9, 9))
        for j in range(self.n):
            o = slice(self._offs[j], self._offs[j + 1])
            segment_mass(self._alpha[o], self._w[o], self._mass[j], self._radius[j], st.q_c[j], M[j])
        return M

    @_finite("kinetic energy", has_v=True)
    def kinetic_energy(self, q, v, t: float = 0.0) -> float:
        """``T = sum_j 1/2 xi_j^T M_xi_j xi_j + 1/2 V_n^T I_p V_n`` (J), the base's own motion
        included (the paper's eq. (4) summed over the segments; docs/model.md section 8), and
        the tip payload's (spatial inertia ``I_p``, tip twist ``V_n``)."""
        st = self._state(q, v, t=t)
        V = self._root_twists(st)
        M = self._segment_masses_c(st)
        xi = np.concatenate([V[:-1], st.v_c], axis=1)
        return 0.5 * float(np.einsum("ni,nij,nj->", xi, M, xi)) + 0.5 * float(V[-1] @ self._payload @ V[-1])

    @_finite("centres of mass")
    def centers_of_mass(self, q, t: float = 0.0) -> np.ndarray:
        """World centre of mass of each segment (n, 3), m (the tip payload's is not among
        them: it is ``tip_placement(q).act(payload.lever)``)."""
        return self._centers_of_mass(self._state(q, t=t))

    def _centers_of_mass(self, st) -> np.ndarray:
        f = self._state_frames(st, _NO_POINTS)
        R, o = f.rotation[0], f.translation[0]
        p = arc_nodes(self._alpha, np.repeat(st.q_c, np.diff(self._offs), axis=0)).p
        c = np.add.reduceat(self._w[:, None] * p, self._offs[:-1], axis=0)  # root frames
        return np.einsum("nij,nj->ni", R[:-1], c) + o[:-1]

    @_finite("potential energy")
    def potential_energy(self, q, t: float = 0.0) -> float:
        """Gravity (about the world origin; the tip payload's included) plus elastic energy (J)
        (docs/model.md section 9)."""
        st = self._state(q, t=t)
        Ug = -float(self._mass @ (self._centers_of_mass(st) @ self.gravity))
        if self._has_payload:
            P = self._payload_inertia
            f = self._state_frames(st, _NO_POINTS)
            Ug -= P.mass * float((f.rotation[0, -1] @ P.lever + f.translation[0, -1]) @ self.gravity)
        Ue = sum(s.elastic_energy(st.q_e[j]) for j, s in enumerate(self.segments))
        return Ug + Ue

    @_finite("momentum", has_v=True)
    def momentum(self, q, v, t: float = 0.0) -> np.ndarray:
        """World momentum (6,): linear (kg m/s) and angular about the world origin (kg m^2/s),
        the tip payload's included."""
        st = self._state(q, v, t=t)
        V = self._root_twists(st)
        M = self._segment_masses_c(st)
        X = self.placements(q, t)
        h = np.zeros(6)
        for j in range(self.n):
            xi = np.concatenate([V[j], st.v_c[j]])
            h += X[j].act(pin.Force(M[j, :6] @ xi)).vector
        return h + X[self.n].act(pin.Force(self._payload @ V[self.n])).vector
