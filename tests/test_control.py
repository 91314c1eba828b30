"""qchain.control: the controllers' input checks and the pressure allocation's bounds."""

import numpy as np
import pytest

from qchain import Chain, Segment
from qchain.control import PDCompensation, SlotineLi, allocate


def _chain():
    seg = Segment(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085,
                  youngs_modulus=1e5, damping=0.02, extensible=False)
    return Chain([seg, seg], gravity=(0.0, 0.0, -9.81))


@pytest.mark.parametrize("kw, words", [
    ({"rate": 0.0}, "rate must be > 0"),
    ({"rate": -5.0}, "rate must be > 0"),
    ({"p_min": 1e5, "p_max": 5e4}, "p_max must be > p_min = 100000 Pa, got 50000 Pa"),
    ({"p_min": -2e5}, "p_min must be >= -101325"),
    ({"rate": float("nan")}, "rate must be finite"),
])
def test_bad_settings_are_refused_naming_the_parameter(kw, words):
    ch = _chain()
    args = {"rate": 500.0, "p_max": 1e5} | kw
    with pytest.raises(ValueError, match=words):
        PDCompensation(ch, ch.neutral(), Kp=1e-3, Kd=1e-4, **args)


def test_a_reference_of_the_wrong_shape_or_with_nan_is_refused():
    ch = _chain()
    with pytest.raises(ValueError, match=r"q_d must have shape \(6,\)"):
        SlotineLi(ch, np.zeros(5), K=1e-4, Lambda=10.0, rate=500.0, p_max=1e5)
    with pytest.raises(ValueError, match="q_d has non-finite entries"):
        SlotineLi(ch, np.full(6, np.nan), K=1e-4, Lambda=10.0, rate=500.0, p_max=1e5)
    with pytest.raises(ValueError, match=r"Lambda\[0\] must be a number > 0"):
        SlotineLi(ch, ch.neutral(), K=1e-4, Lambda=-1.0, rate=500.0, p_max=1e5)


def test_the_allocation_stays_within_bounds_and_realises_a_reachable_force():
    rng = np.random.default_rng(0)
    B = rng.normal(size=(4, 6))
    p_true = rng.uniform(0.0, 1.0, 6)
    a = allocate(B, B @ p_true, 0.0, 1.0, 1e-6)
    assert np.all(a.p >= 0.0) and np.all(a.p <= 1.0)
    assert a.residual < 1e-4 and not a.saturated
    far = allocate(B, 100.0 * B @ p_true, 0.0, 1.0, 1e-6)  # 100 times what the bounds allow
    assert np.all(far.p <= 1.0) and far.saturated and far.at_upper > 0
