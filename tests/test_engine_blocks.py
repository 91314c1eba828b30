"""Compiled engine building blocks: packed schedules and base motions against their Python
``__call__``, and the free-flyer Lie algebra against Pinocchio."""

import re

import numpy as np
import pinocchio as pin
import pytest

from qchain.sim.engine.lie import dexp_inv, dexp_inv_apply, ff_difference, ff_integrate
from qchain.sim.engine.schedules import (
    CONSTANT, ROTATION, SINE, TABLE, TRANSLATION, base_motion_eval, input_eval, pack_base_motion, pack_input,
    pack_inputs, values_at)
from qchain.sim.inputs import Constant, Ramp, Schedule, Sine, Step, Table, as_input
from qchain.scene.scene import SineMotion

ANGLES = (0.0, 1e-9, 1e-4, 1.0, 3.0)  # |w| (rad) of the tangents checked against Pinocchio


def _eval(packed, t):
    ints, params = packed
    out = np.full(ints[1], np.nan)
    input_eval(ints, params, t, out)
    return out


def _around(*knots):
    """The knots and their float neighbours."""
    return [x for k in knots for x in (np.nextafter(k, -np.inf), k, np.nextafter(k, np.inf))]


def _check_exact(u, times):
    packed = pack_input(u, u.size)
    assert packed[0].dtype == np.int64 and packed[1].dtype == np.float64
    for t in times:
        got, ref = _eval(packed, t), u(t)
        assert np.array_equal(got, ref), (t, got, ref)


# ------------------------------------------------------------------ schedules


def test_none_and_constants():
    assert np.array_equal(_eval(pack_input(None, 4), 1.5), np.zeros(4))
    c = np.array([1.0, -2.5, 3e5])
    ints, _ = packed = pack_input(c, 3)
    assert ints[0] == CONSTANT and np.array_equal(_eval(packed, 7.0), c)
    _check_exact(Constant(c), [-1.0, 0.0, 2.0])


def test_step(rng):
    for before in (None, [-1.0, 2.0]):
        u = Step(0.3, [5.0, 7.0], before)
        _check_exact(u, _around(0.3) + list(rng.uniform(-1, 1, 50)) + [-1e12, 1e12])  # (a schedule's times:
        # within +-1e12 s, qchain.checks.bounds.TIME)


def test_ramp(rng):
    u = Ramp(0.1, 0.7, [1.0, -3.0, 1e5], start=[0.2, 0.0, -1e5])
    _check_exact(u, _around(0.1, 0.7) + list(rng.uniform(-0.5, 1.5, 200)))
    _check_exact(Ramp(-2.0, 1e-3, [4.0]), _around(-2.0, 1e-3) + list(rng.uniform(-3, 1, 50)))


def test_table(rng):
    times = np.array([-0.5, 0.0, 0.2, 0.25, 1.0])
    u = Table(times, rng.normal(size=(5, 3)))
    ts = _around(*times) + list(rng.uniform(-2, 2, 300)) + [-1e9, 1e9, -1e12, 1e12]
    _check_exact(u, ts)
    ints, params = pack_input(u, 3)
    assert ints.tolist() == [TABLE, 3, 5] and params.size == 5 + 15
    _check_exact(Table([0.5], [[1.0, 2.0]]), [-1.0, 0.5, 2.0])  # one row: constant
    _check_exact(Table([0.0, 1.0], [[0.0], [1.0]]), _around(0.0, 1.0) + [0.3, 0.7])


def test_sine(rng):
    u = Sine(rng.uniform(-1e5, 1e5, 4), [0.0, 0.5, 3.0, 40.0], phase=rng.uniform(-3, 3, 4),
             offset=[0.0, 1e5, -2.0, 3.0])
    packed = pack_input(u, 4)
    assert packed[0][0] == SINE
    scale = np.abs(u.offset) + np.abs(u.amplitude)
    for t in [0.0, 1e-3, 0.25] + list(rng.uniform(-10, 10, 300)):
        assert np.all(np.abs(_eval(packed, t) - u(t)) <= 1e-15 * scale), t
    _check_exact(Sine([2.0], [1.0]), [0.0])  # sin(0) = 0 on both sides


