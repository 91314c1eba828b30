"""A fresh set of bad calls against the Python API (issue 18, "done when"), each a regression
test of a failure found by /tmp/adv_api/attack.py: no foreign traceback, hang, crash, silent
NaN or lost data; every error names the argument, the value and the bound, raised where the
input enters. Valid inputs in unusual forms (read-only, non-contiguous, big-endian, float32,
Fraction) give the same results as plain float64 arrays, and no function keeps, changes or
hands back a view of a caller's array.
"""

import math
import time
from decimal import Decimal
from fractions import Fraction

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from helpers import deadline
from qchain import Chain, LagrangianChain, QchainError, Segment, simulate_batch
from qchain.model import arc, spatial
from qchain.arm import statics
from qchain.model import segment as segmod
from qchain.arm.data import Data
from qchain.errors import NonFiniteError
from qchain.sim.inputs import Constant, Sine, Step, Table, as_input
from qchain.reference import elastica_cantilever
from qchain.sim.simulation import Event, simulate

SEG = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5,
           damping=0.01)
S = Segment(**SEG)
CH1 = Chain([S])
CH2 = Chain([S, S])
CHF = Chain([S], base="floating")
QB = np.array([0.105, 8.0, -2.0])
Q2 = np.r_[QB, 0.1, -3.0, 4.0]
V2 = np.array([0.01, 1.0, -0.5, 0.0, 0.3, 0.2])
P2 = np.full(6, 1e4)
FEW = settings(max_examples=60, deadline=None, derandomize=True, database=None,
               suppress_health_check=[HealthCheck.too_slow])


def prescribed(motion):
    return Chain([S], base="prescribed", base_motion=motion)


STILL = prescribed(lambda t: (pin.SE3.Identity(), np.zeros(6), np.zeros(6)))


class RaisingFloat:
    def __float__(self):
        raise RuntimeError("boom from __float__")


# ------------------------------------------------------------------------------ not-a-number values

NOT_REAL = [True, np.True_, "0.1", None, 0.1 + 0j, {"a": 1}, object(), RaisingFloat(), Decimal("0.1"), np.array([0.1])]
NOT_FINITE_OR_HUGE = [math.nan, math.inf, -math.inf, 2**70, 10**400, 1e300]


def refused(call, name, exc=(TypeError, ValueError)):
    """``call()`` raises ``exc`` (a qchain error or TypeError/ValueError) whose message names
    ``name``; returns the message."""
    with pytest.raises(exc) as info:
        call()
    err = info.value
    assert not isinstance(err, np.linalg.LinAlgError) and type(err).__module__.split(".")[0] != "numba", repr(err)
    msg = str(err)
    assert name in msg and "could not convert" not in msg, msg
    return msg


@pytest.mark.parametrize("value", NOT_REAL + NOT_FINITE_OR_HUGE, ids=repr)
def test_times_are_checked_where_they_enter_even_where_they_do_not_matter(value):
    """A fixed base ignores ``t``, a prescribed one calls ``base_motion(t)``: either way a
    time that is not a real number within +-1e12 s is refused by name (it was ignored, or
    reached ``float()`` and the user's callable)."""
    refused(lambda: CH2.kinetic_energy(Q2, V2, t=value), "t")
    refused(lambda: STILL.base_state(value), "t")
    refused(lambda: STILL.tip_placement(QB, value), "t")
    if any(value is x for x in NOT_REAL) or isinstance(value, float) and not math.isfinite(value) or value is NOT_FINITE_OR_HUGE[4]:
        refused(lambda: Event(lambda t, q, v: 1.0, direction=value), "direction")  # its sign is what counts


def test_schedule_times_have_the_declared_range():
    refused(lambda: Step(2**70, [1.0, 2.0, 3.0]), "time")
    refused(lambda: Table([0.0, 1e300], np.zeros((2, 3))), "times")
    assert Step(1e12, [1.0, 2.0, 3.0]).time == 1e12


