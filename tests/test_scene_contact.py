"""Scenes with contact: the [contact], [[obstacles]] and [[loads]] tables make the
Environment every run gets; bad values are refused by key, value and bound; an arm that
starts inside an obstacle is refused with the segment, the obstacle and the depth; the
planar model stays only where obstacles and loads are symmetric about the base's x-z plane
(checked against the full model's out-of-plane acceleration), and only where their prescribed
motions stay in that plane."""

import math

import numpy as np
import pytest

from qchain.contact import Box, Capsule, Cylinder, Environment, HalfSpace, Sphere, contact_nodes, hunt_crossley_damping
from qchain.contact.shapes import Motion
from qchain.scene import SceneError, parse_scene
from qchain.scene import format as F
from support import base_scene, to_toml

#: far from the arm of base_scene (straight up the z axis from the origin, 0.18 m long)
FAR = {
    "halfspace": {"type": "halfspace", "point": [0.0, 0.0, -1.0]},
    "sphere": {"type": "sphere", "center": [0.0, 0.0, 5.0], "radius": 0.1},
    "capsule": {"type": "capsule", "a": [1.0, 0.0, 0.0], "b": [2.0, 0.0, 0.0], "radius": 0.1},
    "cylinder": {"type": "cylinder", "a": [1.0, 0.0, 0.0], "b": [1.0, 0.0, 1.0], "radius": 0.1},
    "box": {"type": "box", "center": [1.0, 0.0, 0.0], "half_extents": [0.1, 0.2, 0.3]},
}


def scene(obstacles=(), loads=(), contact=None, **top):
    d = base_scene()
    if obstacles:
        d["obstacles"] = [dict(o) for o in obstacles]
    if loads:
        d["loads"] = [dict(ld) for ld in loads]
    if contact is not None:
        d["contact"] = contact
    d.update(top)
    return to_toml(d)


def refused(text) -> list[str]:
    with pytest.raises(SceneError) as err:
        parse_scene(text, "c.toml")
    return [str(p) for p in err.value.problems]


def test_the_tables_make_the_environment_every_run_gets(monkeypatch):
    law = {"stiffness": 2e5, "exponent": 1.2, "restitution": 0.6, "impact_speed": 0.3, "mu_static": 0.5,
           "mu_dynamic": 0.4, "slip_velocity": 2e-3, "stribeck_velocity": 2e-2, "nodes": 8}
    obstacles = [dict(FAR["halfspace"], name="ground"), FAR["sphere"], FAR["capsule"], FAR["cylinder"],
                 dict(FAR["box"], rpy=[0.0, 0.0, 0.3])]
    loads = [{"segment": 1, "alpha": 1.0, "force": [0.0, 0.0, -0.5]},
             {"segment": 0, "alpha": 0.25, "moment": [0.0, 0.01, 0.0], "local": True}]
    sc = parse_scene(scene(obstacles, loads, law), "c.toml")
    env = sc.environment
    L = env.law
    assert (L.stiffness, L.exponent, L.mu_static, L.mu_dynamic, L.slip_velocity, L.stribeck_velocity, env.nodes) == \
        (2e5, 1.2, 0.5, 0.4, 2e-3, 2e-2, 8)
    assert L.damping == hunt_crossley_damping(0.6, 0.3) == pytest.approx(8 * 0.4 / (5 * 0.6 * 0.3))
    assert [type(o) for o in env.obstacles] == [HalfSpace, Sphere, Capsule, Cylinder, Box]
    assert sc.surroundings.labels[0] == 'obstacles[0] "ground"' and sc.surroundings.labels[1] == "obstacles[1]"
    c, s, sn = math.cos(0.3), math.sin(0.3), 0.0
    assert np.allclose(env.obstacles[4].rotation, [[c, -s, sn], [s, c, 0.0], [0.0, 0.0, 1.0]])
    assert env.loads[0].segment == 1 and np.array_equal(env.loads[0].force, [0.0, 0.0, -0.5])
    assert env.loads[1].local and env.loads[1].alpha == 0.25
    # without the tables: no environment, and the law's defaults are ContactLaw's
    assert parse_scene(scene()).environment is None
    plain = parse_scene(scene([FAR["sphere"]]))
    d = plain.environment
    # without contact.nodes: the fewest balls the ripple rule allows for these segments
    rule = contact_nodes([s.segment() for s in plain.segments], d.law, plain.gravity)
    assert (d.law.stiffness, d.law.exponent, d.law.damping, d.nodes) == (1e6, 1.5, 0.0, rule)
    assert rule == contact_nodes(plain.build(reduce=False).chain.segments, d.law, plain.gravity) and 1 < rule < 64
    # every run hands it to qchain.simulate
    import qchain.scene.scene as S

    seen = {}

    def fake(*args, **kw):
        seen.update(kw)
        raise RuntimeError("stop")

    monkeypatch.setattr(S, "simulate", fake)
    with pytest.raises(RuntimeError):
        sc.simulate(model=sc.build(reduce=False))
    assert seen["env"] is env


