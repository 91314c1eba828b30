"""An independent reference for tendon-driven arms: the Cosserat rod with Rucker and Webster's
tendon model, solved by shooting with scipy.

The rod (Rucker and Webster, "Statics and dynamics of continuum robots with general tendon
routing and external loading", IEEE T-RO 27(6), 2011; in the form of Till, Aloi and Rucker,
"Real-time dynamics of soft and continuum robots based on Cosserat rod models", IJRR 38(6),
2019) is clamped at the origin along +z. Its state along the reference arclength ``s`` is the
position ``p``, the orientation ``R``, the shear/stretch ``v`` and the curvature/twist ``u``
(body frame, ``p' = R v``, ``R' = R [u]x``), with the linear law ``n_b = K_se (v - e_z)``,
``m_b = K_bt u``, ``K_se = diag(GA, GA, EA)``, ``K_bt = diag(EI, EI, GJ)``: shear, extension,
bending and torsion all included. Each straight tendon ``i`` runs at the fixed body-frame
offset ``r_i`` (spacer disks), frictionless, tension ``T_i``, and ends at the tip plate. Its
path's tangent ``p_i' = R (u x r_i + v)`` curves with the rod, so it presses on the backbone
with the distributed load of its path's curvature; written out, the balance of the backbone's
force and moment is linear in ``(v', u')``:

    [K_se + A,  G      ] [v']   [-u x n_b - R^T f - a           ]
    [G^T,       K_bt + H] [u'] = [-u x m_b - v x n_b - b        ]

with, for each tendon, ``t_i = u x r_i + v``, ``A_i = -T_i [t_i]x^2 / |t_i|^3``,
``G_i = -A_i [r_i]x``, ``a_i = A_i (u x t_i)`` and ``A = sum A_i``, ``G = sum G_i``,
``H = sum [r_i]x G_i``, ``a = sum a_i``, ``b = sum r_i x a_i``; ``f`` the distributed
external force (gravity ``rho A g``). At the tip, the backbone carries the tendons' pull on the
plate: ``n_b(L) = sum F_i``, ``m_b(L) = sum r_i x F_i``, ``F_i = -T_i t_i / |t_i|``. The
unknown base force and curvature ``(n_b(0), u(0))`` are found by ``scipy.optimize.root`` on the
tip residual, each guess integrated by ``solve_ivp`` (DOP853).

Written from the papers' equations, not from any code: it shares nothing with qchain.
"""

import numpy as np
from scipy.integrate import solve_ivp
from scipy.optimize import root


def _hat(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


class TendonRod:
    """A clamped Cosserat rod with straight tendons ending at its tip.

    Parameters
    ----------
    length : float
        Reference length ``L`` (m).
    radius : float
        Radius of the solid circular section (m): ``A = pi r^2``, ``I = pi r^4 / 4``, ``J = 2 I``.
    youngs_modulus, shear_modulus : float
        ``E``, ``G`` (Pa).
    density : float
        ``rho`` (kg/m^3).
    gravity : (3,) array
        ``g`` in the base frame (m/s^2).
    offsets : (nt, 3) array
        Each tendon's body-frame offset ``r_i`` from the backbone (m), ``r_i . e_z = 0``.
    """

    def __init__(self, length, radius, youngs_modulus, shear_modulus, density, gravity, offsets):
        self.L = float(length)
        area = np.pi * radius ** 2
        inertia = np.pi * radius ** 4 / 4.0
        self.Kse = np.diag([shear_modulus * area, shear_modulus * area, youngs_modulus * area])
        self.Kbt = np.diag([youngs_modulus * inertia, youngs_modulus * inertia, shear_modulus * 2 * inertia])
        self.f = density * area * np.asarray(gravity, float)  # N/m, base frame
        self.r = np.asarray(offsets, float)

    def _rhs(self, s, y, T):
        R = y[3:12].reshape(3, 3)
        v, u = y[12:15], y[15:18]
        nb = self.Kse @ (v - np.array([0.0, 0.0, 1.0]))
        mb = self.Kbt @ u
        A, G, H = np.zeros((3, 3)), np.zeros((3, 3)), np.zeros((3, 3))
        a, b = np.zeros(3), np.zeros(3)
        for ri, Ti in zip(self.r, T):
            t = np.cross(u, ri) + v
            nt = np.linalg.norm(t)
            Ai = -Ti * _hat(t) @ _hat(t) / nt ** 3
            Gi = -Ai @ _hat(ri)
            ai = Ai @ np.cross(u, t)
            A += Ai
            G += Gi
            H += _hat(ri) @ Gi
            a += ai
            b += np.cross(ri, ai)
        K = np.block([[self.Kse + A, G], [G.T, self.Kbt + H]])
        rhs = np.concatenate([-np.cross(u, nb) - R.T @ self.f - a, -np.cross(u, mb) - np.cross(v, nb) - b])
        return np.concatenate([R @ v, (R @ _hat(u)).ravel(), np.linalg.solve(K, rhs)])

    def _integrate(self, x, T, s_eval=None):
        v0 = np.linalg.solve(self.Kse, x[:3]) + np.array([0.0, 0.0, 1.0])
        y0 = np.concatenate([np.zeros(3), np.eye(3).ravel(), v0, x[3:]])
        return solve_ivp(self._rhs, (0.0, self.L), y0, method="DOP853", rtol=1e-11, atol=1e-13,
                         t_eval=s_eval, args=(T,))

    def _residual(self, x, T):
        y = self._integrate(x, T).y[:, -1]
        v, u = y[12:15], y[15:18]
        force = -self.Kse @ (v - np.array([0.0, 0.0, 1.0]))
        moment = -self.Kbt @ u
        for ri, Ti in zip(self.r, T):
            t = np.cross(u, ri) + v
            Fi = -Ti * t / np.linalg.norm(t)
            force += Fi
            moment += np.cross(ri, Fi)
        # scaled so both halves are of the order of the tendons' force and moment
        return np.concatenate([force, moment / np.abs(self.r).max()])

    def solve(self, tension, s_eval=None, guess=None):
        """The static shape under the tensions ``tension`` (nt,) N.

        Returns ``(s, p)``: the reference arclengths (m) and the backbone points ``p`` (len(s), 3)
        m, base frame; ``s_eval`` None gives the base and the tip. Raises ``RuntimeError`` if
        the shooting does not converge."""
        T = np.asarray(tension, float)
        if guess is None:  # the straight-tendon moment at the base, the tensions in compression
            m = sum(Ti * np.cross(ri, [0.0, 0.0, -1.0]) for ri, Ti in zip(self.r, T))
            guess = np.concatenate([[0.0, 0.0, -T.sum()], np.linalg.solve(self.Kbt, -m)])
        sol = root(self._residual, guess, args=(T,), method="hybr", options=dict(xtol=1e-13))
        if not sol.success:
            raise RuntimeError(f"shooting did not converge: {sol.message}")
        s_eval = np.array([0.0, self.L]) if s_eval is None else np.asarray(s_eval, float)
        out = self._integrate(sol.x, T, s_eval)
        self.x0 = sol.x
        return out.t, out.y[:3].T
