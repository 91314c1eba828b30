"""The coefficients of the compiled methods, as numbers (no import of scipy.integrate at run
time: it costs about 0.2 s of a process's start).

They are scipy's own (``scipy.integrate.RK45`` and ``scipy.integrate._ivp.radau``, which
follow Dormand and Prince 1980 and Hairer and Wanner, *Solving ODEs II*, section IV.8):
``tests/test_engine_blocks.py`` checks every number against scipy's arrays, bit for bit.
"""

from __future__ import annotations

import numpy as np

__all__ = ["DOPRI5_A", "DOPRI5_C", "DOPRI5_E", "DOPRI5_P", "RADAU_C", "RADAU_E", "RADAU_T", "RADAU_TI", "RADAU_P",
           "RADAU_MU"]

#: Dormand-Prince 5(4): stage coefficients, rows 0-5 ``RK45.A`` and row 6 the weights ``RK45.B``
DOPRI5_A = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [0.075, 0.225, 0.0, 0.0, 0.0, 0.0, 0.0],
    [0.9777777777777777, -3.7333333333333334, 3.5555555555555554, 0.0, 0.0, 0.0, 0.0],
    [2.9525986892242035, -11.595793324188385, 9.822892851699436, -0.2908093278463649, 0.0, 0.0, 0.0],
    [2.8462752525252526, -10.757575757575758, 8.906422717743473, 0.2784090909090909, -0.2735313036020583, 0.0, 0.0],
    [0.09114583333333333, 0.0, 0.44923629829290207, 0.6510416666666666, -0.322376179245283, 0.13095238095238096, 0.0],
])
#: stage times ``RK45.C`` and 1 (the first-same-as-last stage)
DOPRI5_C = np.array([0.0, 0.2, 0.3, 0.8, 0.8888888888888888, 1.0, 1.0])
#: error weights ``RK45.E``
DOPRI5_E = np.array([-0.0012326388888888888, 0.0, 0.0042527702905061394, -0.03697916666666667, 0.05086379716981132, -0.0419047619047619, 0.025])
#: 4th-order dense output ``RK45.P`` (7, 4)
DOPRI5_P = np.array([
    [1.0, -2.8535800653862835, 3.0717434641059005, -1.1270175653862835],
    [0.0, 0.0, 0.0, 0.0],
    [0.0, 4.023133379230305, -6.249321565289, 2.675424484351598],
    [0.0, -3.7324019615885042, 10.068970589843675, -5.685526961588504],
    [0.0, 2.5548038301849423, -6.399112377351017, 3.5219323679207912],
    [0.0, -1.3744241142186024, 3.272657752246729, -1.7672812570757455],
    [0.0, 1.3824689317781436, -3.764937863556287, 2.382468931778144],
])

#: Radau IIA order 5: collocation nodes ``C``
RADAU_C = np.array([0.15505102572168222, 0.6449489742783178, 1.0])
#: error estimate weights ``E``
RADAU_E = np.array([-10.048809399827414, 1.382142733160748, -0.3333333333333333])
#: ``T`` and ``TI = T^-1``, which block-diagonalise the method's matrix (real and complex parts)
RADAU_T = np.array([
    [0.09443876248897524, -0.1412552950209542, 0.03002919410514742],
    [0.2502131229653333, 0.20412935229379994, -0.3829421127572619],
    [1.0, 1.0, 0.0],
])
RADAU_TI = np.array([
    [4.178718591551904, 0.32768282076106237, 0.5233764454994495],
    [-4.178718591551904, -0.32768282076106237, 0.47662355450055044],
    [0.5028726349457868, -2.571926949855605, 0.5960392048282249],
])
#: the collocation polynomial's dense output ``P``
RADAU_P = np.array([
    [10.048809399827414, -25.62959144707664, 15.580782047249224],
    [-1.382142733160748, 10.296258113743303, -8.914115380582556],
    [0.3333333333333333, -2.6666666666666665, 3.3333333333333335],
])
#: ``(MU_REAL, MU_COMPLEX.real, MU_COMPLEX.imag)``
RADAU_MU = np.array([3.637834252744496, 2.6810828736277523, -3.050430199247411])