@pytest.mark.parametrize("contact, obstacles, loads, line", [
    ({"stiffness": -1e6}, [], [], "contact.stiffness: expected a number > 0 and <= 1e+15 (N/m^(1+exponent)), found "
     "-1000000.0"),
    ({"mu_static": -0.1}, [], [], "contact.mu_static: expected a number >= 0 and <= 10, found -0.1"),
    ({"mu_static": 0.3, "mu_dynamic": 0.5}, [], [], "contact.mu_dynamic: expected a coefficient <= mu_static = 0.3 "
     "(friction falls from static to dynamic), found 0.5"),
    ({"damping": 1.0, "restitution": 0.8, "impact_speed": 0.5}, [], [], "contact.damping: expected damping, or "
     "restitution with impact_speed, not both, found damping = 1.0 beside restitution = 0.8 and impact_speed = 0.5"),
    ({"restitution": 0.8}, [], [], "contact.impact_speed: expected impact_speed beside restitution"),
    ({"restitution": 0.0, "impact_speed": 0.5}, [], [], "contact.restitution: expected a number > 0 and <= 1, found 0.0"),
    ({"nodes": 0}, [], [], "contact.nodes: expected an integer >= 1 and <= 64, found 0"),
    (None, [{"type": "cone"}], [], 'obstacles[0].type: expected one of "halfspace", "sphere", "capsule", "cylinder", '
     '"box", found a string "cone"'),
    (None, [{"type": "sphear", "center": [0, 0, 5], "radius": 0.1}], [], "(did you mean 'sphere'?)"),
    (None, [{"center": [0, 0, 5]}], [], "obstacles[0].type: expected one of"),
    (None, [{"type": "capsule", "a": [1, 0, 0], "b": [1, 0, 0], "radius": 0.1}], [],
     "obstacles[0].b: expected an end point at least 1e-09 m from a = (1, 0, 0) (the axis), found [1, 0, 0]"),
    (None, [{"type": "cylinder", "a": [1, 0, 0], "b": [1, 0, 0], "radius": 0.1}], [], "obstacles[0].b: expected an "
     "end point at least 1e-09 m from a"),
    (None, [{"type": "halfspace", "normal": [0, 0, 0]}], [], "obstacles[0].normal: expected a non-zero direction, "
     "found [0, 0, 0]"),
    (None, [dict(FAR["sphere"], radius=0.0)], [], "obstacles[0].radius: expected a number > 0 and <= 10000 (m), "
     "found 0.0"),
    (None, [dict(FAR["capsule"], radius=-0.1)], [], "obstacles[0].radius: expected a number > 0"),
    (None, [dict(FAR["box"], half_extents=[0.1, 0.0, 0.1])], [], "obstacles[0].half_extents[1]: expected a number > 0 "
     "and <= 10000 (m), found 0.0"),
    (None, [{"type": "sphere", "center": [0, 0, 5]}], [], "obstacles[0].radius: expected a number > 0 and <= 10000 "
     "(m), found nothing (the key is required)"),
    (None, [dict(FAR["halfspace"], radius=0.1)], [], "obstacles[0].radius: expected only the keys type, name, point, "
     "normal, velocity, amplitude, frequency, phase with type = 'halfspace', found the key 'radius'"),
    # a prescribed motion: Motion's own bounds, and the sine's keys together
    (None, [dict(FAR["sphere"], amplitude=[0.0, 0.0, 0.01])], [], "obstacles[0].frequency: expected a frequency > 0 "
     "Hz beside amplitude = [0.0, 0.0, 0.01] (the sine's), found nothing"),
    (None, [dict(FAR["sphere"], amplitude=[0.0, 0.0, 0.01], frequency=0.0)], [], "obstacles[0].frequency: expected a "
     "frequency > 0 Hz beside amplitude = [0.0, 0.0, 0.01] (a sine of frequency 0 is a constant offset"),
    (None, [dict(FAR["sphere"], amplitude=[0.0, 0.0, 0.01], frequency=-2.0)], [], "obstacles[0].frequency: expected "
     "a number >= 0 and <= 10000 (Hz), found -2.0"),
    (None, [dict(FAR["sphere"], amplitude=[0.0, 0.0, 0.01], frequency=2e4)], [], "obstacles[0].frequency: expected "
     "a number >= 0 and <= 10000 (Hz), found 20000.0"),
    (None, [dict(FAR["sphere"], amplitude=[0.0, 0.0, 0.01], frequency=math.nan)], [], "obstacles[0].frequency: "
     "expected a finite number >= 0 and <= 10000 (Hz), found nan"),
    (None, [dict(FAR["sphere"], frequency=2.0)], [], "obstacles[0].amplitude: expected an amplitude (m, world frame) "
     "beside frequency = 2.0 (the sine it shapes), found nothing"),
    (None, [dict(FAR["box"], phase=0.5)], [], "obstacles[0].amplitude: expected an amplitude (m, world frame) beside "
     "phase = 0.5"),
    (None, [dict(FAR["capsule"], amplitude=[0.0, math.nan, 0.0], frequency=1.0)], [], "obstacles[0].amplitude[1]: "
     "expected a finite number"),
    (None, [dict(FAR["capsule"], amplitude=[0.0, 2e6, 0.0], frequency=1.0)], [], "obstacles[0].amplitude[1]: "
     "expected a number >= -1e+06 and <= 1e+06 (m), found 2000000.0"),
    (None, [dict(FAR["cylinder"], amplitude=[0.0, 0.0, 0.01], frequency=1.0, phase=math.inf)], [],
     "obstacles[0].phase: expected a finite number >= -1000 and <= 1000 (rad), found inf"),
    (None, [dict(FAR["halfspace"], velocity=[0.0, -1e4, 0.0])], [], "obstacles[0].velocity[1]: expected a number "
     ">= -1000 and <= 1000 (m/s), found -10000.0"),
    (None, [dict(FAR["halfspace"], velocity=[0.1, 0.0])], [], "obstacles[0].velocity: expected an array of 3 numbers "
     "(m/s), found 2 numbers [0.1, 0.0]"),
    (None, [dict(FAR["halfspace"], velocity=0.1)], [], "obstacles[0].velocity: expected an array of 3 numbers (m/s)"),
    (None, [dict(FAR["sphere"], centre=[0, 0, 1])], [], "(did you mean 'center'?)"),
    (None, "ground", [], "obstacles: expected an array of tables [[obstacles]], found a string"),
    (None, [], [{"segment": 2, "alpha": 1.0}], "loads[0].segment: expected a segment of the arm, 0 to 1 (2 segments, "
     "count expanded), found 2"),
    (None, [], [{"segment": -1, "alpha": 1.0}], "loads[0].segment: expected an integer >= 0, found -1"),
    (None, [], [{"alpha": 1.0}], "loads[0].segment: expected a segment index, an integer >= 0, found nothing"),
    (None, [], [{"segment": 0, "alpha": 1.5}], "loads[0].alpha: expected a number >= 0 and <= 1, found 1.5"),
    (None, [], [{"segment": 0, "alpha": 1.0, "force": [0, math.nan, 0]}], "loads[0].force[1]: expected a finite "
     "number"),
])
def test_bad_contact_values_are_refused_by_key_value_and_bound(contact, obstacles, loads, line):
    d = base_scene()
    if contact is not None:
        d["contact"] = contact
    if obstacles:
        d["obstacles"] = obstacles
    if loads:
        d["loads"] = loads
    found = refused(to_toml(d))
    assert any(line in p for p in found), found


