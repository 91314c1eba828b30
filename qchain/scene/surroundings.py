"""A scene's surroundings: the ``[contact]``, ``[[obstacles]]`` and ``[[loads]]`` tables
(declared in :mod:`qchain.scene.format`) read into a :class:`qchain.contact.Environment`;
whether they keep the scene symmetric about the base's x-z plane (the planar model); an arm
that starts inside an obstacle (where its motion puts it at t = 0); and how ``qchain info``
describes them."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pinocchio as pin

from . import format as F
from ..checks.text import show_vector
from ..contact.environment import (MAX_OBSTACLES, ContactLaw, Environment, PointLoad, contact_nodes,
                                   hunt_crossley_damping)
from ..contact.shapes import Box, Capsule, Cylinder, HalfSpace, Motion, Sphere
from .format import _MISSING, Problem, _Checker, _show, _type_name

__all__ = ["Surroundings", "read_surroundings", "MIN_AXIS"]

#: Shortest capsule or cylinder axis (m): :mod:`qchain.contact.shapes`' own bound.
MIN_AXIS = 1e-9


@dataclass(frozen=True)
class Surroundings:
    """What a scene's arm can touch and be pushed by: the ``environment`` (None: nothing) and
    a label for each of its obstacles (``obstacles[i]`` and its ``name``), for messages."""

    environment: Environment | None = None
    labels: tuple[str, ...] = ()

    def label(self, i: int) -> str:
        return self.labels[i]

    # ------------------------------------------------------------------ symmetry

    def asymmetry(self, placement: pin.SE3) -> str | None:
        """Why an obstacle, its motion or a load is not symmetric about the x-z plane of the base
        frame ``placement`` (world), or None if all are (the planar model stays exact). A motion
        in the plane keeps a symmetric obstacle symmetric at every time."""
        env = self.environment
        if env is None:
            return None
        o, n = placement.translation, placement.rotation[:, 1]  # the plane: through o, normal n

        def side(x) -> float:  # signed distance from the plane
            return float((np.asarray(x) - o) @ n)

        def tol(*xs) -> float:  # rounding of positions this far from the origin
            return 1e-12 * max(1.0, float(np.linalg.norm(o)), *(float(np.linalg.norm(x)) for x in xs))

        def same(x, y) -> bool:
            return float(np.linalg.norm(np.asarray(x) - np.asarray(y))) <= tol(x, y)

        def mirror(x):
            return np.asarray(x) - 2.0 * side(x) * n

        for i, ob in enumerate(env.obstacles):
            who = self.label(i)
            if isinstance(ob, HalfSpace) and abs(float(ob.normal @ n)) > 1e-12:
                return f"{who}: its normal {show_vector(ob.normal)} leaves the base x-z plane"
            if isinstance(ob, Sphere) and abs(side(ob.center)) > tol(ob.center):
                return f"{who}: its center is {side(ob.center):.6g} m off the base x-z plane"
            if isinstance(ob, (Capsule, Cylinder)):
                # symmetric: both ends in the plane, or each the other's mirror image (an axis across it)
                if not ((same(mirror(ob.a), ob.a) and same(mirror(ob.b), ob.b))
                        or (same(mirror(ob.a), ob.b) and same(mirror(ob.b), ob.a))):
                    return (f"{who}: its axis {show_vector(ob.a)} -> {show_vector(ob.b)} is neither in the base x-z "
                            "plane nor across it, centred on it")
            if isinstance(ob, Box):
                if abs(side(ob.center)) > tol(ob.center):
                    return f"{who}: its center is {side(ob.center):.6g} m off the base x-z plane"
                if float(np.max(np.abs(ob.rotation.T @ n))) < 1.0 - 1e-12:
                    return f"{who}: none of its axes is normal to the base x-z plane (turned out of it by rpy)"
            if ob.motion is not None:
                for name, x, unit in (("velocity", ob.motion.velocity, "m/s"), ("amplitude", ob.motion.amplitude, "m")):
                    if abs(float(x @ n)) > 1e-12 * max(1.0, float(np.linalg.norm(x))):
                        return (f"{who}: its motion's {name} {show_vector(x)} {unit} leaves the base x-z plane "
                                f"(by {float(x @ n):.6g} {unit})")
        for i, ld in enumerate(env.loads):
            if ld.local:  # the slice frame: its y axis stays the base's y axis in the planar model
                f_out, m_in = abs(ld.force[1]), math.hypot(ld.moment[0], ld.moment[2])
            else:
                f_out, m_in = abs(float(ld.force @ n)), float(np.linalg.norm(np.cross(ld.moment, n)))
            frame = "slice" if ld.local else "world"
            if f_out > 1e-12 * max(1.0, float(np.linalg.norm(ld.force))):
                return f"loads[{i}]: its force {show_vector(ld.force)} N ({frame} frame) leaves the base x-z plane"
            if m_in > 1e-12 * max(1.0, float(np.linalg.norm(ld.moment))):
                return (f"loads[{i}]: its moment {show_vector(ld.moment)} N m ({frame} frame) is not normal to the base "
                        "x-z plane")
        return None

    # ------------------------------------------------------------------ the start

    def start_problems(self, chain, q0, v0, t0: float = 0.0) -> list[Problem]:
        """A :class:`Problem` for each obstacle the arm starts inside deeper than
        :data:`qchain.scene.format.MAX_START_PENETRATION` of a segment's radius: the segment
        that goes deepest into it, how deep (mm) and where."""
        env = self.environment
        if env is None or not env.obstacles:
            return []
        c = chain.contacts(q0, v0, env, t0)
        radius = np.array([s.radius for s in chain.segments])
        over = c.penetration > F.MAX_START_PENETRATION * radius[c.segment]
        out = []
        for i in sorted(set(c.obstacle[over].tolist())):
            k = np.flatnonzero(over & (c.obstacle == i))
            k = int(k[np.argmax(c.penetration[k])])
            j = int(c.segment[k])
            limit = F.MAX_START_PENETRATION * radius[j]
            out.append(Problem(
                f"obstacles[{i}]", f"an arm that starts outside {self.label(i)} (inside by at most "
                f"{F.MAX_START_PENETRATION:.0%} of a segment's radius, {limit * 1e3:.3g} mm for segment {j})",
                f"segment {j} starts inside it by {c.penetration[k] * 1e3:.3g} mm (at alpha = {c.alpha[k]:.3g}, "
                f"point {show_vector(np.round(c.point[k], 6))} m)"))
        return out

    # ------------------------------------------------------------------ description

    def describe(self, chain) -> list[str]:
        """``qchain info``'s lines of the obstacles, the contact law and its time scale, and the loads."""
        env = self.environment
        if env is None:
            return []
        lines = []
        if env.obstacles:
            lines.append(f"obstacles: {len(env.obstacles)}")
            lines += [f"  - {self.label(i)}: {_shape_text(ob)}" for i, ob in enumerate(env.obstacles)]
            law = env.law
            lines.append(f"contact: stiffness {law.stiffness:g} N/m^{1 + law.exponent:g} per m, exponent "
                         f"{law.exponent:g}, damping {law.damping:g} s/m, mu_static {law.mu_static:g}, mu_dynamic "
                         f"{law.mu_dynamic:g}, slip velocity {law.slip_velocity:g} m/s, Stribeck velocity "
                         f"{law.stribeck_velocity:g} m/s, {env.nodes} contact points a segment")
            lines.append(f"  time scale {env.time_scale(chain) * 1e3:.3g} ms (one contact point's period at rest: an "
                         "explicit method's steps stay below it in contact)")
        for i, ld in enumerate(env.loads):
            lines.append(f"load {i}: segment {ld.segment} at alpha = {ld.alpha:g}, force {show_vector(ld.force)} N, "
                         f"moment {show_vector(ld.moment)} N m, {'follower (slice frame)' if ld.local else 'world frame'}")
        return lines


