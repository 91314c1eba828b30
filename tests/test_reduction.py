"""Model reduction from scenes: the reduced model against the full one.

* planar (exact where the scene is symmetric about the base x-z plane): the same tip
  trajectory to 1e-9 m (measured: bitwise equal, 0 m) with a fixed, a swinging and a
  free-falling floating base, fixed-step RK4 at the same dt in both models; forcing the
  plane on a scene that is not symmetric is visibly wrong (so the check is not vacuous).
* inextensible (not exact: the limit of a stiff axial direction): the arm with ``l``
  locked against the same arm whose axial stiffness is ``k_a = f EA/l0``, f = 10, 100,
  1000, with the material's damping law ``D = beta K``. Measured tip differences over
  0.5 s (Radau, rtol 1e-8): 1.44e-3, 1.44e-4, 1.44e-5 m, i.e. exactly ``1/k_a``. Asserted:
  below ``n F_max / k_a`` (the summed static elongation of the n segments under the
  largest axial load, all chambers at peak pressure plus the whole arm's weight: measured
  at half of it) and shrinking at least 5 x per decade of stiffness.
* node count from ``node_tolerance`` (not exact): the wave_arm example with 4 nodes a
  segment (tolerance 1e-8, sized for 1.03 rad) against 12 nodes: measured 2.3e-11 m over
  1 s (RK4, dt 1 ms); asserted below ``10 * node_tolerance * arm length`` = 3e-8 m; the
  bends reached (0.34, 0.34, 0.59 rad) stay below the one the nodes were sized for.
"""

import math
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from dataclasses import replace

from qchain import Chain, Segment
from qchain.sim.inputs import Sine
from qchain.scene import load_scene, parse_scene
from qchain.sim.simulation import simulate

EXAMPLES = Path(__file__).parents[1] / "examples" / "scenes"

PLANAR_SCENE = """
gravity = [0.0, 0.0, -9.81]
[[segments]]
count = 3
length = 0.1
radius = 0.015
mass = 0.05
chamber_area = 4.5e-5
chamber_radius = 0.0085
youngs_modulus = 1e5
damping = 0.01
[base]
{base}
[pressure]
type = "sine"
offset = [20e3, 10e3, 10e3,  20e3, 10e3, 10e3,  20e3, 10e3, 10e3]
amplitude = [20e3, 10e3, 10e3,  20e3, 10e3, 10e3,  20e3, 10e3, 10e3]
phase = [0.0, 3.0, 3.0,  0.0, 3.0, {phase}, 0.0, 3.0, 3.0]
frequency = 2.0
segment_phase = -1.0
[initial]
q_e = [[0.1, 3.0, 0.0], [0.1, -2.0, 0.0], [0.1, 0.0, 0.0]]
v = [0.0, 1.0, 0.0,  0.0, 0.0, 0.0,  0.0, -1.0, 0.0]
[simulation]
duration = 0.5
method = "rk4"
dt = 1e-3
[output]
sample_rate = 100.0
"""

BASES = {
    "fixed, turned about y": 'type = "fixed"\nrpy = [0.0, 1.2, 0.0]',
    "prescribed rotation about y": 'type = "prescribed"\nrpy = [0.0, 2.0, 0.0]\n[base.motion]\ntype = "rotation"\n'
                                   "axis = [0.0, 1.0, 0.0]\namplitude = 0.3\nfrequency = 1.5",
    "floating, falling": 'type = "floating"\nrpy = [0.0, 0.5, 0.0]\nvelocity = [0.1, 0.0, 0.2]\n'
                         "angular_velocity = [0.0, 0.5, 0.0]",
}


def tips(model, traj):
    return np.array([model.chain.tip_placement(q, t=t).translation for t, q in zip(traj.t, traj.q)])


@pytest.mark.parametrize("base", BASES.values(), ids=BASES.keys())
def test_planar_reduction_is_exact(base):
    scene = parse_scene(PLANAR_SCENE.format(base=base, phase=3.0))
    red, full = scene.build(reduce=True), scene.build(reduce=False)
    assert red.chain.planar and not full.chain.planar
    assert red.chain.nv_active == full.chain.nv_active - 3
    tr, tf = scene.simulate(model=red), scene.simulate(model=full)
    assert tr.success and tf.success
    assert np.array_equal(tr.t, tf.t) and tr.t[-1] == 0.5
    tip_r, tip_f = tips(red, tr), tips(full, tf)
    assert np.ptp(tip_f[:, [0, 2]], axis=0).min() > 0.03  # the arm does move in the plane
    assert np.abs(tip_r - tip_f).max() < 1e-9
    uy = tf.q[:, [full.chain.q_slice(j).start + 2 for j in range(3)]]
    assert np.abs(uy).max() < 1e-9  # the full model stays in the plane by itself


def test_forcing_the_plane_on_an_asymmetric_scene_is_wrong():
    """Chamber 3 of segment 1 out of phase: the detection refuses the plane, and a plane
    forced on anyway gives a different motion (the reduction would not be exact)."""
    scene = parse_scene(PLANAR_SCENE.format(base=BASES["fixed, turned about y"], phase=2.0))
    assert "the sines of chambers 2 and 3 differ in segment 1" in scene.planar_obstacle()
    full = scene.build()
    assert not full.chain.planar
    forced = replace(full, chain=Chain(full.chain.segments, base="fixed", gravity=full.chain.gravity,
                                       base_placement=full.chain.base_placement, planar=True))
    tf, tp = scene.simulate(model=full), scene.simulate(model=forced)
    assert tf.success and tp.success
    assert np.abs(tips(full, tf) - tips(forced, tp)).max() > 1e-3