def test_an_arm_that_starts_inside_an_obstacle_is_refused_with_segment_obstacle_and_depth():
    # segment 1 (0.08 m from z = 0.1) has its contact point 10 of 16 at z = 0.1 + 0.08 * 10.5 / 16 = 0.1525:
    # 0.02 m from the ball's centre, whose surface is 0.01 m away, so the tube (r_s = 0.015 m) is 5 mm inside
    ball = {"type": "sphere", "name": "ball", "center": [0.02, 0.0, 0.1525], "radius": 0.01}
    found = refused(scene([FAR["halfspace"], ball], contact={"nodes": 16}))
    assert found == ['obstacles[1]: expected an arm that starts outside obstacles[1] "ball" (inside by at most 10% of '
                     "a segment's radius, 1.5 mm for segment 1), found segment 1 starts inside it by 5 mm (at alpha = "
                     "0.656, point (0.015, 0, 0.1525) m)"]


@pytest.mark.parametrize("depth_mm, ok", [(1.0, True), (1.4, True), (1.6, False), (20.0, False)])
def test_the_start_penetration_threshold_is_a_tenth_of_the_radius(depth_mm, ok):
    """A wall ``x <= x0`` (normal +x) is ``r_s + x0`` into the straight arm on the z axis."""
    wall = {"type": "halfspace", "point": [depth_mm * 1e-3 - 0.015, 0.0, 0.0], "normal": [1.0, 0.0, 0.0]}
    if ok:
        sc = parse_scene(scene([wall]))
        c = sc.build().chain.contacts(sc.model.q0, sc.model.v0, sc.environment)
        assert np.allclose(c.penetration, depth_mm * 1e-3)  # every contact point of both segments
    else:
        (line,) = refused(scene([wall]))
        assert f"found segment 0 starts inside it by {depth_mm:.3g} mm" in line