def _shape_text(ob) -> str:
    if ob.motion is None:
        return _placement_text(ob)
    mo = ob.motion
    return (f"{_placement_text(ob)}; moved by u(t) = velocity t + amplitude sin(2 pi frequency t + phase): velocity "
            f"{show_vector(mo.velocity)} m/s, amplitude {show_vector(mo.amplitude)} m, frequency {mo.frequency:g} Hz, "
            f"phase {mo.phase:g} rad")


def _placement_text(ob) -> str:
    if isinstance(ob, HalfSpace):
        return f"half-space through {show_vector(ob.point)} m, normal {show_vector(ob.normal)}"
    if isinstance(ob, Sphere):
        return f"sphere, radius {ob.radius:g} m, center {show_vector(ob.center)} m"
    if isinstance(ob, (Capsule, Cylinder)):
        return (f"{type(ob).__name__.lower()}, radius {ob.radius:g} m, axis {show_vector(ob.a)} -> "
                f"{show_vector(ob.b)} m")
    rpy = pin.rpy.matrixToRpy(ob.rotation)
    return (f"box, half extents {show_vector(ob.half_extents)} m, center {show_vector(ob.center)} m, rpy "
            f"{show_vector(np.round(rpy, 12) + 0.0)} rad")


# --------------------------------------------------------------------------------------
# reading