def test_integrate_and_difference_never_return_non_finite_configurations():
    for bad in ([np.nan, 9, -2.5, 0.1, -2.7, 4.2], [0.1, 9, -2.5, 0.1, -2.7, np.inf]):
        refused(lambda: CH2.integrate(bad, V2), "q")
        refused(lambda: CH2.difference(bad, Q2), "q0")
        refused(lambda: CH2.difference(Q2, bad), "q1")
    with pytest.raises(NonFiniteError, match=r"Chain.integrate: q \(\+\) v dt is not finite .* q\[0\]"):
        CH2.integrate(Q2, np.full(6, 1e300), 1e10)
    with pytest.raises(NonFiniteError, match="Chain.difference"):
        CH2.difference(np.full(6, -1e308), np.full(6, 1e308))
    refused(lambda: CH2.integrate(Q2, V2, 2**70), "dt")
    qf = CHF.neutral()
    assert np.all(np.isfinite(CHF.integrate(qf, np.ones(9), 0.5)))


def test_a_missing_velocity_is_named_not_a_numba_typing_error():
    msg = refused(lambda: CH2.tip_velocity(Q2, None), "v", TypeError)
    assert "Chain.tip_velocity" in msg


def test_indices_and_workspaces_are_checked():
    refused(lambda: CH2.coordinate_name(-5), "i")
    refused(lambda: CH2.coordinate_name(True), "i")
    refused(lambda: CH2.coordinate_name(20.0), "i")
    assert CH2.coordinate_name(0) == "segment 0, l"
    refused(lambda: CH2.q_slice(2), "j")
    refused(lambda: CH2.v_slice(-1), "j")
    for n in (True, 0, -5, 10**30, 20.0, "3", None):
        refused(lambda n=n: Data(n, 3), "n")
    refused(lambda: Data(2, 7), "nv")
    other = Chain([S, S, S]).create_data()
    for call in (lambda d: CH2.forward_dynamics(Q2, V2, P2, data=d), lambda d: CH2.mass_matrix(Q2, data=d),
                 lambda d: CH2.forward_dynamics_derivatives(Q2, V2, P2, data=d),
                 lambda d: CH2.inverse_dynamics_derivatives(Q2, V2, V2, data=d),
                 lambda d: CH2.mass_matrix_derivative(Q2, data=d),
                 lambda d: CH2.forward_dynamics(Q2, V2, P2, data=d, skip_checks=True)):
        refused(lambda: call(other), "data", ValueError)
        refused(lambda: call(object()), "data", TypeError)
    d = CH2.create_data()
    assert np.array_equal(CH2.forward_dynamics(Q2, V2, P2, data=d), CH2.forward_dynamics(Q2, V2, P2))


def test_frames_batch_checks_the_arrays_it_writes_into_even_on_the_unchecked_path():
    """A float32 ``out`` crashed the process (the compiled pass wrote float64 into it)."""
    Q = np.tile(Q2, (4, 1))
    good = CH2.frames_batch(Q, 5)
    for out in (tuple(a.astype(np.float32) for a in good), CH2.frames_batch(Q[:2], 5), CH2.frames_batch(Q, 3),
                tuple(np.asfortranarray(a) if a.ndim > 2 else a for a in good)):
        refused(lambda out=out: CH2.frames_batch(Q, 5, skip_checks=True, out=out), "out", ValueError)
    refused(lambda: CH2.frames_batch(Q, 5, skip_checks=True, out=([1], [2], [3], [4])), "out")
    mine = tuple(np.empty_like(a) for a in good)
    got = CH2.frames_batch(Q.astype(">f8"), 5, skip_checks=True, out=mine)  # big-endian Q: converted, not a crash
    assert all(np.array_equal(a, b) for a, b in zip(got, good))
    Qp = np.tile(QB, (3, 1))
    refused(lambda: STILL.frames_batch(Qp, 4, t=[0.0, 1.0]), "t")
    refused(lambda: STILL.frames_batch(Qp, 4, t=np.nan), "t")
    refused(lambda: STILL.frames_batch(Qp, 4, t="x"), "t")


def test_a_singular_inertia_names_the_segment_and_its_coordinates():
    for q in ([1e-300, 0.0, 0.0], [5e-324, 1.0, 0.0]):
        for call in (lambda: CH1.forward_dynamics(q, np.ones(3)),
                     lambda: CH1.forward_dynamics_derivatives(q, np.ones(3), np.full(3, 1e4))):
            msg = refused(call, "segment 0", QchainError)
            assert "not positive definite" in msg and "q[0:3]" in msg, msg