def test_an_arm_resting_on_the_ground_passes():
    """Lying on the ground is the rest state, not a start inside it."""
    d = base_scene()
    d["base"] = {"type": "fixed", "position": [0.0, 0.0, 0.015], "rpy": [0.0, math.pi / 2, 0.0]}
    d["obstacles"] = [{"type": "halfspace"}]
    sc = parse_scene(to_toml(d))
    c = sc.build().chain.contacts(sc.model.q0, sc.model.v0, sc.environment)
    assert np.all(np.abs(c.penetration) < 1e-12)


SYMMETRIC = [
    [{"type": "halfspace", "point": [0.0, 3.0, -1.0], "normal": [0.3, 0.0, 1.0]}],
    [{"type": "sphere", "center": [0.02, 0.0, 0.1525], "radius": 0.006}],
    [{"type": "capsule", "a": [0.02, 0.0, 0.1], "b": [0.05, 0.0, 0.2], "radius": 0.006}],
    [{"type": "cylinder", "a": [0.02, -0.05, 0.15], "b": [0.02, 0.05, 0.15], "radius": 0.006}],  # across it
    [{"type": "box", "center": [0.0205, 0.0, 0.15], "half_extents": [0.0055, 0.1, 0.01], "rpy": [0.0, 0.05, 0.0]}],
    [{"type": "box", "center": [0.0195, 0.0, 0.15], "half_extents": [0.0055, 0.1, 0.1], "rpy": [math.pi / 2, 0.0, 0.0]}],
]
LOADS_SYMMETRIC = [
    {"segment": 1, "alpha": 1.0, "force": [0.3, 0.0, -0.5], "moment": [0.0, 0.01, 0.0]},
    {"segment": 1, "alpha": 0.5, "force": [0.3, 0.0, -0.5], "moment": [0.0, 0.01, 0.0], "local": True},
]
ASYMMETRIC = [
    ([{"type": "halfspace", "normal": [0.0, 1.0, 0.0], "point": [0.0, -0.0145, 0.0]}], [],
     "obstacles[0]: its normal (0, 1, 0) leaves the base x-z plane"),
    ([{"type": "sphere", "center": [0.0, 0.02, 0.1525], "radius": 0.006}], [],
     "obstacles[0]: its center is 0.02 m off the base x-z plane"),
    ([{"type": "capsule", "a": [0.02, 0.0, 0.1], "b": [0.02, 0.01, 0.2], "radius": 0.006}], [],
     "obstacles[0]: its axis (0.02, 0, 0.1) -> (0.02, 0.01, 0.2) is neither in the base x-z plane nor across it"),
    ([{"type": "cylinder", "a": [0.02, -0.05, 0.14], "b": [0.02, 0.05, 0.16], "radius": 0.006}], [],
     "is neither in the base x-z plane nor across it"),
    ([{"type": "box", "center": [0.0205, 0.0, 0.15], "half_extents": [0.0055, 0.1, 0.1], "rpy": [0.0, 0.0, 0.3]}], [],
     "obstacles[0]: none of its axes is normal to the base x-z plane"),
    ([], [{"segment": 1, "alpha": 1.0, "force": [0.0, 0.5, 0.0]}],
     "loads[0]: its force (0, 0.5, 0) N (world frame) leaves the base x-z plane"),
    ([], [{"segment": 1, "alpha": 1.0, "moment": [0.01, 0.0, 0.0]}],
     "loads[0]: its moment (0.01, 0, 0) N m (world frame) is not normal to the base x-z plane"),
    ([], [{"segment": 1, "alpha": 1.0, "force": [0.0, 0.5, 0.0], "local": True}],
     "loads[0]: its force (0, 0.5, 0) N (slice frame) leaves the base x-z plane"),
]


