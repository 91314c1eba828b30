"""A scene's tip payload: the ``[payload]`` table (declared here, listed with the others in
:data:`qchain.scene.format.TABLES`) read into the ``pinocchio.Inertia`` that
:class:`qchain.Chain`'s ``payload=`` takes; whether it keeps the scene symmetric about the
base's x-z plane (the planar model); and how ``qchain info`` describes it.

The bounds and the rigid-body check are :mod:`qchain.arm.payload`'s, the ones ``Chain``
applies: a scene refuses what ``Chain(payload=)`` would, by key, value and bound.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pinocchio as pin

from ..arm.payload import PAYLOAD_INERTIA, PAYLOAD_LEVER, PAYLOAD_MASS, inertia_problem, planar_consistent
from ..checks.text import show_matrix, show_vector
from .keys import Field, KeyTable

if TYPE_CHECKING:
    from .format import _Checker

__all__ = ["PAYLOAD", "PAYLOAD_EXAMPLE", "read_payload", "payload_asymmetry", "describe_payload"]

PAYLOAD = KeyTable("payload", "A rigid body fixed at the arm's tip (`qchain.Chain(payload=pinocchio.Inertia(mass, "
                   "lever, inertia))`, `qchain/arm/payload.py`): its mass, where its centre of mass sits in the tip "
                   "frame (the last segment's end slice: z along the arm, x towards chamber 1) and its rotational "
                   "inertia about that centre, tip-frame axes. Gravity acts on it, it moves with the tip; "
                   "`mass = 0` is no payload.", (
    Field("mass", "number", "Its mass.", PAYLOAD_MASS, required=True),
    Field("lever", "vector", "Its centre of mass, tip frame.", PAYLOAD_LEVER, default="[0, 0, 0]: at the tip's "
          "centre", size=3),
    Field("inertia", "matrix", "Rotational inertia about its centre of mass, tip-frame axes: symmetric, positive "
          "semi-definite, one array a row (a body whose principal axes are the tip frame's: the principal moments "
          "on the diagonal). A solid sphere of mass `m`, radius `r`: `0.4 m r^2` on the diagonal.", PAYLOAD_INERTIA,
          default="zeros: a point mass", size=3),
))

#: The payload table, as the documentation shows it: a 60 g ball of 20 mm radius whose centre
#: is 20 mm beyond the tip (0.4 m r^2 = 9.6e-6 kg m^2).
PAYLOAD_EXAMPLE = '''\
[payload]
mass = 0.06
lever = [0.0, 0.0, 0.02]
inertia = [[9.6e-6, 0.0, 0.0], [0.0, 9.6e-6, 0.0], [0.0, 0.0, 9.6e-6]]
'''


def read_payload(ck: _Checker, raw: dict) -> pin.Inertia | None:
    """The ``[payload]`` table of the parsed scene ``raw``: a ``pinocchio.Inertia`` (tip frame),
    or None (no table, ``mass = 0``, or a problem, added to ``ck``)."""
    if "payload" not in raw:
        return None
    T = PAYLOAD
    t = ck.section(raw, "payload", T.keys())
    if not isinstance(raw["payload"], dict):  # (said by section)
        return None
    start = len(ck.problems)
    mass = ck.field(t, T["mass"], "payload.mass")
    lever = ck.field(t, T["lever"], "payload.lever", default=np.zeros(3))
    inertia = ck.field(t, T["inertia"], "payload.inertia", default=np.zeros((3, 3)))
    if inertia is not None and "inertia" in t:
        why = inertia_problem(inertia)
        if why is not None:
            ck.add("payload.inertia", "a rigid body's rotational inertia about its centre of mass: symmetric, "
                   "positive semi-definite (kg m^2)", why)
        elif mass == 0.0 and np.abs(inertia).max() > 0.0:
            ck.add("payload.inertia", "zeros with payload.mass = 0 (a body without mass has no rotational inertia)",
                   f"{show_matrix(inertia)} kg m^2")
    if len(ck.problems) > start or mass is None or lever is None or inertia is None or mass == 0.0:
        return None
    return pin.Inertia(mass, lever, 0.5 * (inertia + inertia.T))


def payload_asymmetry(payload: pin.Inertia | None) -> str | None:
    """Why ``payload`` (tip frame) is not symmetric about the tip frame's x-z plane, which the
    planar model keeps in the base's x-z plane (:func:`qchain.arm.payload.planar_consistent`,
    the condition ``Chain(planar=True)`` checks), or None if it is (or there is none)."""
    if payload is None or planar_consistent(payload.matrix()):
        return None
    c, I = np.asarray(payload.lever), np.asarray(payload.inertia)
    if c[1] != 0.0:
        return f"payload: its lever {show_vector(c)} m leaves the tip frame's x-z plane (y = {c[1]:.6g} m, not 0)"
    return (f"payload: its inertia couples the tip frame's y axis with x or z (inertia[0][1] = {I[0, 1]:.6g}, "
            f"inertia[1][2] = {I[1, 2]:.6g} kg m^2, not 0): y is not one of its principal axes")


def describe_payload(payload: pin.Inertia | None, chain) -> list[str]:
    """``qchain info``'s line of the payload (none without one): its mass beside the arm's, its
    lever and its inertia."""
    if payload is None:
        return []
    arm = sum(s.mass for s in chain.segments)
    I = np.asarray(payload.inertia)
    if not I.any():
        rot = "a point mass"
    elif not (I - np.diag(np.diag(I))).any():
        rot = f"principal moments {show_vector(np.diag(I))} kg m^2 along the tip axes"
    else:
        rot = f"inertia {show_matrix(I)} kg m^2"
    return [f"payload: {payload.mass:g} kg ({payload.mass / arm:.3g} x the arm's {arm:g} kg) at lever "
            f"{show_vector(payload.lever)} m (tip frame), {rot} about its centre of mass; weight "
            f"{payload.mass * float(np.linalg.norm(chain.gravity)):.4g} N"]