# ------------------------------------------------------------------------------ the public helpers

HELPERS = [
    ("segment.paper_to_curvature", segmod.paper_to_curvature, (np.array([0.1, 0.3, 5.0]),), "q_p"),
    ("segment.curvature_to_paper", segmod.curvature_to_paper, (QB,), "q_c"),
    ("segment.paper_jacobian", segmod.paper_jacobian, (np.array([0.1, 0.3, 5.0]),), "q_p"),
    ("segment.paper_jacobian_dot", segmod.paper_jacobian_dot, (np.array([0.1, 0.3, 5.0]), np.ones(3)), "q_p"),
    ("spatial.skew", spatial.skew, (np.array([1.0, 2.0, 3.0]),), "w"),
    ("spatial.ad_matrix", spatial.ad_matrix, (np.arange(6.0),), "a"),
    ("spatial.force_cross_bar", spatial.force_cross_bar, (np.arange(6.0),), "h"),
    ("spatial.quaternion_to_rotation", spatial.quaternion_to_rotation, (np.array([0.1, 0.2, 0.3, 0.9]),), "quat"),
    ("arc.strain_twist", arc.strain_twist, (QB,), "q"),
    ("arc.bend_functions", arc.bend_functions, (np.array([0.0, 0.5, 3.0]),), "x"),
]
BAD_ENTRIES = st.sampled_from([True, np.True_, None, "1", 1j, math.nan, math.inf, -math.inf, 10**400, Decimal("1")])


@FEW
@given(which=st.sampled_from(HELPERS), bad=BAD_ENTRIES, where=st.integers(0, 2))
def test_public_helpers_refuse_bad_entries_by_name(which, bad, where):
    """The coordinate maps and spatial algebra took anything numpy would cast: booleans,
    None (an object array), strings of digits, complex numbers (imaginary part dropped),
    NaN (returned as NaN), integers too large for a float (OverflowError)."""
    _, fn, args, name = which
    first = list(np.asarray(args[0], dtype=object))
    first[where] = bad
    msg = refused(lambda: fn(first, *args[1:]), name)
    assert name in msg


@pytest.mark.parametrize("which", HELPERS, ids=[h[0] for h in HELPERS])
def test_public_helpers_give_the_same_result_for_every_valid_layout(which):
    _, fn, args, name = which
    ref = fn(*args)
    a = np.asarray(args[0], dtype=float)
    wide = np.zeros(2 * a.size)
    wide[::2] = a
    ro = a.copy()
    ro.flags.writeable = False
    for form in (a.astype(">f8"), wide[::2], ro, list(a), np.array([Fraction(x) for x in a], dtype=object)):
        assert np.array_equal(fn(form, *args[1:]), ref)
    assert np.array_equal(fn(a.astype(np.float32), *args[1:]), fn(a.astype(np.float32).astype(float), *args[1:]))
    for bad_shape in () if fn is arc.bend_functions else (a[:-1], np.zeros(0), a[:, None]):  # angles: any shape
        refused(lambda bad_shape=bad_shape: fn(bad_shape, *args[1:]), name, ValueError)


def test_helpers_at_their_singular_points_refuse_instead_of_returning_nan():
    with pytest.raises(QchainError, match="kappa"):
        segmod.curvature_velocity_to_paper(np.array([0.1, 1e-320, 0.0]), np.ones(3))  # kappa^2 underflows: was inf
    refused(lambda: spatial.quaternion_to_rotation(np.zeros(4)), "quat")
    refused(lambda: spatial.disk_inertia(1.0, math.nan), "radius")
    refused(lambda: arc.arc_nodes([math.nan], QB), "alpha")
    refused(lambda: arc.arc_nodes([0.5], QB + 1j), "q")
    refused(lambda: spatial.motion_cross(np.ones(6), np.ones(5)), "b")
    assert np.allclose(arc.bend_functions(-1.0), arc.bend_functions(1.0))  # even: any real angle