def _out_of_plane_acceleration(text, t: float = 0.0) -> float:
    """Largest ``uy`` acceleration of the full model in its initial state at time ``t`` (s),
    pressures off (the symmetric start: any out-of-plane push is the obstacles' or the loads')."""
    sc = parse_scene(text)
    m = sc.build(reduce=False)
    ch = m.chain
    a = ch.forward_dynamics(m.q0, m.v0, np.zeros(ch.nu), t=t, env=sc.environment)
    return float(np.max(np.abs(a[2::3])))


@pytest.mark.parametrize("obstacles", SYMMETRIC)
def test_symmetric_obstacles_and_loads_keep_the_planar_model(obstacles):
    text = scene(obstacles, LOADS_SYMMETRIC)
    sc = parse_scene(text)
    assert sc.planar_obstacle() is None
    assert sc.model.chain.planar and any(r.startswith("planar: uy locked") for r in sc.model.reductions)
    c = sc.model.chain.contacts(sc.model.q0, sc.model.v0, sc.environment)
    if obstacles[0]["type"] != "halfspace":
        assert len(c.segment) > 0  # in contact at the start: the symmetry is tested where it acts
    # the independent check: the full model's out-of-plane acceleration is zero (rounding), and its
    # in-plane accelerations are the planar model's (the reduction is exact with the obstacles and loads)
    assert _out_of_plane_acceleration(text) < 1e-9
    full, planar = sc.build(reduce=False), sc.model
    p0 = np.zeros(full.chain.nu)
    a_full = full.chain.forward_dynamics(full.q0, full.v0, p0, env=sc.environment)
    a_planar = planar.chain.forward_dynamics(planar.q0, planar.v0, p0, env=sc.environment)
    assert np.allclose(a_planar, a_full, rtol=1e-9, atol=1e-9 * np.abs(a_full).max())


@pytest.mark.parametrize("obstacles, loads, why", ASYMMETRIC)
def test_asymmetric_obstacles_or_loads_give_the_full_model(obstacles, loads, why):
    text = scene(obstacles, loads)
    sc = parse_scene(text)
    assert why in sc.planar_obstacle()
    assert not sc.model.chain.planar and any(why in k for k in sc.model.kept)
    # the independent check: the full model does accelerate out of the plane
    assert _out_of_plane_acceleration(text) > 1e-3


def test_the_plane_is_the_base_frames():
    """With the base turned 90 degrees about z its x-z plane is the world's y-z plane."""
    d = base_scene()
    d["base"] = {"type": "fixed", "rpy": [0.0, 0.0, math.pi / 2]}
    d["obstacles"] = [{"type": "sphere", "center": [0.0, 5.0, 0.0], "radius": 0.1}]
    assert parse_scene(to_toml(d)).planar_obstacle() is None
    d["obstacles"] = [{"type": "sphere", "center": [5.0, 0.0, 0.0], "radius": 0.1}]
    assert "its center is -5 m off the base x-z plane" in parse_scene(to_toml(d)).planar_obstacle()


#: a prescribed motion of every kind of key, in the x-z plane
SWAY = {"velocity": [0.02, 0.0, -0.01], "amplitude": [0.004, 0.0, 0.002], "frequency": 3.0, "phase": 0.4}


