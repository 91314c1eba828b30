"""The automatic inextensible reduction of a scene (:mod:`qchain.scene.stretch`): when it is
tried, its estimate against the full model's tip on a run, the axial and bending
frequencies against the uniform rod's, and what the model and its notes say."""

from dataclasses import replace

import numpy as np
import pytest

from qchain.scene import parse_scene
from qchain.scene.stretch import DEFAULT_LENGTH_TOLERANCE

# the cantilever release of benchmarks/bench_release.py: L = 0.2 m, r = 0.02 m,
# rho = 1000 kg/m^3, E = 0.5 MPa, clamped along world +x, released straight under gravity
L, R, RHO, E, N = 0.2, 0.02, 1000.0, 5e5, 10
MASS = RHO * np.pi * R * R * L / N


def cantilever(extra: str = "", duration: float = 1.0, model: str = "", youngs_modulus: float = E) -> str:
    return f"""
name = "cantilever"
[model]
{model}
[[segments]]
count = {N}
length = {L / N!r}
radius = {R!r}
mass = {MASS!r}
chamber_area = 1e-6
chamber_radius = 0.005
youngs_modulus = {youngs_modulus!r}
[base]
rpy = [0, 1.5707963267948966, 0]
[simulation]
duration = {duration!r}
method = "radau5"
rtol = 1e-8
atol = 1e-10
[output]
sample_rate = 500
save = false
{extra}
"""


def note(model, word="inextensible") -> str:
    found = [r for r in model.reductions + model.kept if r.startswith(word + ":")]
    assert len(found) == 1, model.reductions + model.kept
    return found[0]


def tip_path(model, traj) -> np.ndarray:
    return np.array([model.chain.tip_placement(q).translation for q in traj.q])


def test_frequencies_are_the_uniform_rods():
    """The slowest axial mode of the clamped-free rod, ``sqrt(E / rho) / (4 L)``, and its
    slowest bending mode, ``1.8751^2 / (2 pi) sqrt(EI / (rho A L^4))`` (Euler-Bernoulli),
    from the arm of 10 segments (its discretisation and rotary inertia: within 1 %)."""
    sc = parse_scene(cantilever())
    f_bend, f_axial = sc.axial_frequencies()
    axial = np.sqrt(E / RHO) / (4 * L)
    EI, rhoA = E * np.pi * R**4 / 4, RHO * np.pi * R * R
    bend = 1.875104**2 / (2 * np.pi) * np.sqrt(EI / (rhoA * L**4))
    assert f_axial == pytest.approx(axial, rel=1e-2)
    assert f_bend == pytest.approx(bend, rel=1e-2)


@pytest.mark.parametrize("youngs_modulus, duration", [
    (E, 1.0), pytest.param(2e6, 1.0, marks=pytest.mark.slow), pytest.param(2e6, 3.0, marks=pytest.mark.slow)])
def test_the_estimate_covers_the_full_models_tip_change_on_a_release(youngs_modulus, duration):
    """The estimated tip change of locking ``l`` is at least the largest tip distance between
    the locked and the full (planar, extensible) model over the run, and not more than 3
    times it (a useful estimate, not a blanket margin)."""
    sc = parse_scene(cantilever(duration=duration, model="length_tolerance = 0.01", youngs_modulus=youngs_modulus))
    locked = sc.build()
    assert note(locked).startswith("inextensible: l locked at l0 in every segment")
    assert locked.chain.planar and locked.chain.nv_active == N  # only the bends stay free
    full = replace(sc, length_tolerance=1e-12).build()
    assert note(full).startswith("inextensible: not applicable: estimated tip change")
    assert full.chain.nv_active == 2 * N
    est = sc.estimate_stretch(planar=True)
    a, b = sc.simulate(model=locked), sc.simulate(model=full)
    assert a.success and b.success
    actual = np.linalg.norm(tip_path(locked, a) - tip_path(full, b), axis=1).max()
    assert actual <= est.tip <= 3 * actual, (actual, est)