def _messages(u, size):
    with pytest.raises(ValueError) as ref:
        as_input("pressure", u, size)
    with pytest.raises(ValueError) as got:
        pack_input(u, size, "pressure")
    assert str(got.value) == str(ref.value)
    return str(got.value)


def test_sizes_and_messages():
    for u in (Constant([1.0, 2.0]), Step(0.0, [1.0, 2.0]), Ramp(0, 1, [1.0, 2.0]), Sine([1.0, 2.0], 1.0),
              Table([0.0, 1.0], np.zeros((2, 2)))):
        assert _messages(u, 3) == "pressure schedule gives 2 values, the model needs 3"
    assert re.search(r"must have shape \(3,\), got shape \(2,\)", _messages([1.0, 2.0], 3))
    assert "non-finite" in _messages([1.0, np.nan, 2.0], 3)
    assert "got shape ()" in _messages(1.0, 1)
    assert pack_input([1.0, 2.0], 2, "pressure")[1].tolist() == [1.0, 2.0]


class _Doubled(Schedule):
    size = 2

    def __call__(self, t):
        return np.full(2, 2.0 * t)


class _LateStep(Step):
    def __call__(self, t):
        return super().__call__(t - 1.0)


def test_what_compiled_code_cannot_evaluate():
    assert pack_input(lambda t, q, v: np.zeros(2), 2) is None
    assert pack_input(lambda t: np.zeros(2), 2) is None
    assert pack_input(_Doubled(), 2) is None
    assert pack_input(_LateStep(0.0, [1.0]), 1) is None  # a subclass may change __call__
    assert pack_input(_Doubled(), 3) is None  # a user's schedule is evaluated in Python, where it is checked:
    with pytest.raises(ValueError, match="pressure schedule gives 2 values, the model needs 3"):
        as_input("pressure", _Doubled(), 3)


def test_a_batch_of_inputs_packs_to_each_ones_rows_and_is_valued_as_each(rng):
    """pack_inputs gives the rows pack_input gives each entry (zero-padded), bit for bit, for a
    batch of one fixed-layout kind (packed at once), of constant arrays and of mixed kinds, and
    values_at each entry's value; what cannot be packed is None, and errors name the entry."""
    m, B = 3, 4

    def sine():
        return Sine(rng.normal(size=m), rng.uniform(0.0, 5.0, size=m), rng.normal(size=m), rng.normal(size=m))

    batches = [[Constant(rng.normal(size=m)) for _ in range(B)],
               [Step(rng.uniform(), rng.normal(size=m), rng.normal(size=m)) for _ in range(B)],
               [Ramp(0.1, 0.2 + rng.uniform(), rng.normal(size=m), rng.normal(size=m)) for _ in range(B)],
               [sine() for _ in range(B)],
               [rng.normal(size=m) for _ in range(B)],
               [sine(), None, rng.normal(size=m), Table(np.array([0.0, 0.5, 1.0]), rng.normal(size=(3, m))),
                Step(0.3, rng.normal(size=m))]]
    for us in batches:
        ints, params = pack_inputs(us, m, "pressure")
        assert ints.dtype == np.int64 and params.dtype == np.float64 and ints.shape[0] == params.shape[0] == len(us)
        for i, u in enumerate(us):
            ri, rp = pack_input(u, m)
            assert np.array_equal(ints[i, :ri.size], ri) and not ints[i, ri.size:].any()
            assert np.array_equal(params[i, :rp.size], rp) and not params[i, rp.size:].any()
        for t in (0.0, 0.37, 2.5):
            ref = np.array([np.zeros(m) if u is None else u if isinstance(u, np.ndarray) else u(t) for u in us])
            assert np.array_equal(values_at(us, t, m), ref)
            for i, u in enumerate(us):  # (a sine: libm's sin against numpy's, the last bit)
                tol = 1e-15 * (np.abs(u.offset) + np.abs(u.amplitude)) if type(u) is Sine else 0.0
                assert np.all(np.abs(_eval((ints[i], params[i]), t) - ref[i]) <= tol)
    assert pack_inputs([Sine(np.ones(2), 1.0), _Doubled()], 2) is None
    with pytest.raises(ValueError, match=r"pressure\[1\] schedule gives 2 values, the model needs 3"):
        pack_inputs([Sine(np.ones(3), 1.0), Sine(np.ones(2), 1.0)], 3, "pressure")
    with pytest.raises(ValueError, match=r"pressure\[1\].*non-finite"):
        pack_inputs([np.ones(3), np.array([1.0, np.nan, 2.0])], 3, "pressure")