def _law_offset(m: dict, t: float) -> np.ndarray:
    """u(t) = velocity t + amplitude sin(2 pi frequency t + phase) (m), written out here."""
    v, a = np.asarray(m.get("velocity", [0.0] * 3)), np.asarray(m.get("amplitude", [0.0] * 3))
    return v * t + a * math.sin(2 * math.pi * m.get("frequency", 0.0) * t + m.get("phase", 0.0))


def test_a_moving_obstacle_scene_gives_the_environment_its_motion_and_the_engine_moves_it():
    """Each kind carries the Motion of its keys (a missing key: Motion's default; no key: a
    fixed obstacle); the contacts at time t are those of the same obstacle fixed where the law,
    written out independently, puts it then."""
    moving = [dict(FAR["halfspace"], velocity=[0.1, 0.0, 0.0]), dict(FAR["sphere"], **SWAY),
              dict(FAR["capsule"], amplitude=[0.0, 0.0, 0.01], frequency=2.0), dict(FAR["cylinder"], **SWAY),
              dict(FAR["box"], **SWAY), FAR["sphere"]]
    env = parse_scene(scene(moving)).environment
    mo = [o.motion for o in env.obstacles]
    assert mo[5] is None and mo[0].frequency == 0.0 and mo[0].phase == 0.0 and not mo[0].amplitude.any()
    assert np.array_equal(mo[0].velocity, [0.1, 0.0, 0.0])
    assert np.array_equal(mo[2].amplitude, [0.0, 0.0, 0.01]) and (mo[2].frequency, mo[2].phase) == (2.0, 0.0)
    assert not mo[2].velocity.any()
    for m in (mo[1], mo[3], mo[4]):
        assert np.array_equal(m.velocity, SWAY["velocity"]) and np.array_equal(m.amplitude, SWAY["amplitude"])
        assert (m.frequency, m.phase) == (3.0, 0.4)
    # a ball swinging into the arm (base_scene: straight up the z axis, r_s = 0.015 m) and a wall
    # 1 mm into it sliding up (a belt): the engine's contacts at t are those of the fixed shapes moved there
    ball = {"type": "sphere", "center": [0.025, 0.0, 0.15], "radius": 0.004, "amplitude": [0.008, 0.0, 0.0],
            "frequency": 5.0, "phase": math.pi / 2}
    belt = {"type": "halfspace", "point": [-0.014, 0.0, 0.0], "normal": [1.0, 0.0, 0.0], "velocity": [0.0, 0.0, 0.3]}
    sc = parse_scene(scene([ball, belt], contact={"mu_static": 0.5, "mu_dynamic": 0.4}))  # (no friction by default)
    ch = sc.build(reduce=False).chain
    q, v = sc.model.q0, sc.model.v0
    for t in (0.0, 0.03, 0.05, 0.1, 0.11):
        fixed = Environment([Sphere(np.array(ball["center"]) + _law_offset(ball, t), 0.004),
                             HalfSpace(np.array(belt["point"]) + _law_offset(belt, t), [1.0, 0.0, 0.0])],
                            law=sc.environment.law, nodes=sc.environment.nodes)
        got, want = ch.contacts(q, v, sc.environment, t), ch.contacts(q, v, fixed)
        assert np.array_equal(got.obstacle, want.obstacle) and np.array_equal(got.segment, want.segment)
        np.testing.assert_allclose(got.point, want.point, rtol=0, atol=1e-15)
        np.testing.assert_allclose(got.penetration, want.penetration, rtol=0, atol=1e-15)
        assert np.allclose(got.penetration[got.obstacle == 1], 1e-3, rtol=0, atol=1e-12)  # the belt, all along
        # the ball: half a period after its start (12 mm clear of the tube) it is 2 mm into it
        assert (0 in got.obstacle.tolist()) == (t in (0.1, 0.11))
        if t == 0.1:
            assert got.penetration[got.obstacle == 0].max() == pytest.approx(2e-3, abs=1e-4)
    # the friction of the moving belt acts on the arm's velocity relative to it: dragged along +z
    c = ch.contacts(q, v, sc.environment, 0.0)
    belt_force = c.force[c.obstacle == 1]
    assert belt_force[:, 2].sum() > 0.0 and np.all(belt_force[:, 2] > 0.0)
    still = ch.contacts(q, v, Environment([HalfSpace(belt["point"], belt["normal"])], law=sc.environment.law,
                                          nodes=sc.environment.nodes))
    assert np.all(still.force[:, 2] == 0.0)  # the same wall at rest: no friction on an arm at rest