def test_the_tolerance_decides_and_the_note_says_why():
    sc = parse_scene(cantilever())
    assert sc.length_tolerance == DEFAULT_LENGTH_TOLERANCE
    est = sc.estimate_stretch(planar=True)
    kept = note(sc.build())  # the default 0.1 mm: the soft cantilever's estimate is larger
    assert kept.startswith("inextensible: not applicable: ") and "> length_tolerance = 0.1 mm" in kept
    assert f"{est.tip * 1e3:.3g} mm" in kept
    loose = replace(sc, length_tolerance=est.tip * 1.01).build()
    assert "<= length_tolerance" in note(loose) and loose.chain.nv_active == N
    assert not replace(sc, length_tolerance=est.tip * 0.99).build().reductions.count(note(loose))
    off = sc.build(reduce=False)
    assert note(off) == "inextensible: not tried (reduce = false)" and off.chain.nv_active == off.chain.nv


def pressure(values: list[float]) -> str:
    return f'[pressure]\ntype = "constant"\nvalue = {values * N}'


@pytest.mark.parametrize("extra, why", [
    # chamber 1 alone, stepped on: the segments' mean pressure changes, the axial mode is the motion
    ('[pressure]\ntype = "step"\ntime = 0.1\nafter = ' + str([3e3, 0.0, 0.0] * N), "the pressures actuate elongation"),
    ("[initial]\nq_e = " + str([[L / N * 1.001, 0.0, 0.0]] * N), "initial l differs from l0"),
    ("[initial]\nv = " + str([[1e-3, 0.0, 0.0]] * N), "initial l differs from l0 or its rate is not 0"),
    ('[pressure]\ntype = "sine"\noffset = ' + str([0.0] * 3 * N) + "\namplitude = " + str([2e3, 0.0, 0.0] * N)
     + "\nfrequency = 20.0\nphase = " + str([0.0] * 3 * N), "the pressures actuate elongation"),
    ('[[obstacles]]\ntype = "halfspace"\npoint = [0, 0, -0.1]\nnormal = [0, 0, 1]', "obstacles"),
])
def test_refused_with_the_reason(extra, why):
    sc = parse_scene(cantilever(extra, model="length_tolerance = 1.0"))
    assert why in sc.inextensible_obstacle()
    text = note(sc.build())
    assert text.startswith("inextensible: not applicable: ") and why in text
    assert not any(r.startswith("inextensible: l locked") for r in sc.build().reductions)


def test_a_bending_drive_of_constant_mean_may_lock_and_fast_inputs_refuse():
    """``p1 = 2 a sin``, ``p2 = p3 = -a sin``: the mean pressure stays 0, so the reduction is
    decided by the estimate; the same drive near the axial mode (within 3 x) is refused."""
    def sine(f):
        return ('[pressure]\ntype = "sine"\noffset = ' + str([0.0] * 3 * N) + "\namplitude = "
                + str([2e3, 1e3, 1e3] * N) + f"\nfrequency = {f!r}\nphase = " + str([0.0, np.pi, np.pi] * N))
    sc = parse_scene(cantilever(sine(1.0), model="length_tolerance = 1.0"))
    assert sc.inextensible_obstacle() is None
    assert note(sc.build()).startswith("inextensible: l locked at l0")
    fast = parse_scene(cantilever(sine(10.0), model="length_tolerance = 1.0"))
    assert "the slowest axial mode (28 Hz) is within 3x of the inputs' 10 Hz" in note(fast.build())


def test_a_controlled_build_keeps_l_free():
    sc = parse_scene(cantilever(model="length_tolerance = 1.0"))
    m = sc.build(controlled=True)
    assert "the pressures come from a controller" in note(m) and m.chain.nv_active == m.chain.nv


def test_length_tolerance_is_checked_where_it_enters():
    from qchain.scene import SceneError

    with pytest.raises(SceneError, match=r"model\.length_tolerance.*> 0"):
        parse_scene(cantilever(model="length_tolerance = 0.0"))
