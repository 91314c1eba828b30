"""Pressure and force inputs from Python (qchain.sim.inputs): schedules, constants and controllers
are checked against the declared ranges where they enter and at every call, and keep read-only
copies."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from helpers import deadline
from qchain.checks import bounds as B
from qchain.sim.inputs import Constant, Ramp, Schedule, Sine, Step, Table, as_input, schedules_inside
from qchain.sim.simulation import simulate
from support import CH1, NOT_NUMBERS, QB, outside, pressure_arm, refused, soft_arm


def test_schedule_times_have_the_declared_range():
    refused(lambda: Step(2**70, [1.0, 2.0, 3.0]), "time")
    refused(lambda: Table([0.0, 1e300], np.zeros((2, 3))), "times")
    assert Step(1e12, [1.0, 2.0, 3.0]).time == 1e12


def test_schedules_and_constants_keep_read_only_copies():
    v = np.full(3, 1e4)
    c = Constant(v)
    f = as_input("pressure", v, 3)
    v[0] = 1e300  # after the range check
    assert c(0.0)[0] == 1e4 and f(0.0, None, None)[0] == 1e4
    for arr in (Sine(np.full(3, 1e3), 1.0).amplitude, Table([0.0, 1.0], np.zeros((2, 3))).values,
                as_input("pressure", None, 3)(0.0, None, None), f(0.0, None, None)):
        with pytest.raises(ValueError):
            arr[0] = 5.0


def test_a_schedule_subclass_of_the_users_is_a_checked_function_of_time():
    from qchain.sim.inputs import Schedule

    class U(Schedule):
        __call__ = lambda self, t: np.full(3, np.nan)  # noqa: E731

    class W(Schedule):
        __call__ = lambda self, t: np.zeros(4)  # noqa: E731

    class Good(Schedule):
        __call__ = lambda self, t: np.full(3, 1e4)  # noqa: E731

    msg = refused(lambda: simulate(CH1, QB, np.zeros(3), (0, 0.01), pressure=U()), "pressure")
    assert "non-finite" in msg
    refused(lambda: simulate(CH1, QB, np.zeros(3), (0, 0.01), pressure=W()), "pressure")
    r = simulate(CH1, QB, np.zeros(3), (0, 0.01), pressure=Good())
    assert r.success and np.allclose(r.p[-1], 1e4)


def test_schedules_check_their_time_and_phase_and_show_the_digits_near_a_bound():
    from qchain.sim.inputs import Sine, Step, Table

    with pytest.raises(ValueError, match=r"phase\[0\] must be >= -1000 and <= 1000 rad, got 1e\+300 rad"):
        Sine([1.0] * 3, 1.0, phase=1e300)
    for u in (Sine([1.0] * 3, 1.0), Table([0.0, 1.0], [[0.0] * 3, [1.0] * 3]), Step(0.5, [0.0] * 3, [1.0] * 3)):
        for t in (float("nan"), float("inf")):
            with pytest.raises(ValueError, match="t must be finite"):
                u(t)
    ch = soft_arm(1)
    with pytest.raises(ValueError, match=r"reaches 1000000001.0 Pa"):
        simulate(ch, ch.neutral(), np.zeros(3), (0, 0.1), pressure=Sine([1.0] * 3, 1.0, offset=[1e9] * 3))


@pytest.mark.parametrize("name, value, match", [
    ("pressure", np.full(6, 1e300), r"pressure\[0\] must be >= -101325 and <= 1e\+09 Pa, got 1e\+300 Pa"),
    ("pressure", [0, 0, -2e5, 0, 0, 0], r"pressure\[2\] must be >= -101325 and <= 1e\+09 Pa, got -200000 Pa"),
    ("pressure", Sine(np.full(6, 2e5), 1.0), r"pressure\[0\] must stay >= -101325 and <= 1e\+09 Pa, but the Sine "
                                            r"schedule given as pressure reaches -200000 Pa"),
    ("pressure", Sine(np.full(6, 2e5), 1.0, offset=np.full(6, 1e9)), r"pressure\[0\] must stay .* reaches 1\.0002e\+09"),
    ("pressure", Step(0.1, after=[0, 0, 0, 0, 2e9, 0]), r"pressure\[4\] must stay .* Step schedule .* reaches 2e\+09 Pa"),
    ("pressure", Ramp(0.0, 1.0, end=np.zeros(6), start=[0, 0, 0, 0, 0, -1e6]), r"pressure\[5\] must stay .* Ramp"),
    ("pressure", Table([0.0, 1.0], [np.zeros(6), [3e9, 0, 0, 0, 0, 0]]), r"pressure\[0\] must stay .* Table .* 3e\+09"),
    ("pressure", [10**400, 0, 0, 0, 0, 0], r"pressure must hold real numbers representable as floats"),
    ("tau", np.full(6, 1e308), r"tau\[0\] must be >= -1e\+15 and <= 1e\+15, got 1e\+308"),
    ("tau", Step(0.05, after=[0, 0, 0, -1e16, 0, 0]), r"tau\[3\] must stay >= -1e\+15 and <= 1e\+15, but the Step"),
])
def test_absurd_pressures_and_forces_are_refused_before_the_run_naming_the_argument(name, value, match):
    ch = pressure_arm()
    with deadline(20):
        with pytest.raises(ValueError, match=match):
            simulate(ch, ch.neutral(), np.zeros(6), (0.0, 1.0), **{name: value})


@pytest.mark.parametrize("name", ["pressure", "tau"])
@pytest.mark.parametrize("value, error, match", [
    ([True, 0, 0, 0, 0, 0], TypeError, r"\(booleans are not numbers\)"),
    ([1j, 0, 0, 0, 0, 0], TypeError, r"complex numbers are refused"),
    (np.array([0, 0, 1 + 0j, 0, 0, 0]), TypeError, r"complex numbers are refused"),
    (["1e4", 0, 0, 0, 0, 0], TypeError, r"array of real numbers"),
    ([np.nan, 0, 0, 0, 0, 0], ValueError, r"non-finite entries at indices \[0\]"),
    ([0, 0, 0, 0, 0, -np.inf], ValueError, r"non-finite entries at indices \[5\]"),
])
def test_pressures_and_forces_that_are_not_finite_real_numbers_are_refused_by_name(name, value, error, match):
    ch = pressure_arm()
    with pytest.raises(error, match=match) as exc:
        simulate(ch, ch.neutral(), np.zeros(6), (0.0, 0.1), **{name: value})
    assert str(exc.value).startswith(name), str(exc.value)
    with pytest.raises(error, match=match):  # a schedule refuses it when it is made
        Constant(value)


def test_a_controller_outside_the_range_stops_the_run_naming_the_call():
    ch = pressure_arm()
    calls = []

    def pump(t, q, v):
        calls.append(t)
        return np.full(6, 2e4) if t < 0.01 else np.array([0, 0, 0, 0, 0, 5e9])

    with deadline(60):
        with pytest.raises(ValueError, match=r"pressure\(t, q, v\)\[5\] must be >= -101325 and <= 1e\+09 Pa, got "
                                             r"5e\+09 Pa"):
            simulate(ch, ch.neutral(), np.zeros(6), (0.0, 0.05), pressure=pump, method="RK45")
    assert calls and max(calls) >= 0.01  # it ran until the controller left the range
    with deadline(60):  # held at 100 Hz by the compiled engine: checked at each hold too
        with pytest.raises(ValueError, match=r"tau\(t\)\[0\] must be >= -1e\+15 and <= 1e\+15, got 1e\+20"):
            simulate(ch, ch.neutral(), np.zeros(6), (0.0, 0.05), tau=lambda t: np.full(6, 1e20 if t > 0.02 else 0.0),
                     controller_rate=100.0)


def test_the_edges_of_the_ranges_are_accepted():
    from qchain.sim.inputs import FORCE, as_input, input_range

    assert input_range("pressure") is B.PRESSURE and input_range("pressure[3]") is B.PRESSURE
    assert input_range("tau") is FORCE and input_range("tau(t)") is FORCE and input_range("gain") is None
    edge = np.array([B.VACUUM_GAUGE, 1e9, 0.0])
    assert np.array_equal(as_input("pressure", edge, 3)(0.0, None, None), edge)
    assert as_input("pressure", Sine([1e5] * 3, 2.0, offset=[B.VACUUM_GAUGE + 1e5] * 3), 3)(0.0, None, None).shape == (3,)
    assert np.array_equal(as_input("tau", np.array([-1e15, 1e15, 0.0]), 3)(0.0, None, None), [-1e15, 1e15, 0.0])
    # a sine of frequency 0 is a constant: only the value it holds counts
    assert as_input("pressure", Sine([2e5, 0, 0], 0.0), 3)(0.0, None, None)[0] == 0.0
    with pytest.raises(ValueError, match=r"pressure\[0\] must stay"):
        as_input("pressure", Sine([2e5, 0, 0], 0.0, phase=[-np.pi / 2, 0, 0]), 3)
    # no range for a name without one, or when asked for none
    assert as_input("gain", np.full(3, 1e300), 3)(0.0, None, None)[0] == 1e300
    assert as_input("pressure", np.full(3, 1e300), 3, bound=None)(0.0, None, None)[0] == 1e300


def test_a_schedule_whose_values_are_not_known_ahead_is_checked_at_every_call():
    from qchain.sim.inputs import Schedule, as_input

    class Surge(Step):  # changes __call__, keeps Step's extent: that extent says nothing of it
        def __call__(self, t):
            return np.full(self.size, 5e9 if t > 1.0 else 1e4)

    class Mine(Schedule):
        size = 3

        def __call__(self, t):
            return np.array([0.0, 0.0, -2e5 if t > 1.0 else 0.0])

    surge, mine = as_input("pressure", Surge(0.0, [1.0, 2.0, 3.0]), 3), as_input("pressure", Mine(), 3)
    assert surge(0.5, None, None)[0] == 1e4 and mine(0.5, None, None)[2] == 0.0
    with pytest.raises(ValueError, match=r"pressure\(t\)\[0\] must be >= -101325 and <= 1e\+09 Pa, got 5e\+09 Pa"):
        surge(2.0, None, None)
    with pytest.raises(ValueError, match=r"pressure\(t\)\[2\] must be >= -101325 and <= 1e\+09 Pa, got -200000 Pa"):
        mine(2.0, None, None)


@pytest.mark.slow
@settings(max_examples=200, deadline=None, derandomize=True, database=None)
@given(data=st.data())
def test_fuzzed_pressures_and_forces_give_a_clean_error_naming_the_argument(data):
    from qchain.sim.inputs import FORCE

    name = data.draw(st.sampled_from(["pressure", "tau"]))
    rng = B.PRESSURE if name == "pressure" else FORCE
    bad = data.draw(st.one_of(outside(rng), NOT_NUMBERS, st.complex_numbers()))
    i = data.draw(st.integers(0, 5))
    values = [0.0] * 6
    values[i] = bad
    kind = data.draw(st.sampled_from(["array", "Constant", "Step", "Ramp", "Sine offset", "Table"]))
    ch = pressure_arm()
    with deadline(20):
        with pytest.raises((ValueError, TypeError)) as exc:
            if kind == "array":
                u = values
            elif kind == "Constant":
                u = Constant(values)
            elif kind == "Step":
                u = Step(0.5, after=values)
            elif kind == "Ramp":
                u = Ramp(0.0, 0.5, end=values)
            elif kind == "Sine offset":
                u = Sine(np.zeros(6), 1.0, offset=values)
            else:
                u = Table([0.0, 1.0], [[0.0] * 6, values])
            simulate(ch, ch.neutral(), np.zeros(6), (0.0, 0.01), **{name: u})
    text = str(exc.value)
    names = (name, "value", "after", "end", "offset", "values")  # a schedule refuses it when it is made
    assert text.startswith(names), text
    assert "could not convert" not in text and "OverflowError" not in text


@pytest.mark.parametrize("value", [10**400, [1.0, -(10**400)], np.array([0.5, 10**309], dtype=object)])
def test_integers_too_large_for_a_float_are_a_value_error_naming_the_argument(value):
    from qchain.checks.convert import as_real_array

    with pytest.raises(ValueError, match=r"^q_e must hold real numbers representable as floats \(\|x\| <= 1.8e308\), got "):
        as_real_array("q_e", value)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.floats(-3e5, 3e5), st.sampled_from([0.0, 0.5, 2.0]), st.floats(-7.0, 7.0),
                          st.floats(-2e5, 2e5)), min_size=1, max_size=6))
def test_a_sines_extent_bounds_its_values_and_is_reached(entries):
    """Sine.extent (used to check a schedule's range once, before a run): every value lies
    inside it, on the fast path (every entry swinging) and the general one (some frequency 0),
    and each bound is reached to round-off; the range check agrees with the values."""
    a, f, ph, off = (np.array(x) for x in zip(*entries))
    s = Sine(amplitude=a, frequency=f, phase=ph, offset=off)
    lo, hi = s.extent()
    t, dt = np.linspace(0.0, 2.0, 4001, retstep=True)  # a period of the slowest live entry (0.5 Hz)
    vals = np.array([s(x) for x in t])
    scale = 1.0 + np.abs(a) + np.abs(off)
    assert np.all(vals >= lo - 1e-9 * scale) and np.all(vals <= hi + 1e-9 * scale)
    # the grid passes each extreme within half a step: |a| (1 - cos(pi f dt)) <= |a| (pi f dt)^2 / 2 below it
    miss = np.abs(a) * (np.pi * f * dt) ** 2 / 2 + 1e-9 * scale
    assert np.all(vals.min(axis=0) <= lo + miss) and np.all(vals.max(axis=0) >= hi - miss)
    inside = bool(np.all(lo >= B.PRESSURE.low) and np.all(hi <= B.PRESSURE.high))
    if inside:
        as_input("pressure", s, a.size)
    else:
        with pytest.raises(ValueError, match=r"pressure\[\d+\] must stay"):
            as_input("pressure", s, a.size)


class _Held(Schedule):
    """A schedule of the user's (its values are checked as they come, not ahead)."""
    size = 3

    def __call__(self, t):
        return np.full(3, 1e4)


def _each_accepted(name, us, size) -> bool:
    try:
        for i, u in enumerate(us):
            as_input(f"{name}[{i}]", u, size)
    except ValueError:
        return False
    return True


def test_a_batch_of_schedules_is_checked_at_once_as_each_would_be():
    """schedules_inside (a batch's B schedules at once) says True only where as_input accepts
    every entry, and False for what it cannot tell at once (the batch then checks each, whose
    error names the entry)."""
    low, high = B.VACUUM_GAUGE, 1e9
    sines = [Sine(np.full(3, 1e4 * (k + 1)), 1.0 + k, offset=np.full(3, 5e4)) for k in range(6)]
    mixed = [Constant(np.full(3, high)), Step(0.1, np.full(3, low)), Ramp(0.0, 1.0, np.full(3, 2e5)),
             Table(np.array([0.0, 1.0]), np.full((2, 3), 3e4)), Sine(np.full(3, 1e5), 2.0, offset=np.full(3, low + 1e5))]
    over = sines[:3] + [Sine(np.full(3, 1e4), 1.0, offset=[0.0, high, 0.0])] + sines[3:]
    under = mixed + [Step(0.1, np.full(3, 1e4), before=[0.0, 0.0, np.nextafter(low, -np.inf)])]
    for name, us, size, expected in (
            ("pressure", sines, 3, True), ("pressure", mixed, 3, True),  # the edges of the range are inside
            ("pressure", over, 3, False), ("pressure", under, 3, False),
            ("pressure", sines, 4, False),  # a wrong size: as_input names it
            ("tau", over, 3, True), ("gain", over, 3, True),  # another range, or none
            ("pressure", sines + [_Held()], 3, False), ("pressure", sines + [np.zeros(3)], 3, False),
            ("pressure", sines + [None], 3, False), ("pressure", [], 3, False)):
        assert schedules_inside(name, us, size) is expected, (name, len(us), size)
        if expected:
            assert _each_accepted(name, us, size)
    assert not _each_accepted("pressure", over, 3) and not _each_accepted("pressure", under, 3)
    with pytest.raises(ValueError, match=r"pressure\[3\]\[1\] must stay"):
        for i, u in enumerate(over):
            as_input(f"pressure[{i}]", u, 3)