def read_surroundings(ck: _Checker, raw: dict, segments, gravity) -> Surroundings:
    """The ``[contact]``, ``[[obstacles]]`` and ``[[loads]]`` tables of the parsed scene ``raw``
    (its ``segments``, None if unknown, and ``gravity`` (3,) m/s^2), their problems added to
    ``ck``. Without ``contact.nodes`` the contact points a segment are the fewest the ripple
    rule allows (:func:`qchain.contact.contact_nodes`)."""
    start = len(ck.problems)
    law, nodes = _law(ck, raw)
    obstacles, labels = _obstacles(ck, raw)
    loads = _loads(ck, raw, None if segments is None else len(segments))
    if len(ck.problems) > start or law is None or (not obstacles and not loads) or segments is None:
        return Surroundings()
    if nodes is None:
        nodes = contact_nodes(segments, law, gravity)
    return Surroundings(Environment(obstacles, law=law, loads=loads, nodes=nodes), tuple(labels))


def _law(ck: _Checker, raw: dict) -> tuple[ContactLaw | None, int | None]:
    T = F.CONTACT
    ct = ck.section(raw, "contact", T.keys())
    start = len(ck.problems)
    v = {k: ck.field(ct, T[k], f"contact.{k}") for k in T.keys()}
    nodes = v.pop("nodes")  # None: contact_nodes picks them
    e, speed = v.pop("restitution"), v.pop("impact_speed")
    if "damping" in ct and ("restitution" in ct or "impact_speed" in ct):
        ck.add("contact.damping", "damping, or restitution with impact_speed, not both",
               f"damping = {_show(ct['damping'])} beside " + " and ".join(
                   f"{k} = {_show(ct[k])}" for k in ("restitution", "impact_speed") if k in ct))
    elif ("restitution" in ct) != ("impact_speed" in ct):
        have, need = ("restitution", "impact_speed") if "restitution" in ct else ("impact_speed", "restitution")
        ck.add(f"contact.{need}", f"{need} beside {have} (the damping is set by both)", "nothing")
    ms = v["mu_static"] if v["mu_static"] is not None else F._LAW["mu_static"]
    if v["mu_dynamic"] is not None and v["mu_dynamic"] > ms:
        ck.add("contact.mu_dynamic", f"a coefficient <= mu_static = {ms:g} (friction falls from static to dynamic)",
               _show(ct["mu_dynamic"]))
    if len(ck.problems) > start:
        return None, nodes
    if e is not None and speed is not None:
        v["damping"] = hunt_crossley_damping(e, speed)
    try:
        return ContactLaw(**{k: x for k, x in v.items() if x is not None}), nodes
    except (ValueError, TypeError) as err:  # pragma: no cover - the checks above are ContactLaw's own
        ck.add("contact", "a valid contact law", str(err))
        return None, nodes


def _tables(ck: _Checker, raw: dict, key: str) -> list:
    """The array of tables ``raw[key]`` ([] if missing or wrong)."""
    ts = raw.get(key, _MISSING)
    if ts is _MISSING:
        return []
    if not isinstance(ts, list) or not all(isinstance(t, dict) for t in ts):
        ck.add(key, f"an array of tables [[{key}]]", f"{_type_name(ts)} {_show(ts)}")
        return []
    return ts


def _obstacles(ck: _Checker, raw: dict) -> tuple[list, list[str]]:
    T = F.OBSTACLE
    tables = _tables(ck, raw, "obstacles")
    if len(tables) > MAX_OBSTACLES:
        ck.add("obstacles", f"at most {MAX_OBSTACLES} obstacles", f"{len(tables)}")
        return [], []
    out, labels = [], []
    for i, o in enumerate(tables):
        path = f"obstacles[{i}]"
        start = len(ck.problems)
        kind = ck.field(o, T["type"], f"{path}.type")
        allowed = T.keys(kind) if kind is not None else T.keys()
        for k in o:
            if k in T.keys() and k not in allowed:
                ck.add(f"{path}.{k}", f"only the keys {', '.join(allowed)} with type = {kind!r}", f"the key {k!r}")
        ck.keys(o, path, T.keys())
        if kind is None:
            continue
        defaults = {"point": (0.0, 0.0, 0.0), "normal": (0.0, 0.0, 1.0), "rpy": (0.0, 0.0, 0.0), "name": ""}
        v = {k: ck.field(o, T[k], f"{path}.{k}", defaults.get(k)) for k in allowed
             if k != "type" and k not in F.OBSTACLE_MOTION_KEYS}
        motion = _motion(ck, path, o)
        if len(ck.problems) > start:
            continue
        shape = _shape(ck, path, kind, v, o, motion)
        if shape is not None:
            out.append(shape)
            labels.append(f'{path} "{v["name"]}"' if v["name"] else path)
    return out, labels


