"""A scene's tendons: the ``[[tendons]]`` tables and the ``[tension]`` table, declared here
(listed with the others in :data:`qchain.scene.format.TABLES`; read by
:func:`qchain.scene.reading.read_tendons`) into the
:class:`qchain.Tendon` s that :class:`qchain.Chain`'s ``tendons=`` takes and the tension
schedule that :func:`qchain.simulate`'s ``tension=`` takes (docs/tendons.md).

The bounds are :mod:`qchain.checks.bounds`' (``TENDON_RADIUS``, ``ANGLE``, ``TENDON_PITCH``,
``TENSION``), the ones :class:`qchain.Tendon` and ``simulate`` apply: a scene refuses what they
would, by key, value and bound.
"""

from __future__ import annotations

from ..checks import bounds as B
from ..checks.bounds import Range
from .keys import Field, KeyTable

__all__ = ["TENDONS", "TENSION", "TENSION_KINDS", "TENDON_EXAMPLE", "describe_tendons"]


#: The kinds of tension schedule a scene may give.
TENSION_KINDS = ("constant", "step", "ramp", "sine", "table")

TENDONS = KeyTable("tendons[]", "One table a tendon (`qchain.Tendon`, docs/tendons.md): `[[tendons]]`, in the order "
                   "of the tensions. A tendon runs at `radius` from the backbone, fixed to the cross-sections it "
                   "crosses and free to slide along them, from the base to the tip of segment `end`; every "
                   "configuration must keep `kappa radius < 1` in the segments it passes.", (
    Field("radius", "number", "Offset `r` from the backbone.", B.TENDON_RADIUS, required=True),
    Field("angle", "number", "Angle `phi` about the base segment's root `z` axis at the base; 0 is the root `+x` "
          "axis, where chamber 1 lies.", B.ANGLE, default="0"),
    Field("pitch", "number", "A helical tendon: rest length a turn, `abs(pitch)` within the range; `> 0` turns "
          "right-handed about the backbone, `< 0` the other way.", B.TENDON_PITCH,
          default="none: a straight tendon"),
    Field("end", "integer", "The segment at whose tip it ends, from 0 at the base (`count` expanded).",
          Range(0, None, integer=True), default="the last segment (the tip)"),
))

TENSION = KeyTable("tension", "The tendons' tensions, one of five kinds (`type`), one number a tendon in the order of "
                   "`[[tendons]]`; a tendon pulls, so every tension is `>= 0`. Only with `[[tendons]]`.", (
    Field("type", "choice", "The kind of schedule.", choices=TENSION_KINDS, required=True),
    Field("value", "tensions", "`constant`: the tensions.", B.TENSION, required=True, when=("constant",)),
    Field("time", "number", "`step`: when the step happens.", B.TIME, required=True, when=("step",)),
    Field("after", "tensions", "`step`: tensions from `time` on.", B.TENSION, required=True, when=("step",)),
    Field("before", "tensions", "`step`: tensions before `time`.", B.TENSION, default="zeros", when=("step",)),
    Field("t0", "number", "`ramp`: start of the ramp.", B.TIME, required=True, when=("ramp",)),
    Field("t1", "number", "`ramp`: its end, `> t0`.", B.TIME, required=True, when=("ramp",)),
    Field("end", "tensions", "`ramp`: tensions from `t1` on.", B.TENSION, required=True, when=("ramp",)),
    Field("start", "tensions", "`ramp`: tensions until `t0`.", B.TENSION, default="zeros", when=("ramp",)),
    Field("amplitude", "tensions", "`sine`: `offset + amplitude sin(2 pi frequency t + phase)` for each tendon; "
          "`offset - abs(amplitude)` must stay `>= 0` (a tendon cannot push).", B.TENSION_AMPLITUDE, required=True,
          when=("sine",)),
    Field("offset", "tensions", "`sine`: the mean tensions.", B.TENSION, default="zeros", when=("sine",)),
    Field("frequency", "number_or_tensions", "`sine`: Hz, one for all tendons or one a tendon.", B.FREQUENCY,
          required=True, when=("sine",)),
    Field("phase", "number_or_tensions", "`sine`: rad, one for all tendons or one a tendon.", B.ANGLE, default="0",
          when=("sine",)),
    Field("times", "times", "`table`: strictly increasing times.", B.TIME, required=True, when=("table",)),
    Field("values", "tension_rows", "`table`: one array of tensions a time; piecewise linear between them, held "
          "outside.", B.TENSION, required=True, when=("table",)),
), )

#: The tendon tables, as the documentation shows them: two straight tendons on opposite sides
#: of a three-segment arm, one to the tip, one to the middle segment's tip, and a ramp of
#: their tensions.
TENDON_EXAMPLE = '''\
[[tendons]]
radius = 0.01
angle = 0.0

[[tendons]]
radius = 0.01
angle = 3.141592653589793
end = 1

[tension]
type = "ramp"
t0 = 0.0
t1 = 1.0
end = [2.0, 1.0]
'''



def describe_tendons(tendons, tension_spec: dict) -> list[str]:
    """``qchain info``'s lines of the tendons (none without any): each one's routing, and the
    tension schedule."""
    if not tendons:
        return []
    lines = []
    for k, td in enumerate(tendons):
        route = "straight" if td.pitch is None else f"helical, pitch {td.pitch:g} m"
        to = "the tip" if td.end is None else f"the tip of segment {td.end}"
        lines.append(f"tendon {k}: radius {td.radius:g} m, angle {td.angle:g} rad, {route}, to {to}")
    kind = tension_spec.get("type")
    lines.append(f"tension: {kind}" if kind else "tension: none (every tendon slack, 0 N)")
    return lines
