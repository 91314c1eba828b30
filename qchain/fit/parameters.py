"""The parameters a fit can change, named by scene keys, and their link to the model's own.

A fit parameter is a dotted scene key (docs/scene-format.md), the same form a sweep's axes
use (:func:`qchain.batch.sweep_spec.parse_key`):

``segments[i].NAME``   one ``[[segments]]`` table's value: every one of its ``count`` copies
                       shares it (``NAME`` one of :data:`SEGMENT_PARAMETERS`);
``segments[*].NAME``   one value for every segment of the arm;
``gravity[k]``         one component of gravity (m/s^2, world frame).

:func:`fit_parameters` reads their start values from the scene table and their bounds from
the scene format's ranges (narrowed by the caller's); :func:`scene_values` turns fitted values
back into scene keys (:func:`qchain.batch.sweep_spec.apply_values` writes them into a scene);
:func:`column_map` sums the model's per-segment derivative columns into the fit's columns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..batch.sweep_spec import parse_key
from ..checks import bounds as B

__all__ = ["SEGMENT_PARAMETERS", "FitParameter", "fit_parameters", "scene_values", "column_map"]

#: segment keys a fit can change: their range (the scene format's) and what they are
SEGMENT_PARAMETERS = {
    "youngs_modulus": (B.YOUNGS_MODULUS, "Young's modulus E (bending and axial stiffness)"),
    "damping": (B.DAMPING, "stiffness-proportional damping beta"),
    "mass": (B.MASS, "the segment's mass (its density scaled)"),
    "length": (B.LENGTH, "rest length l0"),
    "chamber_area": (B.CHAMBER_AREA, "each chamber's cross-section: the input gain"),
}


@dataclass(frozen=True)
class FitParameter:
    """One fitted number.

    Attributes
    ----------
    key : str
        The scene key (``"segments[0].youngs_modulus"``, ``"segments[*].damping"``,
        ``"gravity[2]"``).
    name : str
        The model parameter (a :data:`SEGMENT_PARAMETERS` key, or ``"gravity"``).
    segments : tuple of int
        The arm's segments (0-based, ``count`` expanded) that share the value; empty for gravity.
    component : int or None
        Gravity's component.
    start : float
        The scene's value (SI units).
    lower, upper : float
        Bounds.
    unit : str
    """

    key: str
    name: str
    segments: tuple
    component: int | None
    start: float
    lower: float
    upper: float
    unit: str


def _tables(raw: dict) -> list[tuple[int, int]]:
    """(first expanded segment, count) of each ``[[segments]]`` table."""
    out, k = [], 0
    for tab in raw.get("segments", []):
        c = int(tab.get("count", 1))
        out.append((k, c))
        k += c
    return out


def fit_parameters(raw: dict, keys, bounds: dict | None = None) -> list[FitParameter]:
    """The parameters ``keys`` of the scene table ``raw`` (a parsed scene file).

    Parameters
    ----------
    raw : dict
        The scene file's table (``tomllib.load``).
    keys : sequence of str
        Scene keys, each once.
    bounds : dict, optional
        ``{key: (lower, upper)}`` narrowing the scene format's range (None: that side unchanged).

    Raises
    ------
    ValueError
        A key that is not a fit parameter (the message lists those there are), a table index
        past the scene's tables, a key given twice, a bound outside the format's range or a
        start value outside its bounds, or a scene with tendons (the measured inputs are
        chamber pressures: its tendons would be slack).
    """
    if raw.get("tendons"):
        raise ValueError("scene: a fit takes no tendons ([[tendons]]): the measured inputs are chamber pressures")
    bounds = dict(bounds or {})
    unknown = set(bounds) - set(keys)
    if unknown:
        raise ValueError(f"bounds for {sorted(unknown)[0]!r}, which is not one of the fitted keys {list(keys)}")
    if len(set(keys)) != len(keys):
        raise ValueError(f"keys: {next(k for k in keys if list(keys).count(k) > 1)!r} is given twice")
    tables = _tables(raw)
    allowed = ", ".join([f"segments[i].{n}" for n in SEGMENT_PARAMETERS] + ["segments[*].NAME", "gravity[k]"])
    out = []
    for key in keys:
        tok = parse_key(key)
        if tok[0] == "segments" and len(tok) == 3 and tok[2] in SEGMENT_PARAMETERS:
            idx, name = tok[1], tok[2]
            rng, _ = SEGMENT_PARAMETERS[name]
            if idx == "*":
                segs = tuple(range(sum(c for _, c in tables)))
                vals = {tab.get(name) for tab in raw["segments"]}
                if len(vals) != 1:
                    raise ValueError(f"{key}: the tables have different values {sorted(map(str, vals))}; fit them "
                                     "one by one (segments[i].NAME) or make them equal first")
                start = vals.pop()
            else:
                if idx >= len(tables):
                    raise ValueError(f"{key}: the scene has {len(tables)} [[segments]] tables (0 to {len(tables) - 1})")
                first, c = tables[idx]
                segs = tuple(range(first, first + c))
                start = raw["segments"][idx].get(name, 0.0 if name == "damping" else None)
            if start is None:
                raise ValueError(f"{key}: the scene gives no value to start from")
            lo, hi, comp, unit = rng.low, rng.high, None, rng.unit
        elif tok[0] == "gravity" and len(tok) == 2 and isinstance(tok[1], int) and 0 <= tok[1] < 3:
            g = raw.get("gravity", [0.0, 0.0, -9.81])
            name, segs, comp, start = "gravity", (), tok[1], g[tok[1]]
            lo, hi, unit = B.GRAVITY.low, B.GRAVITY.high, B.GRAVITY.unit
        else:
            raise ValueError(f"{key!r} is not a parameter a fit can change; those are: {allowed}")
        lo = -np.inf if lo is None else float(lo)
        hi = np.inf if hi is None else float(hi)
        if key in bounds:
            blo, bhi = bounds[key]
            if blo is not None:
                if blo < lo:
                    raise ValueError(f"{key}: lower bound {blo:g} is below the scene format's {lo:g} {unit}")
                lo = float(blo)
            if bhi is not None:
                if bhi > hi:
                    raise ValueError(f"{key}: upper bound {bhi:g} is above the scene format's {hi:g} {unit}")
                hi = float(bhi)
        start = float(start)
        if not lo <= start <= hi:
            raise ValueError(f"{key}: the start value {start:g} {unit} is outside the bounds [{lo:g}, {hi:g}]")
        out.append(FitParameter(key, name, segs, comp, start, lo, hi, unit))
    return out


def scene_values(params: list[FitParameter], x) -> dict:
    """``{scene key: value}`` of fitted values ``x`` (p,), for ``apply_values``."""
    return {p.key: float(v) for p, v in zip(params, np.asarray(x, dtype=float))}


def column_map(params: list[FitParameter], model_columns: list[tuple[str, int | None]]) -> np.ndarray:
    """The matrix ``T`` (n_model, p) with ``d/d(fit) = d/d(model) @ T``: a fit parameter shared
    by several segments is the sum of their columns.

    Parameters
    ----------
    params : list of FitParameter
    model_columns : list of (name, segment or component)
        The model's derivative columns: ``("youngs_modulus", 3)`` for segment 3's modulus,
        ``("gravity", 2)`` for gravity's z component.
    """
    index = {c: i for i, c in enumerate(model_columns)}
    T = np.zeros((len(model_columns), len(params)))
    for j, p in enumerate(params):
        cols = [(p.name, s) for s in p.segments] if p.name != "gravity" else [("gravity", p.component)]
        for c in cols:
            if c not in index:
                raise ValueError(f"{p.key}: the model has no derivative column {c}")
            T[index[c], j] = 1.0
    return T