def _motion(ck: _Checker, path: str, o: dict) -> Motion | None:
    """The :class:`Motion` of the obstacle table ``o`` (None without motion keys, or with a
    problem added): each key within :data:`qchain.contact.shapes.MOTION_RANGES`, ``amplitude``
    and a ``frequency`` > 0 together (a sine of frequency 0 is a constant offset, a frequency
    or phase without amplitude moves nothing: both are mistakes), ``phase`` only with them."""
    T = F.OBSTACLE
    if not any(k in o for k in F.OBSTACLE_MOTION_KEYS):
        return None
    start = len(ck.problems)
    vel = ck.field(o, T["velocity"], f"{path}.velocity", (0.0, 0.0, 0.0))
    amp = ck.field(o, T["amplitude"], f"{path}.amplitude", (0.0, 0.0, 0.0))
    freq = ck.field(o, T["frequency"], f"{path}.frequency")
    phase = ck.field(o, T["phase"], f"{path}.phase", 0.0)
    if "amplitude" in o and "frequency" not in o:
        ck.add(f"{path}.frequency", f"a frequency > 0 Hz beside amplitude = {_show(o['amplitude'])} (the sine's)",
               "nothing")
    elif "amplitude" in o and freq == 0.0:
        ck.add(f"{path}.frequency", f"a frequency > 0 Hz beside amplitude = {_show(o['amplitude'])} (a sine of "
               "frequency 0 is a constant offset: move the obstacle instead)", _show(o["frequency"]))
    for k in ("frequency", "phase"):
        if k in o and "amplitude" not in o:
            ck.add(f"{path}.amplitude",
                   f"an amplitude (m, world frame) beside {k} = {_show(o[k])} (the sine it shapes)", "nothing")
            break
    if len(ck.problems) > start:
        return None
    try:
        return Motion(vel, amp, 0.0 if freq is None else freq, phase)
    except (ValueError, TypeError) as err:  # pragma: no cover - the checks above are Motion's own
        ck.add(path, "a valid motion", str(err))
        return None


def _shape(ck: _Checker, path: str, kind: str, v: dict, o: dict, motion: Motion | None = None):
    """The obstacle of type ``kind`` from its checked values ``v``, carried by ``motion``; None
    (with a problem) for a degenerate one: a zero normal, an axis whose ends coincide."""
    if kind == "halfspace" and not np.any(v["normal"]):
        ck.add(f"{path}.normal", "a non-zero direction", _show(o.get("normal")))
        return None
    if kind in ("capsule", "cylinder") and not float(np.linalg.norm(v["b"] - v["a"])) >= MIN_AXIS:
        ck.add(f"{path}.b", f"an end point at least {MIN_AXIS:g} m from a = {show_vector(v['a'])} (the axis)",
               _show(o["b"]))
        return None
    try:
        if kind == "halfspace":
            nrm = v["normal"] / np.max(np.abs(v["normal"]))  # scaled first: the norm of [1e-200, 0, 0] underflows
            return HalfSpace(v["point"], nrm, motion=motion)
        if kind == "sphere":
            return Sphere(v["center"], v["radius"], motion=motion)
        if kind == "capsule":
            return Capsule(v["a"], v["b"], v["radius"], motion=motion)
        if kind == "cylinder":
            return Cylinder(v["a"], v["b"], v["radius"], motion=motion)
        return Box(v["center"], v["half_extents"], pin.rpy.rpyToMatrix(*v["rpy"]), motion=motion)
    except (ValueError, TypeError) as err:  # pragma: no cover - the checks above are the shapes' own
        ck.add(path, f"a valid {kind}", str(err))
        return None


def _loads(ck: _Checker, raw: dict, n: int | None) -> list[PointLoad]:
    T = F.LOAD
    out = []
    for i, ld in enumerate(_tables(ck, raw, "loads")):
        path = f"loads[{i}]"
        start = len(ck.problems)
        ck.keys(ld, path, T.keys())
        if "segment" not in ld:  # (a required number, alpha, says so itself; an integer does not)
            ck.add(f"{path}.segment", "a segment index, an integer >= 0", "nothing (the key is required)")
        seg = ck.field(ld, T["segment"], f"{path}.segment")
        alpha = ck.field(ld, T["alpha"], f"{path}.alpha")
        force = ck.field(ld, T["force"], f"{path}.force", (0.0, 0.0, 0.0))
        moment = ck.field(ld, T["moment"], f"{path}.moment", (0.0, 0.0, 0.0))
        local = ck.field(ld, T["local"], f"{path}.local", False)
        if seg is not None and n is not None and seg >= n:
            ck.add(f"{path}.segment", f"a segment of the arm, 0 to {n - 1} ({n} segment{'s' if n != 1 else ''}, "
                   "count expanded)", str(seg))
        if len(ck.problems) > start or n is None:
            continue
        out.append(PointLoad(seg, alpha, force, moment, local))
    return out