def test_the_elastica_reference_checks_its_parameters():
    for v in (True, "1", Decimal("1"), RaisingFloat(), 0.0, -1.0, math.nan, 10**400):
        refused(lambda v=v: elastica_cantilever(v, 1.0, 1.0), "length")
        refused(lambda v=v: elastica_cantilever(1.0, v, 1.0), "EI")
    refused(lambda: elastica_cantilever(1.0, 1.0, math.inf), "weight_per_length")
    assert abs(elastica_cantilever(1.0, 1.0, 1.0).tip[0] - 0.9912) < 1e-3


# ------------------------------------------------------------------------------ models

def test_a_model_owns_copies_of_its_arrays():
    K = np.diag([10.0, 1.0, 1.0])
    r = np.array([0.1, 0.0, 0.0])
    seg = Segment(**SEG, stiffness_matrix=K, rest_q_e=r)
    K[0, 1], r[0] = 123.0, -5.0  # after the checks: not symmetric, not a configuration
    assert seg.stiffness_matrix[0, 1] == 0.0 and seg.rest_q_e[0] == 0.1
    with pytest.raises(ValueError):
        seg.stiffness_matrix[0, 0] = 1.0
    with pytest.raises(ValueError):
        CH1.gravity[2] = 1e300  # read-only: the dynamics use a base-frame copy made at construction
    refused(lambda: Segment(**SEG, stiffness_matrix=np.eye(3), rest_q_e=[-0.1, 0, 0]), "rest_q_e")
    q = QB.copy()
    assert not np.shares_memory(S.check_configuration(q), q) and not np.shares_memory(S.to_curvature(q), q)


def test_placements_must_be_rotations_within_the_declared_positions():
    refused(lambda: Chain([S], base_placement=pin.SE3(2 * np.eye(3), np.zeros(3))), "base_placement.rotation")
    refused(lambda: Chain([S], base_placement=pin.SE3(np.eye(3), np.array([1e300, 0, 0]))), "base_placement")
    skewed = prescribed(lambda t: (pin.SE3(2 * np.eye(3), np.zeros(3)), np.zeros(6), np.zeros(6)))
    refused(lambda: skewed.forward_dynamics(QB, np.zeros(3)), "base_motion")
    refused(lambda: simulate(skewed, QB, np.zeros(3), (0, 0.01)), "base_motion")
    refused(lambda: CHF.mass_matrix(np.r_[1e300, 0, 0, 0, 0, 0, 1.0, QB]), "base position")
    refused(lambda: Chain(S), "segments", TypeError)
    refused(lambda: Chain(None), "segments", TypeError)


def test_statics_checks_its_inputs_where_they_enter():
    refused(lambda: statics.equilibrium(CH1, None, [math.nan, 0, 0]), "q0")
    refused(lambda: statics.equilibrium(CH1, np.full(3, 1e300)), "p")
    refused(lambda: statics.equilibrium(CH1, None, None, np.full(6, 1e300)), "tip_wrench")
    refused(lambda: statics.equilibrium(CH1, continuation="no"), "continuation")
    refused(lambda: statics.equilibrium(CH1, None, [0.1, 1e3, 0]), "segment 0")
    assert statics.equilibrium(CH1, np.full(3, 1e4)).success


# ------------------------------------------------------------------------------ simulate and batches

def test_run_settings_are_checked_alike_in_simulate_and_simulate_batch():
    q0 = np.tile(CH1.neutral(), (2, 1))
    z = np.zeros(3)
    te = [0.0, 0.01]
    cases = [(dict(t_span="0 1"), "t_span"), (dict(t_span=(False, True)), "t_span"),
             (dict(t_span=(Decimal(0), Decimal("0.01"))), "t_span"), (dict(t_span=(0.0, 1e-300)), "t_span"),
             (dict(t_eval=[0.0, 0.005 + 0j]), "t_eval"), (dict(rtol="1e-6"), "rtol"), (dict(rtol=np.ones(2)), "rtol"),
             (dict(atol="x"), "atol"), (dict(method="rk4", dt="1e-3"), "dt"), (dict(method="rk4", dt=1 + 0j), "dt"),
             (dict(energies="no"), "energies"), (dict(events=3), "events"), (dict(events=[lambda t, q, v: 1]), "events")]
    for kw, name in cases:
        span = kw.pop("t_span", (0.0, 0.01))
        refused(lambda: simulate(CH1, CH1.neutral(), z, span, **kw), name)
        refused(lambda: simulate_batch(CH1, q0, z, span, **{"t_eval": te, "workers": 1, **kw}), name)
    refused(lambda: simulate(CH1, CH1.neutral(), z, (0, 0.01), progress="yes"), "progress")
    refused(lambda: simulate(CH1, CH1.neutral(), z, (0, 0.01), on_sample=3), "on_sample")
    refused(lambda: simulate_batch(CH1, q0, z, (0, 0.01), t_eval=te, workers=1, progress="yes"), "progress")