# ------------------------------------------------------------------ base motion


def _random_se3(rng):
    return pin.SE3(pin.exp3(rng.normal(size=3)), rng.normal(size=3))


@pytest.mark.parametrize("kind", ["translation", "rotation"])
@pytest.mark.parametrize("amplitude", [0.3, 1e-6, -2.0])
def test_sine_motion(rng, kind, amplitude):
    axis = rng.normal(size=3)
    for freq in (0.0, 2.5):
        motion = SineMotion(kind=kind, axis=axis / np.linalg.norm(axis), amplitude=amplitude, frequency=freq,
                            phase=0.7, mount=_random_se3(rng))
        ints, params = pack_base_motion(motion)
        assert ints.tolist() == [TRANSLATION if kind == "translation" else ROTATION] and params.shape == (18,)
        R, p, V, A = np.empty((3, 3)), np.empty(3), np.empty(6), np.empty(6)
        for t in [0.0, 0.1] + list(rng.uniform(-3, 3, 40)):
            base_motion_eval(ints, params, t, R, p, V, A)
            X, V_ref, A_ref = motion(t)
            for got, ref in ((R, X.rotation), (p, X.translation), (V, V_ref), (A, A_ref)):
                np.testing.assert_allclose(got, ref, rtol=0, atol=1e-14 * max(1.0, np.abs(ref).max()))


def test_base_motion_fallbacks():
    assert pack_base_motion(lambda t: (pin.SE3.Identity(), np.zeros(6), np.zeros(6))) is None
    bad = SineMotion(kind="twist", axis=np.array([0.0, 0.0, 1.0]), amplitude=1.0, frequency=1.0, phase=0.0,
                     mount=pin.SE3.Identity())
    with pytest.raises(ValueError, match="'translation' or 'rotation'"):
        pack_base_motion(bad)


# ------------------------------------------------------------------ free-flyer Lie group


@pytest.fixture(scope="module")
def ff_model():
    m = pin.Model()
    m.addJoint(0, pin.JointModelFreeFlyer(), pin.SE3.Identity(), "base")
    return m


def _random_q(rng):
    quat = rng.normal(size=4)
    return np.concatenate([rng.normal(size=3), quat / np.linalg.norm(quat)])


def _tangents(rng, angles=ANGLES, per_angle=12):
    for angle in angles:
        for _ in range(per_angle):
            d = rng.normal(size=6)
            d[3:] *= angle / np.linalg.norm(d[3:])
            yield d


def test_integrate(rng, ff_model):
    out = np.empty(7)
    for d in _tangents(rng, ANGLES + (4.0, 6.0)):  # beyond pi Pinocchio flips the hemisphere
        q = _random_q(rng)
        ff_integrate(q, d, out)
        np.testing.assert_allclose(out, pin.integrate(ff_model, q, d), rtol=0, atol=1e-12)
        assert abs(np.linalg.norm(out[3:]) - 1.0) < 1e-15
    q = _random_q(rng)
    ff_integrate(q, np.zeros(6), out)
    assert np.array_equal(out[:3], q[:3]) and np.allclose(out[3:], q[3:], rtol=0, atol=2e-16)


def test_integrate_in_place(rng):
    q, d, out = _random_q(rng), rng.normal(size=6), np.empty(7)
    ff_integrate(q, d, out)
    ff_integrate(q, d, q)
    assert np.array_equal(q, out)