# --------------------------------------------------------------------------------------
# inextensible segments against a stiff axial direction

SEG = dict(length=0.1, radius=0.015, mass=0.05, chamber_area=4.5e-5, chamber_radius=0.0085, youngs_modulus=1e5)
BETA = 0.02  # s
P_PEAK = 4e4  # Pa, offset + amplitude below


def _pressure():
    phase = np.tile([0.0, 2 * np.pi / 3, 4 * np.pi / 3], 3) + np.repeat([0.0, -1.0, -2.0], 3)
    return Sine(amplitude=[P_PEAK / 2] * 9, frequency=1.0, phase=phase, offset=[P_PEAK / 2] * 9)


def _run(segs, T=0.5):
    X = pin.SE3(pin.rpy.rpyToMatrix(math.pi, 0.0, 0.0), np.array([0.0, 0.0, 0.5]))  # hanging
    ch = Chain(segs, base="fixed", base_placement=X)
    tr = simulate(ch, ch.neutral(), np.zeros(ch.nv), (0.0, T), pressure=_pressure(), method="Radau", rtol=1e-8,
                  atol=1e-10, t_eval=np.linspace(0.0, T, 51))
    assert tr.success, tr.message
    return ch, tr, np.array([ch.tip_placement(q).translation for q in tr.q])


def test_inextensible_equals_the_linear_law_on_l_equals_l0():
    """The stiff comparison uses the linear law ``K = diag(k_a, EI l0, EI l0)``: on the
    constraint ``l = l0`` its bending forces equal the material law's, so the two arms
    differ only by the axial mode."""
    mat = Segment(**SEG, damping=BETA)
    EI, l0 = mat.bending_stiffness, mat.length
    lin = Segment(**SEG, damping=BETA, stiffness_matrix=np.diag([1e6, EI * l0, EI * l0]))
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = np.array([l0, *rng.uniform(-20, 20, 2)])
        qd = np.array([0.0, *rng.normal(size=2)])
        assert np.allclose(mat.elastic_force(q)[1:], lin.elastic_force(q)[1:], rtol=1e-14, atol=0)
        assert np.allclose(mat.damping_force(q, qd)[1:], lin.damping_force(q, qd)[1:], rtol=1e-14, atol=0)
        assert np.allclose(mat.elastic_stiffness(q)[1:, 1:], lin.elastic_stiffness(q)[1:, 1:], rtol=1e-14, atol=0)


@pytest.mark.slow
def test_inextensible_is_the_limit_of_a_stiff_axial_direction():
    ch_i, tr_i, tip_i = _run([Segment(**SEG, damping=BETA, extensible=False) for _ in range(3)])
    assert ch_i.nv_active == 6
    assert np.all(tr_i.q[:, [0, 3, 6]] == SEG["length"])
    mat = Segment(**SEG, damping=BETA)
    EI, EA, l0 = mat.bending_stiffness, mat.axial_stiffness, mat.length
    F_max = 3 * SEG["chamber_area"] * P_PEAK + 3 * SEG["mass"] * 9.81  # N: all chambers at peak + whole weight
    diffs = []
    for f in (10.0, 100.0, 1000.0):
        k_a = f * EA / l0
        segs = [Segment(**SEG, damping=BETA, stiffness_matrix=np.diag([k_a, EI * l0, EI * l0])) for _ in range(3)]
        _, tr_s, tip_s = _run(segs)
        d = float(np.abs(tip_s - tip_i).max())
        bound = 3 * F_max / k_a
        print(f"k_a = {f:g} EA/l0: tip difference {d:.3g} m (bound {bound:.3g} m), "
              f"max |l - l0| {np.abs(tr_s.q[:, [0, 3, 6]] - l0).max():.3g} m")
        assert d < bound
        diffs.append(d)
    assert diffs[1] < diffs[0] / 5 and diffs[2] < diffs[1] / 5


# --------------------------------------------------------------------------------------
# node count


def test_node_count_from_tolerance_keeps_the_trajectory():
    scene = load_scene(EXAMPLES / "wave_arm.toml")
    red = scene.build()
    assert scene.node_tolerance == 1e-8 and max(red.nodes) < 6
    T = 1.0

    def run(ch):
        tr = simulate(ch, red.q0, red.v0, (0.0, T), pressure=red.pressure, method="rk4", dt=1e-3,
                      t_eval=np.linspace(0.0, T, 51))
        assert tr.success
        return tr, np.array([ch.tip_placement(q).translation for q in tr.q])

    tr_r, tip_r = run(red.chain)
    ref = Chain([replace(s, nodes=12) for s in red.chain.segments], base="fixed", gravity=red.chain.gravity,
                base_placement=red.chain.base_placement, planar=red.chain.planar)
    _, tip_ref = run(ref)
    length = sum(s.length for s in scene.segments)
    d = float(np.abs(tip_r - tip_ref).max())
    print(f"nodes {red.nodes} vs 12: tip difference {d:.3g} m")
    assert d < 10 * scene.node_tolerance * length
    reached = [np.max(np.hypot(tr_r.q[:, 3 * j + 1], tr_r.q[:, 3 * j + 2]) * tr_r.q[:, 3 * j]) for j in range(3)]
    assert np.all(np.array(reached) <= red.max_bend)