@pytest.mark.parametrize("workers", [10**9, 10**30, 0, -2, True, 2.0, "2"])
def test_absurd_worker_counts_are_refused_at_once(workers):
    """``workers=10**9`` made a pool of a billion slots (a hang, then the process killed)."""
    q0 = np.tile(CH1.neutral(), (2, 1))
    t0 = time.perf_counter()
    with deadline(20):
        refused(lambda: simulate_batch(CH1, q0, np.zeros(3), (0, 0.01), t_eval=[0, 0.01], workers=workers), "workers")
    assert time.perf_counter() - t0 < 5.0
    refused(lambda: simulate_batch(CH1, q0, np.zeros(3), (0, 0.01), t_eval=[0, 0.01], workers=1, retries=10**30),
            "retries")


@pytest.mark.parametrize("name, value", [("q0", np.ones((2, 3), bool)), ("q0", np.tile([0.1, 0, 0], (2, 1)) + 1e-3j),
                                         ("q0", "abc"), ("pressure", np.zeros((2, 3), bool)),
                                         ("pressure", np.zeros(3) + 1j), ("tau", np.zeros((2, 3), bool))])
def test_batch_arrays_are_never_cast_from_booleans_strings_or_complex_numbers(name, value):
    kw = dict(q0=np.tile(CH1.neutral(), (2, 1)), v0=np.zeros(3), t_span=(0, 0.01), t_eval=[0, 0.01], workers=1)
    kw[name] = value
    refused(lambda: simulate_batch(CH1, kw.pop("q0"), kw.pop("v0"), kw.pop("t_span"), **kw), name)


def test_valid_batch_layouts_give_the_plain_result():
    q0 = np.tile(CH1.neutral(), (2, 1))
    ref = simulate_batch(CH1, q0, np.zeros(3), (0, 0.01), pressure=np.full((2, 3), 1e4), t_eval=[0, 0.01], workers=1)
    ro = np.full((2, 3), 1e4)
    ro.flags.writeable = False
    for Q, P in ((np.asfortranarray(q0), np.full((2, 3), 1e4)), (q0.astype(">f8"), ro), (q0, [[10000] * 3] * 2)):
        b = simulate_batch(CH1, Q, np.zeros(3), (0, 0.01), pressure=P, t_eval=[0, 0.01], workers=1)
        assert np.array_equal(b.q, ref.q)


@pytest.mark.parametrize("ctl", [lambda: np.zeros(3), lambda t, q: np.zeros(3)], ids=["no argument", "two"])
def test_a_controller_of_the_wrong_arity_is_named_where_it_enters(ctl):
    for kw in (dict(method="RK45"), dict(controller_rate=1e3)):
        msg = refused(lambda: simulate(CH1, CH1.neutral(), np.zeros(3), (0, 0.01), pressure=ctl, **kw), "pressure",
                      TypeError)
        assert "(t, q, v)" in msg


@pytest.mark.parametrize("ret", [math.nan, "1", np.ones(2), None, 1j], ids=repr)
@pytest.mark.parametrize("method", ["radau5", "RK45"])
def test_an_event_function_must_return_a_finite_real(ret, method):
    """NaN never crosses zero (the event was silently never seen); the others failed in a
    comparison naming nothing."""
    def level(t, q, v):
        return ret

    msg = refused(lambda: simulate(CH1, CH1.neutral(), np.zeros(3), (0, 0.01), method=method, events=[Event(level)]),
                  "event 'level'")
    assert "t = 0 s" in msg
    refused(lambda: Event(level, terminal="no"), "terminal")
    refused(lambda: Event(level, name=3), "name")


