"""Fit parameters named by scene keys (qchain.fit.parameters): start values and bounds from the
scene, the fitted values written back into a scene that builds, shared parameters' columns."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from qchain.batch.sweep_spec import apply_values
from qchain.fit.parameters import column_map, fit_parameters, scene_values

SCENE = Path(__file__).parents[1] / "examples" / "scenes" / "spatial_arm.toml"  # one table, count = 4


def _raw(two_tables: bool = False) -> dict:
    raw = tomllib.loads(SCENE.read_text())
    if two_tables:  # the first segment apart: tables [0] (count 1) and [1] (count 3)
        first = dict(raw["segments"][0], count=1, youngs_modulus=2e5)
        raw["segments"] = [first, dict(raw["segments"][0], count=3)]
    return raw


def test_keys_read_their_start_values_and_the_formats_bounds():
    raw = _raw(two_tables=True)
    ps = fit_parameters(raw, ["segments[0].youngs_modulus", "segments[1].damping", "segments[*].mass", "gravity[2]"],
                        bounds={"segments[0].youngs_modulus": (1e4, 1e6)})
    E, d, m, g = ps
    assert (E.start, E.lower, E.upper, E.unit, E.segments) == (2e5, 1e4, 1e6, "Pa", (0,))
    assert (d.start, d.lower, d.upper, d.segments) == (0.02, 0.0, 100.0, (1, 2, 3))
    assert (m.start, m.segments) == (0.05, (0, 1, 2, 3))
    assert (g.name, g.component, g.start, g.segments) == ("gravity", 2, -9.81, ())


def test_fitted_values_go_back_into_a_scene_that_builds():
    from qchain.scene.reading import parse_scene
    import tomli_w

    raw = _raw(two_tables=True)
    ps = fit_parameters(raw, ["segments[1].youngs_modulus", "segments[*].mass", "gravity[2]"])
    new = apply_values(raw, scene_values(ps, [1.5e5, 0.06, -9.7]))
    scene = parse_scene(tomli_w.dumps(new))
    chain = scene.build(reduce=False).chain
    assert [s.youngs_modulus for s in chain.segments] == [2e5, 1.5e5, 1.5e5, 1.5e5]
    assert [s.mass for s in chain.segments] == [0.06] * 4
    assert chain.gravity[2] == -9.7


def test_a_shared_parameter_sums_its_segments_columns():
    raw = _raw(two_tables=True)
    ps = fit_parameters(raw, ["segments[1].youngs_modulus", "gravity[0]"])
    cols = [("youngs_modulus", s) for s in range(4)] + [("gravity", k) for k in range(3)]
    T = column_map(ps, cols)
    np.testing.assert_array_equal(T[:, 0], [0, 1, 1, 1, 0, 0, 0])
    np.testing.assert_array_equal(T[:, 1], [0, 0, 0, 0, 1, 0, 0])
    with pytest.raises(ValueError, match=r"segments\[1\].youngs_modulus: the model has no derivative column"):
        column_map(ps, cols[:1] + cols[4:])


def test_bad_keys_and_bounds_are_refused_by_name():
    raw = _raw(two_tables=True)
    with pytest.raises(ValueError, match=r"'segments\[0\].radius' is not a parameter a fit can change; those are: "
                                         r"segments\[i\].youngs_modulus"):
        fit_parameters(raw, ["segments[0].radius"])
    with pytest.raises(ValueError, match=r"segments\[5\].mass: the scene has 2 \[\[segments\]\] tables"):
        fit_parameters(raw, ["segments[5].mass"])
    with pytest.raises(ValueError, match=r"segments\[\*\].youngs_modulus: the tables have different values"):
        fit_parameters(raw, ["segments[*].youngs_modulus"])
    with pytest.raises(ValueError, match=r"lower bound 0\.5 is below the scene format's 1 Pa"):
        fit_parameters(raw, ["segments[0].youngs_modulus"], bounds={"segments[0].youngs_modulus": (0.5, None)})
    with pytest.raises(ValueError, match=r"the start value 200000 Pa is outside the bounds \[1, 1000\]"):
        fit_parameters(raw, ["segments[0].youngs_modulus"], bounds={"segments[0].youngs_modulus": (None, 1e3)})
    with pytest.raises(ValueError, match="is given twice"):
        fit_parameters(raw, ["gravity[2]", "gravity[2]"])
    with pytest.raises(ValueError, match=r"bounds for 'gravity\[1\]', which is not one of the fitted keys"):
        fit_parameters(raw, ["gravity[2]"], bounds={"gravity[1]": (0, 1)})
