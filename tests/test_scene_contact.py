"""Scenes with contact: the [contact], [[obstacles]] and [[loads]] tables make the
Environment every run gets; bad values are refused by key, value and bound; an arm that
starts inside an obstacle is refused with the segment, the obstacle and the depth; the
planar model stays only where obstacles and loads are symmetric about the base's x-z plane
(checked against the full model's out-of-plane acceleration)."""

import math

import numpy as np
import pytest

from qchain.contact import Box, Capsule, Cylinder, HalfSpace, Sphere, contact_nodes, hunt_crossley_damping
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
     "normal with type = 'halfspace', found the key 'radius'"),
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


def _out_of_plane_acceleration(text) -> float:
    """Largest ``uy`` acceleration of the full model at the start, pressures off (the
    symmetric start: any out-of-plane push is the obstacles' or the loads')."""
    sc = parse_scene(text)
    m = sc.build(reduce=False)
    ch = m.chain
    a = ch.forward_dynamics(m.q0, m.v0, np.zeros(ch.nu), env=sc.environment)
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
    assert F.OBSTACLE.keys("box") == ("type", "name", "center", "half_extents", "rpy")
    assert F.OBSTACLE.keys("halfspace") == ("type", "name", "point", "normal")
    assert F.LOAD.keys() == ("segment", "alpha", "force", "moment", "local")


def test_the_format_docs_contact_example_is_a_valid_symmetric_scene():
    sc = parse_scene(F.EXAMPLE + "\n" + F.CONTACT_EXAMPLE, "example.toml")
    env = sc.environment
    assert [type(o) for o in env.obstacles] == [HalfSpace, Cylinder] and len(env.loads) == 1
    assert sc.surroundings.labels == ('obstacles[0] "ground"', 'obstacles[1] "pole"')
    assert sc.planar_obstacle() is None  # the pole lies across the arm's plane, centred on it
    assert env.law.damping == pytest.approx(hunt_crossley_damping(0.8, 0.5))