@pytest.mark.parametrize("method", ["radau5", "rk4", "RK45"])
def test_callables_get_copies_of_the_state(method):
    """A controller, an event function and ``on_sample`` that write into the arrays they get
    change neither the caller's q0, nor the run, nor the recorded samples (on the Python
    path the run went outside the model, and a private exception escaped)."""
    def careless(t, q, v):
        q[:] = 0.0
        v[:] = 1e3
        return np.full(6, 1e4)

    def ev(t, q, v):
        q[:] = -1.0
        return 1.0

    def cb(t, q, v, p):
        q[:] = 7.0
        p[:] = 7.0

    kw = dict(method=method, dt=1e-3, t_eval=[0, 0.005, 0.01])
    if method != "RK45":
        kw["controller_rate"] = 1e3
    ref = simulate(CH2, CH2.neutral(), np.zeros(6), (0, 0.01), pressure=lambda t, q, v: np.full(6, 1e4), **kw)
    q0 = CH2.neutral()
    tr = simulate(CH2, q0, np.zeros(6), (0, 0.01), pressure=careless, events=[Event(ev)], on_sample=cb, **kw)
    assert np.array_equal(q0, CH2.neutral()) and tr.success
    assert np.allclose(tr.q, ref.q, rtol=1e-12, atol=1e-15) and np.allclose(tr.p, ref.p)


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


def test_the_base_placement_is_given_as_a_copy():
    """It was the chain's own SE3: changing it left the passes' gravity in the base frame stale."""
    X = pin.SE3(pin.rpy.rpyToMatrix(0.3, 0.0, 0.0), np.array([0.0, 0.0, 1.0]))
    ch = Chain([S], base_placement=X)
    q = ch.neutral()
    g0 = ch.generalized_gravity(q)
    got = ch.base_placement
    got.rotation = np.eye(3)
    X.rotation = np.eye(3)
    again = ch.generalized_gravity(q)
    assert np.array_equal(g0, again)
    assert np.allclose(ch.base_placement.rotation, pin.rpy.rpyToMatrix(0.3, 0.0, 0.0), atol=0, rtol=0)


def test_inputs_and_outputs_share_no_memory():
    q0, v0, P, te = CH2.neutral(), np.zeros(6), np.full(6, 1e4), np.linspace(0, 0.01, 3)
    keep = [x.copy() for x in (q0, v0, P, te)]
    tr = simulate(CH2, q0, v0, (0, 0.01), pressure=P, t_eval=te)
    assert all(np.array_equal(a, b) for a, b in zip((q0, v0, P, te), keep))
    assert not any(np.shares_memory(o, i) for o in (tr.t, tr.q, tr.v, tr.p) for i in (q0, v0, P, te))


@FEW
@given(kind=st.sampled_from(["bool", "str", "complex", "nan", "short", "2-D", "object"]),
       method=st.sampled_from(["integrate", "difference", "tip_velocity", "momentum", "coriolis_matrix",
                               "inverse_dynamics_derivatives", "pressure_stiffness", "mass_matrix_derivative"]))
def test_chain_methods_refuse_bad_arrays_by_name(kind, method):
    bad = {"bool": np.ones(6, bool), "str": ["0.1"] * 6, "complex": Q2 + 0j, "nan": np.r_[np.nan, Q2[1:]],
           "short": Q2[:5], "2-D": Q2[None], "object": np.array([0.1, object(), 0, 0, 0, 0], dtype=object)}[kind]
    call = {"integrate": lambda: CH2.integrate(bad, V2), "difference": lambda: CH2.difference(bad, Q2),
            "tip_velocity": lambda: CH2.tip_velocity(bad, V2), "momentum": lambda: CH2.momentum(bad, V2),
            "coriolis_matrix": lambda: CH2.coriolis_matrix(bad, V2),
            "inverse_dynamics_derivatives": lambda: CH2.inverse_dynamics_derivatives(bad, V2, V2),
            "pressure_stiffness": lambda: CH2.pressure_stiffness(bad, P2),
            "mass_matrix_derivative": lambda: CH2.mass_matrix_derivative(bad)}[method]
    refused(call, "q0" if method == "difference" else "q")


