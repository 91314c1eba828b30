"""Known answers (docs/model.md section 11, rung 5): the n-segment static cantilever converges to
the Euler elastica (a Cosserat rod without shear and extension) at second order in 1/n.
The pure-end-moment arc is in tests/test_statics.py."""

import math
from decimal import Decimal

import numpy as np
import pinocchio as pin

from qchain import Chain, Segment
from qchain.arm.statics import equilibrium
from qchain.reference import elastica_cantilever
from support import RaisingFloat, refused

L, R, E, RHO = 0.3, 0.01, 5e6, 1100.0  # m, m, Pa, kg/m^3


def cantilever(n):
    A = np.pi * R * R
    segs = [Segment(length=L / n, radius=R, mass=RHO * A * L / n, chamber_area=1e-6, chamber_radius=0.005,
                    youngs_modulus=E, extensible=False) for _ in range(n)]
    X = pin.SE3(pin.utils.rotate("y", np.pi / 2), np.zeros(3))  # backbone along world +x
    return Chain(segs, base_placement=X, planar=True)


def test_static_cantilever_converges_to_the_elastica_at_second_order():
    A = np.pi * R * R
    ref = elastica_cantilever(L, E * np.pi * R**4 / 4, RHO * A * 9.81)
    assert ref.tip[1] < -0.25 * L  # a large deflection (27 % of L), not the linear regime
    errs = []
    for n in (2, 4, 8, 16):
        ch = cantilever(n)
        res = equilibrium(ch, tol=1e-12)
        assert res.success, res.message
        tip = ch.tip_placement(res.q).translation
        assert abs(tip[1]) < 1e-12  # planar
        errs.append(np.hypot(tip[0] - ref.tip[0], tip[2] - ref.tip[1]))
    rates = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    # measured: 6.6e-3, 1.6e-3, 4.1e-4, 1.0e-4 m; rates 2.01, 2.00, 2.00
    assert np.all((rates > 1.9) & (rates < 2.1)), (errs, rates)
    assert errs[-1] < 2e-4


# --------------------------------------------------------------------------------------
# Bad input (issue 18): refused where it enters, naming the argument, the value and the bound;
# never a foreign traceback, a hang, a crash, a silent NaN or lost data.

def test_the_elastica_reference_checks_its_parameters():
    for v in (True, "1", Decimal("1"), RaisingFloat(), 0.0, -1.0, math.nan, 10**400):
        refused(lambda v=v: elastica_cantilever(v, 1.0, 1.0), "length")
        refused(lambda v=v: elastica_cantilever(1.0, v, 1.0), "EI")
    refused(lambda: elastica_cantilever(1.0, 1.0, math.inf), "weight_per_length")
    assert abs(elastica_cantilever(1.0, 1.0, 1.0).tip[0] - 0.9912) < 1e-3
