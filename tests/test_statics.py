"""Static equilibrium against closed forms and against the end of a long damped run; its
inputs checked where they enter."""

import math

import numpy as np
import pytest

from qchain import Chain, Segment
from qchain.arm import statics
from qchain.arm.statics import equilibrium
from qchain.sim.simulation import simulate
from support import CH1, refused

SEG = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5)
PHI = np.array([0.0, 2 * np.pi / 3, -2 * np.pi / 3])


@pytest.mark.parametrize("coords", ["curvature", "paper"])
def test_weightless_segment_under_pressure_matches_closed_form(coords):
    """With the volume model the energy balance dU_el/dq = B p solves in closed form:
    l = l0 (1 + A_ch sum p / EA), (ux, uy) = -(m_x, m_y) l0 / (EI l), m = A_ch r_ch sum p_i (cos, sin) phi_i."""
    seg = Segment(**SEG, coords=coords)
    ch = Chain([seg], gravity=np.zeros(3))
    for p in ([3e4, 1e4, 0.0], [0.0, 5e4, 2e4], [6e4, 6e4, 6e4]):
        p = np.array(p)
        q0 = None
        if coords == "paper":
            q0 = np.array([0.1, 2.0, 1.0])  # start off the straight (singular) pose
        res = equilibrium(ch, p, q0=q0, tol=1e-13)
        A, r, l0 = seg.chamber_area, seg.chamber_radius, seg.length
        l = l0 * (1 + A * p.sum() / seg.axial_stiffness)
        mx, my = A * r * (p @ np.cos(PHI)), A * r * (p @ np.sin(PHI))
        ux, uy = -mx * l0 / (seg.bending_stiffness * l), -my * l0 / (seg.bending_stiffness * l)
        if coords == "paper" and np.hypot(ux, uy) == 0:
            continue
        assert res.success, res.message
        q_c = seg.to_curvature(res.q)
        assert np.allclose(q_c, [l, ux, uy], rtol=1e-9, atol=1e-9)


def test_pure_end_moment_gives_an_exact_arc():
    """A weightless segment under a pure tip moment M about y bends into an arc of curvature
    M / EI at its rest length (docs/model.md sections 9 and 11, known answers)."""
    seg = Segment(**SEG)
    ch = Chain([seg], gravity=np.zeros(3))
    for M in (0.002, 0.01, -0.02):
        res = equilibrium(ch, tip_wrench=[0, 0, 0, 0, M, 0])
        assert res.success, res.message
        assert np.allclose(res.q, [seg.length, M / seg.bending_stiffness, 0.0], rtol=1e-9, atol=1e-9)
        pts = ch.backbone(res.q, 50)[0]
        centre = np.array([seg.bending_stiffness / M, 0.0, 0.0])
        assert np.allclose(np.linalg.norm(pts - centre, axis=1), abs(seg.bending_stiffness / M), rtol=1e-12)


@pytest.mark.slow
def test_hanging_arm_equilibrium_matches_the_end_of_a_damped_run():
    ch = Chain([Segment(**SEG, damping=0.2) for _ in range(3)], gravity=(0, 0, 9.81))  # hanging
    p = np.array([3e4, 0, 0, 0, 2e4, 0, 1e4, 1e4, 0])
    res = equilibrium(ch, p)
    assert res.success and res.iterations < 50
    tr = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0, 20), pressure=p, method="BDF", rtol=1e-10, atol=1e-12,
                  energies=False, t_eval=[20.0])
    assert tr.success
    tip_sim = ch.tip_placement(tr.q[-1]).translation
    tip_eq = ch.tip_placement(res.q).translation
    assert np.linalg.norm(tip_sim - tip_eq) < 1e-6  # m
    assert np.abs(tr.v[-1]).max() < 1e-4


def test_equilibrium_argument_errors():
    ch = Chain([Segment(**SEG)], base="floating")
    with pytest.raises(ValueError, match="fixed or prescribed base"):
        equilibrium(ch)
    ch = Chain([Segment(**SEG)])
    with pytest.raises(ValueError, match=r"p must have shape \(3,\)"):
        equilibrium(ch, [1.0])
    with pytest.raises(ValueError, match=r"tip_wrench must have shape \(6,\)"):
        equilibrium(ch, tip_wrench=[1.0, 2.0])


# --------------------------------------------------------------------------------------
# Bad input (issue 18): refused where it enters, naming the argument, the value and the bound;
# never a foreign traceback, a hang, a crash, a silent NaN or lost data.

def test_statics_checks_its_inputs_where_they_enter():
    refused(lambda: statics.equilibrium(CH1, None, [math.nan, 0, 0]), "q0")
    refused(lambda: statics.equilibrium(CH1, np.full(3, 1e300)), "p")
    refused(lambda: statics.equilibrium(CH1, None, None, np.full(6, 1e300)), "tip_wrench")
    refused(lambda: statics.equilibrium(CH1, continuation="no"), "continuation")
    refused(lambda: statics.equilibrium(CH1, None, [0.1, 1e3, 0]), "segment 0")
    assert statics.equilibrium(CH1, np.full(3, 1e4)).success