def test_difference(rng, ff_model):
    out, back = np.empty(6), np.empty(7)
    for d in _tangents(rng, ANGLES + (np.pi - 1e-6,)):
        q0 = _random_q(rng)
        q1 = pin.integrate(ff_model, q0, d)
        ff_difference(q0, q1, out)
        np.testing.assert_allclose(out, pin.difference(ff_model, q0, q1), rtol=0, atol=1e-12)
        ff_integrate(q0, out, back)
        np.testing.assert_allclose(back[:3], q1[:3], rtol=0, atol=1e-12)
        np.testing.assert_allclose(back[3:] * np.sign(back[3:] @ q1[3:]), q1[3:], rtol=0, atol=1e-12)
    for _ in range(20):  # unrelated configurations, either hemisphere
        q0, q1 = _random_q(rng), _random_q(rng)
        ff_difference(q0, q1, out)
        np.testing.assert_allclose(out, pin.difference(ff_model, q0, q1), rtol=0, atol=1e-12)
    ff_difference(q0, q0, out)
    assert np.array_equal(out, np.zeros(6))


def _ad(d):
    A = np.zeros((6, 6))
    A[:3, :3] = A[3:, 3:] = pin.skew(d[3:])
    A[:3, 3:] = pin.skew(d[:3])
    return A


def _jexp6_series(d, terms=60):
    """``Jexp6(d) = sum_n (-ad d)^n / (n + 1)!``: an independent reference that stays
    accurate at small ``|w|``."""
    term, J = np.eye(6), np.eye(6)
    for n in range(1, terms):
        term = term @ -_ad(d) / (n + 1)
        J += term
    return J


def test_dexp_inv_against_pinocchio(rng):
    out, Id = np.empty((6, 6)), np.eye(6)
    for d in _tangents(rng):
        J = pin.Jexp6(pin.Motion(d))
        dexp_inv(d, out)
        np.testing.assert_allclose(out, np.linalg.inv(J), rtol=0, atol=1e-12)
        np.testing.assert_allclose(out @ J, Id, rtol=0, atol=1e-12)
    dexp_inv(np.zeros(6), out)
    assert np.array_equal(out, Id)


def test_dexp_inv_small_angles(rng):
    # Pinocchio's Jexp6 loses up to ~5e-8 between |w| = 1e-4 and 1e-1 (closed forms with
    # 1/|w|^4 cancellation); the series reference does not
    out = np.empty((6, 6))
    for d in _tangents(rng, (1e-6, 1e-4, 1e-3, 1e-2, 0.5, 0.999, 1.001, 2.0), per_angle=6):
        dexp_inv(d, out)
        np.testing.assert_allclose(out @ _jexp6_series(d), np.eye(6), rtol=0, atol=1e-13)


def test_dexp_inv_apply(rng):
    M, out = np.empty((6, 6)), np.empty(6)
    for d in _tangents(rng, ANGLES + (5.0,), per_angle=4):
        u = rng.normal(size=6)
        dexp_inv(d, M)
        dexp_inv_apply(d, u, out)
        np.testing.assert_allclose(out, M @ u, rtol=0, atol=1e-13 * max(1.0, np.abs(M).max()))
        dexp_inv_apply(d, u, u)  # in place
        assert np.array_equal(u, out)


def test_method_coefficients_are_scipy_s_bit_for_bit():
    """:mod:`qchain.sim.engine.tableaus` holds scipy's RK45 and Radau numbers (so a run needs no
    import of scipy.integrate)."""
    from scipy.integrate import RK45
    from scipy.integrate._ivp import radau as R

    from qchain.sim.engine import tableaus as T

    A = np.zeros((7, 7))
    A[:6, :5] = RK45.A
    A[6, :6] = RK45.B
    assert np.array_equal(T.DOPRI5_A, A) and np.array_equal(T.DOPRI5_C, np.append(RK45.C, 1.0))
    assert np.array_equal(T.DOPRI5_E, RK45.E) and np.array_equal(T.DOPRI5_P, RK45.P)
    for name in ("C", "E", "T", "TI", "P"):
        assert np.array_equal(getattr(T, "RADAU_" + name), getattr(R, name)), name
    assert np.array_equal(T.RADAU_MU, [R.MU_REAL, R.MU_COMPLEX.real, R.MU_COMPLEX.imag])