def test_the_lagrangian_form_and_engine_entry_points_name_bad_arguments():
    from qchain import compile_all
    from qchain.sim.engine import system

    L = LagrangianChain(CHF)
    refused(lambda: L.forward_dynamics(np.r_[0.1, 0.2, 0.3, 0.1, 0.2, 0.3, QB], [True] * 9), "qd_L")
    refused(lambda: compile_all(["bogus"]), "methods")
    refused(lambda: compile_all("rk4"), "methods")
    refused(lambda: system.pack("chain", None, None), "chain")


def test_a_failed_run_of_a_large_chain_does_not_spend_minutes_on_its_stability_limit():
    """A 1000-segment rk4 run that failed formed the 6000 x 6000 Jacobian for its message."""
    from helpers import deadline
    from qchain.sim.engine.driver import STABILITY_MAX_NV, stability_limit

    big = Chain([S] * (STABILITY_MAX_NV // 3 + 1))
    with deadline(10, "stability_limit of a large chain"):
        assert stability_limit(big, big.neutral(), np.zeros(big.nv), np.zeros(big.nu), np.zeros(big.nv), 0.0) is None
    small = Chain([S] * 2)
    lim = stability_limit(small, small.neutral(), np.zeros(small.nv), np.zeros(small.nu), np.zeros(small.nv), 0.0)
    assert lim is not None and 0 < lim < 1


# ------------------------------------------------------------------------------ second round (issue 18 follow-up)

@pytest.mark.filterwarnings("ignore:the matrix subclass:PendingDeprecationWarning")
def test_masked_arrays_are_refused_by_name_or_taken_as_plain_arrays():
    """A masked array with a masked entry is refused where it enters (it reached numba, or
    its masked entries were used silently); an unmasked one, or an np.matrix row, is a plain
    array for compiled code."""
    from qchain.errors import as_batch, as_matrix, as_real, as_real_array, as_vector

    masked = np.ma.masked_array(QB, mask=[0, 1, 0])
    for call in (lambda: simulate(CH1, masked, np.zeros(3), (0, 0.01)),
                 lambda: as_vector("q0", masked, 3), lambda: as_real_array("q0", masked),
                 lambda: as_batch("q0", masked, 3), lambda: as_matrix("q0", masked.reshape(1, 3), (1, 3))):
        assert "masked entries" in refused(call, "q0")
    refused(lambda: Chain([S], gravity=np.ma.masked_array([0, 0, -9.81], mask=[0, 0, 1])), "gravity")
    refused(lambda: simulate(CH1, QB, np.zeros(3), (0, 0.01), t_eval=np.ma.masked_array([0, 0.005], mask=[0, 1])),
            "t_eval")
    refused(lambda: simulate(CH1, QB, np.zeros(3), (0, 0.01), pressure=np.ma.masked_array(np.ones(3), mask=[0, 1, 0])),
            "pressure")
    refused(lambda: simulate(CH1, QB, np.zeros(3), (0, 0.01),
                             pressure=lambda t, q, v: np.ma.masked_array(np.ones(3), mask=[0, 1, 0])), "pressure")
    refused(lambda: as_real("t", np.ma.masked_array(1.0, mask=True)), "t")
    for plain in (np.ma.masked_array(QB), np.ma.masked_array(QB, mask=[0, 0, 0])):
        a = as_vector("q0", plain, 3)
        assert type(a) is np.ndarray and np.array_equal(a, QB)
        r = simulate(CH1, plain, np.zeros(3), (0, 0.01))
        assert r.success and np.array_equal(r.q[-1], simulate(CH1, QB, np.zeros(3), (0, 0.01)).q[-1])
    assert type(as_real_array("x", np.matrix([[1.0, 2.0]]))) is np.ndarray
    refused(lambda: simulate(CH1, np.matrix(QB), np.zeros(3), (0, 0.01)), "q0")


def test_a_set_table_is_merged_into_the_scenes_table():
    """``set={'simulation': {'duration': ...}}`` changes the duration and keeps method and dt
    (it replaced the whole [simulation] table: the runs used the default method)."""
    from qchain.batch.sweep_spec import apply_values

    raw = {"simulation": {"duration": 0.2, "method": "rk4", "dt": 1e-3}, "segments": [{"damping": 0.1}]}
    out = apply_values(raw, {"simulation": {"duration": 0.03}})
    assert out["simulation"] == {"duration": 0.03, "method": "rk4", "dt": 1e-3}
    assert raw["simulation"]["duration"] == 0.2
    out = apply_values(raw, {"simulation": {"duration": 0.03, "output": {"x": 1}}, "segments[0]": {"mass": 2.0}})
    assert out["simulation"]["method"] == "rk4" and out["segments"][0] == {"damping": 0.1, "mass": 2.0}


def test_sweep_keys_take_ascii_digits_only():
    from qchain.batch.sweep_spec import parse_key

    assert parse_key("segments[0].damping") == ["segments", 0, "damping"]
    for key in ("segments[\u0660].damping", "segments[\uff11].damping"):
        with pytest.raises(ValueError, match="segments"):
            parse_key(key)


def bad_metric(scene, model, traj):
    return {"x": object(), "ok": 1.0}


def test_an_unserialisable_metric_fails_its_run_not_the_sweep(tmp_path):
    from helpers import SEGMENTS_TOML
    from qchain import sweep
    from qchain.batch.sweeps import _check_metric

    base = tmp_path / "base.toml"
    base.write_text('name = "m"\n' + SEGMENTS_TOML + '[simulation]\nduration = 0.002\nmethod = "rk4"\ndt = 1e-3\n')
    res = sweep(base, {"segments[0].damping": [0.01, 0.02]}, workers=1, folder=tmp_path / "f", progress=False,
                metrics=bad_metric)
    rows = res.rows()
    assert len(rows) == 2 and all(not r["success"] for r in rows)
    assert all("'x'" in r["message"] and "object" in r["message"] for r in rows), rows[0]["message"]
    assert (tmp_path / "f" / "summary.parquet").exists()
    for ok in (None, True, 1, 2.5, "s", [1.0, 2], [[1.0], [2.0]]):
        _check_metric("k", ok)
    for bad in (object(), {"a": 1}, [1.0, math.nan], [1.0, "a"], b"x"):
        with pytest.raises(TypeError, match="'k'"):
            _check_metric("k", bad)


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


def test_paper_psi_is_bounded_where_it_enters():
    sp = Segment(**SEG, coords="paper")
    msg = refused(lambda: simulate(Chain([sp]), np.array([0.1, 1e300, 2.0]), np.zeros(3), (0, 0.01)), "psi")
    assert "1000" in msg
    refused(lambda: Segment(**SEG, coords="paper", rest_q_e=[0.1, -2e3, 2.0]), "psi")
    assert simulate(Chain([sp]), np.array([0.1, 0.5, 2.0]), np.zeros(3), (0, 0.002)).success


def test_a_0d_object_array_of_segments_is_refused_by_name():
    msg = refused(lambda: Chain(np.array(S, dtype=object)), "segments")
    assert "sequence" in msg
    assert Chain(np.array([S, S], dtype=object)).n == 2


def test_an_explicit_adaptive_method_on_a_stiff_model_stops_at_the_step_budget():
    """Refused before it starts where the stability limit puts it over budget; where the
    limit (a lower bound of the steps) lets it start, stopped at budget.max_steps as it goes."""
    from qchain.sim.budget import Budget, BudgetError
    from qchain.sim.simulation import explicit_stability_limit

    s = Segment(length=1e-5, radius=1e-3, mass=1e-9, chamber_area=1e-8, chamber_radius=5e-4, youngs_modulus=1e12)
    ch = Chain([s])
    t = time.perf_counter()
    with pytest.raises(BudgetError, match=r"budget.max_steps: expected at most 10000000 steps, found .* steps \("
                       r"duration 0.02 s / dopri5's stability limit of the step at the start, about .* s: the model "
                       r"is stiff for an explicit method, use method 'radau5'\)"):
        simulate(ch, s.neutral(), np.zeros(3), (0, 0.02), method="dopri5")
    h = explicit_stability_limit(ch, "dopri5", s.neutral(), np.zeros(3), 0.0)
    r = simulate(ch, s.neutral(), np.zeros(3), (0, 2000 * h), method="dopri5", budget=Budget(max_steps=5000))
    assert time.perf_counter() - t < 60
    assert not r.success and "budget.max_steps = 5000" in r.message and "radau5" in r.message, r.message