def test_the_start_check_uses_where_the_motion_puts_the_obstacle_at_t0():
    """The ball of the start-inside test, placed 30 mm off and swung back onto the arm by its
    phase: inside at t = 0 (refused), or, a quarter period later, outside (accepted)."""
    ball = {"type": "sphere", "name": "ball", "center": [0.05, 0.0, 0.1525], "radius": 0.01,
            "amplitude": [-0.03, 0.0, 0.0], "frequency": 1.0, "phase": math.pi / 2}
    found = refused(scene([ball], contact={"nodes": 16}))
    assert len(found) == 1 and found[0].startswith('obstacles[0]: expected an arm that starts outside obstacles[0] '
                                                   '"ball"') and "found segment 1 starts inside it by 5 mm" in found[0]
    sc = parse_scene(scene([dict(ball, phase=0.0)], contact={"nodes": 16}))
    assert sc.environment.obstacles[0].motion.phase == 0.0


def test_a_motion_in_the_plane_keeps_the_planar_model_and_one_out_of_it_is_refused_with_the_reason():
    """The ball touching the arm: swung along x (in the base's x-z plane) the planar model stays,
    its accelerations the full model's at a later time; swung along y it is refused, saying
    which motion key leaves the plane, and the full model does accelerate out of the plane
    then. A turned base turns the plane with it."""
    ball = {"type": "sphere", "center": [0.02, 0.0, 0.1525], "radius": 0.006}
    law = {"mu_static": 0.5, "mu_dynamic": 0.4}  # friction too: it acts on the velocity relative to the ball
    inplane = scene([dict(ball, velocity=[0.01, 0.0, 0.02], amplitude=[-0.002, 0.0, 0.0], frequency=4.0)], contact=law)
    sc = parse_scene(inplane)
    assert sc.planar_obstacle() is None and sc.model.chain.planar
    full, planar = sc.build(reduce=False), sc.model
    p0, t = np.zeros(full.chain.nu), 0.04
    a_full = full.chain.forward_dynamics(full.q0, full.v0, p0, t=t, env=sc.environment)
    a_planar = planar.chain.forward_dynamics(planar.q0, planar.v0, p0, t=t, env=sc.environment)
    assert len(full.chain.contacts(full.q0, full.v0, sc.environment, t).segment) > 0
    assert np.allclose(a_planar, a_full, rtol=1e-9, atol=1e-9 * np.abs(a_full).max())
    assert _out_of_plane_acceleration(inplane, t) < 1e-9
    for key, motion, why in (
            ("velocity", {"velocity": [0.0, 0.05, 0.0]},
             "obstacles[0]: its motion's velocity (0, 0.05, 0) m/s leaves the base x-z plane (by 0.05 m/s)"),
            ("amplitude", {"amplitude": [0.0, 0.003, 0.0], "frequency": 4.0},
             "obstacles[0]: its motion's amplitude (0, 0.003, 0) m leaves the base x-z plane (by 0.003 m)")):
        text = scene([dict(ball, **motion)], contact=law)
        sc = parse_scene(text)
        assert sc.planar_obstacle() == why, key
        assert not sc.model.chain.planar and any(why in k for k in sc.model.kept)
        assert _out_of_plane_acceleration(text, 1 / 16) > 1e-3  # the ball pushed off the plane by then
    d = base_scene()
    d["base"] = {"type": "fixed", "rpy": [0.0, 0.0, math.pi / 2]}  # the base x-z plane is the world's y-z plane
    d["obstacles"] = [dict(FAR["sphere"], velocity=[0.0, 0.3, 0.1])]
    assert parse_scene(to_toml(d)).planar_obstacle() is None
    d["obstacles"] = [dict(FAR["sphere"], velocity=[0.3, 0.0, 0.0])]
    why = parse_scene(to_toml(d)).planar_obstacle()
    assert "its motion's velocity (0.3, 0, 0) m/s leaves the base x-z plane" in why


def test_info_lines_list_the_obstacles_the_law_and_its_time_scale():
    sc = parse_scene(scene([dict(FAR["halfspace"], name="ground"), FAR["box"]],
                           [{"segment": 1, "alpha": 1.0, "force": [0.0, 0.0, -0.5]}], {"mu_static": 0.5}))
    m = sc.build()
    lines = sc.describe(m)
    assert 'obstacles: 2' in lines
    assert '  - obstacles[0] "ground": half-space through (0, 0, -1) m, normal (0, 0, 1)' in lines
    assert "  - obstacles[1]: box, half extents (0.1, 0.2, 0.3) m, center (1, 0, 0) m, rpy (0, 0, 0) rad" in lines
    law = next(x for x in lines if x.startswith("contact: "))
    assert "stiffness 1e+06 N/m^2.5 per m, exponent 1.5, damping 0 s/m, mu_static 0.5, mu_dynamic 0" in law
    # the time scale: one contact point (mass m = 0.05 / 16 kg) on the law's spring linearised where it
    # carries its weight, l k d^1.5 = m g: period 2 pi / omega, omega^2 = 1.5 l k d^0.5 / m
    g, k, ell_m = 9.81, 1e6, [(0.1 / 16, 0.05 / 16), (0.08 / 16, 0.05 / 16)]
    periods = []
    for ell, mass in ell_m:
        d = (mass * g / (ell * k)) ** (1 / 1.5)
        periods.append(2 * math.pi / math.sqrt(1.5 * ell * k * math.sqrt(d) / mass))
    assert f"  time scale {min(periods) * 1e3:.3g} ms" in "\n".join(lines)
    assert "load 0: segment 1 at alpha = 1, force (0, 0, -0.5) N, moment (0, 0, 0) N m, world frame" in lines
    moving = parse_scene(scene([dict(FAR["sphere"], name="swing", **SWAY)])).describe()
    assert ('  - obstacles[0] "swing": sphere, radius 0.1 m, center (0, 0, 5) m; moved by u(t) = velocity t + '
            "amplitude sin(2 pi frequency t + phase): velocity (0.02, 0, -0.01) m/s, amplitude (0.004, 0, 0.002) m, "
            "frequency 3 Hz, phase 0.4 rad") in moving, moving
    assert not any(x.startswith(("obstacles:", "contact:")) for x in parse_scene(scene()).describe())


def test_the_example_arm_on_the_ground_loads_rests_outside_and_stays_planar():
    from support import ROOT

    sc = parse_scene((ROOT / "examples" / "scenes" / "arm_on_ground.toml").read_text(), "arm_on_ground.toml")
    assert sc.n == 3 and [type(o) for o in sc.environment.obstacles] == [HalfSpace]
    assert sc.planar_obstacle() is None
    assert sc.environment.law.damping == pytest.approx(hunt_crossley_damping(0.5, 0.5))


def test_the_declaration_names_the_agreed_keys():
    assert F.CONTACT.keys() == ("stiffness", "exponent", "damping", "restitution", "impact_speed", "mu_static",
                                "mu_dynamic", "slip_velocity", "stribeck_velocity", "nodes")
    motion = ("velocity", "amplitude", "frequency", "phase")
    assert F.OBSTACLE.keys("box") == ("type", "name", "center", "half_extents", "rpy", *motion)
    assert F.OBSTACLE.keys("halfspace") == ("type", "name", "point", "normal", *motion)
    assert F.OBSTACLE_MOTION_KEYS == motion
    # declared with Motion's own bounds and units, one place for both
    from qchain.contact.shapes import MOTION_RANGES

    assert {k: F.OBSTACLE[k].range for k in motion} == MOTION_RANGES
    assert [MOTION_RANGES[k].unit for k in motion] == ["m/s", "m", "Hz", "rad"]
    assert F.LOAD.keys() == ("segment", "alpha", "force", "moment", "local")


def test_the_format_docs_contact_example_is_a_valid_symmetric_scene():
    sc = parse_scene(F.EXAMPLE + "\n" + F.CONTACT_EXAMPLE, "example.toml")
    env = sc.environment
    assert [type(o) for o in env.obstacles] == [HalfSpace, Cylinder] and len(env.loads) == 1
    assert sc.surroundings.labels == ('obstacles[0] "ground"', 'obstacles[1] "pole"')
    assert sc.planar_obstacle() is None  # the pole lies across the arm's plane, centred on it
    assert env.law.damping == pytest.approx(hunt_crossley_damping(0.8, 0.5))

